"""Simulated Gough-Stewart platform (pure numpy, no rclpy): the controller drives the legs to
``IK(controller, pose)``; the real platform sits at ``FK(true, q)`` (docs/platform_effects.md)."""

import dataclasses

import numpy as np

from gsp_kinematics.model.effect_groups import commanded_leg_readings
from gsp_kinematics.model.effects import PlatformEffects, approach_directions, thermal_strains
from gsp_kinematics.model.kinematics import check_reachable, home_pose
from gsp_kinematics.model.motion import LegMove
from gsp_kinematics.model.real_pose import real_poses

#: Largest condition number of dq/dX a command may have (singularity guard): above the one
#: postures are sampled within, so they stay accepted as the controller geometry changes.
DEFAULT_MAX_CONDITION = 100.0
#: Thermal growth (m, of a 1 m leg) since the resting pose was solved above which
#: :meth:`PlatformSimulator.update` solves it again.
THERMAL_RESOLVE_M = 1e-10


@dataclasses.dataclass(frozen=True)
class CommandOutcome:
    """Result of :meth:`PlatformSimulator.command`: q (6,) m or None when rejected, the real
    pose once carried out and ``travel_s`` (s)."""

    accepted: bool
    reason: str
    commanded_leg_lengths: np.ndarray | None
    true_pose: np.ndarray
    travel_s: float = 0.0


class PlatformSimulator:
    """A platform whose controller uses ``controller_geometry`` and whose hardware is
    ``true_geometry``; ``leg_lengths_noise_std`` in m, ``start_s`` when the legs start warming (s).
    """

    def __init__(
        self,
        true_geometry,
        controller_geometry,
        leg_lengths_noise_std=0.0,
        rng=None,
        max_condition=DEFAULT_MAX_CONDITION,
        initial_pose=None,
        limits=None,
        effects=None,
        start_s=0.0,
    ):
        self.limits = limits
        self.effects = PlatformEffects() if effects is None else effects
        self._start_s = float(start_s)
        self._directions = None  # each leg's approach direction (+1 extending)
        self._pose_time_s = self._start_s  # time of the thermal growth in the resting pose
        self._move = None  # the LegMove under way, with the real poses at its ends
        self._true_geometry = true_geometry
        #: Used from the next command; the legs hold their current lengths.
        self.controller_geometry = controller_geometry
        self.leg_lengths_noise_std = float(leg_lengths_noise_std)  #: m
        self.max_condition = float(max_condition)  #: largest dq/dX condition number commanded
        self._rng = rng if rng is not None else np.random.default_rng()
        self._leg_lengths = None
        self._true_pose = None
        start = home_pose() if initial_pose is None else initial_pose
        outcome = self.command(start, self._start_s)
        if not outcome.accepted:
            raise ValueError(
                f'cannot reach the initial pose {np.asarray(start).tolist()}: {outcome.reason}'
            )

    @property
    def moving(self):
        """True while the legs have not arrived (as of the last :meth:`update`)."""
        return self._move is not None

    def update(self, now_s):
        """Advance the move under way to ``now_s`` (s, the clock of :meth:`command`); at rest,
        follow the legs' thermal growth."""
        if self._move is None:
            self._follow_thermal_growth(now_s)
            return
        move, start_pose, end_pose = self._move
        fraction = move.fraction(now_s)
        if fraction >= 1.0:
            self._leg_lengths, self._true_pose, self._move = move.end.copy(), end_pose, None
            self._follow_thermal_growth(now_s)
            return
        self._leg_lengths = move.start + fraction * (move.end - move.start)
        self._true_pose = start_pose + fraction * (end_pose - start_pose)

    def _real_pose(self, leg_lengths, directions, now_s, guess):
        """Real pose (6,) for the readings, or None when the platform has none near ``guess``."""
        pose, converged = real_poses(
            self._true_geometry,
            self.effects,
            leg_lengths[None],
            guess[None],
            directions[None],
            [now_s - self._start_s],
        )
        return pose[0] if converged[0] and np.all(np.isfinite(pose[0])) else None

    def _follow_thermal_growth(self, now_s):
        if not self.effects.thermal:
            return
        times = np.array([self._pose_time_s, now_s]) - self._start_s
        growth = np.abs(np.diff(thermal_strains(self.effects, times), axis=0))
        if np.max(growth) > THERMAL_RESOLVE_M:
            pose = self._real_pose(self._leg_lengths, self._directions, now_s, self._true_pose)
            if pose is not None:
                self._true_pose, self._pose_time_s = pose, now_s

    @property
    def leg_lengths(self):
        """Noise-free leg sensor readings q (6,) the legs are driven to (m); the real articular
        variables are ``(1 + kq_true) q``."""
        return self._leg_lengths.copy()

    @property
    def true_pose(self):
        """Real pose (6,) ``[x, y, z, psi, theta, phi]`` of the platform (m, rad)."""
        return self._true_pose.copy()

    def measured_leg_lengths(self):
        """Leg sensor readings q (6,) plus Gaussian noise of std ``leg_lengths_noise_std`` (m)."""
        return self._leg_lengths + self._rng.normal(0.0, self.leg_lengths_noise_std, size=6)

    def _reject(self, reason):
        return CommandOutcome(
            False, reason, None, None if self._true_pose is None else self._true_pose.copy()
        )

    def command(self, pose, now_s=0.0):
        """Drive the platform to ``pose`` (6,) as the controller understands it, from ``now_s`` (s);
        a refusal leaves it unchanged, ``reason`` says why."""
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (6,):
            return self._reject(f'pose must be [x, y, z, psi, theta, phi], got shape {pose.shape}')
        if not np.all(np.isfinite(pose)):
            return self._reject(f'pose is not finite: {pose.tolist()}')
        ok, reasons = check_reachable(
            self.controller_geometry, pose[None], max_condition=self.max_condition
        )
        if not ok[0]:
            return self._reject(f'unreachable: {reasons[0]}')
        if self._leg_lengths is not None and self.limits is not None and self._move is not None:
            self.update(now_s)  # a command may supersede a move: from where the legs are now
        # The controller's IK, compensating the effects it knows (geometry.effects).
        leg_lengths = commanded_leg_readings(
            self.controller_geometry, pose[None], self._leg_lengths
        )[0]
        directions = approach_directions(leg_lengths[None], self._leg_lengths, self._directions)[0]
        true_pose = self._real_pose(leg_lengths, directions, now_s, pose)
        if true_pose is None:
            return self._reject(
                'forward kinematics of the real platform found no pose near the command for '
                f'q = {np.round(leg_lengths, 6).tolist()} m (singularity or assembly mode change)'
            )
        self._directions, self._pose_time_s = directions, now_s
        travel_s = 0.0
        if self._leg_lengths is None or self.limits is None or self.limits.instantaneous:
            self._leg_lengths, self._true_pose, self._move = leg_lengths, true_pose, None
        else:
            move = LegMove(self._leg_lengths, leg_lengths, self.limits, now_s)
            travel_s = move.duration_s
            self._move = (move, self._true_pose.copy(), true_pose)
            self.update(now_s)
        return CommandOutcome(True, '', leg_lengths.copy(), true_pose.copy(), travel_s)
