"""What the effect groups need of a run, from its own record (pure, no rclpy;
docs/platform_effects.md#through-the-calibrator)."""

import numpy as np

from gsp_kinematics.model.effect_groups import REFERENCE_PAYLOAD_MASS, EffectDesign
from gsp_kinematics.model.effects import approach_directions
from gsp_kinematics.model.kinematics import inverse_kinematics


class ApproachTracker:
    """Approach directions of the postures commanded through ``nominal`` (a ``Geometry``)."""

    def __init__(self, nominal, initial=None):
        self.nominal = nominal
        self._legs = None  # (6,) commanded leg lengths where the platform stands, m
        self._directions = None if initial is None else np.asarray(initial, dtype=float)
        self._undo = None
        self.by_posture = {}  #: posture -> (6,) approach directions of its last command

    def command(self, posture, pose, standing_legs=None):
        """Note the command of ``posture`` (``pose`` (6,) m, rad); its directions (6,).
        ``standing_legs`` (6,): the leg lengths heard before it, for the run's first command
        (None: the first command's legs, so each leg keeps its initial direction)."""
        legs = inverse_kinematics(self.nominal, np.reshape(pose, (1, 6)))[0]
        previous = self._legs if self._legs is not None else standing_legs
        initial = self._directions
        if initial is not None and not np.all(np.abs(initial) == 1.0):
            initial = np.where(initial == 0.0, 1.0, initial)  # unknown: homed extending
        directions = approach_directions(legs[None], previous, initial)[0]
        self._undo = (int(posture), self._legs, self._directions)
        self._legs, self._directions = legs, directions
        self.by_posture[int(posture)] = directions
        return directions

    def rejected(self, posture):
        """The platform rejected ``posture`` (the last commanded): it stands where it was."""
        if self._undo is not None and self._undo[0] == int(posture):
            _, self._legs, self._directions = self._undo
            self._undo = None

    def directions(self, posture):
        """The directions (6,) of ``posture``'s last command, or None if never commanded."""
        return self.by_posture.get(int(posture))


def effect_design(samples, payload_mass=0.0, centre_of_mass=(0.0, 0.0, 0.0), leg_mass=None):
    """The ``EffectDesign`` of a run's rows (``files.run_directory.Rows``), the payload the user
    gave (kg; 0: unknown, the reference mass) and the legs' masses (6,) kg (None: massless); no
    directions when a row has none."""
    stamps = np.asarray(samples.stamps, dtype=float)
    times = stamps - stamps[0] if stamps.size else stamps
    directions = np.asarray(samples.directions, dtype=float)
    known = directions.size > 0 and bool(np.all(np.abs(directions) == 1.0))
    return EffectDesign(
        times_s=times,
        directions=directions if known else None,
        payload_mass=float(payload_mass) if payload_mass > 0.0 else REFERENCE_PAYLOAD_MASS,
        centre_of_mass=tuple(float(v) for v in centre_of_mass),
        reference_time_s=float(times[-1]) if times.size else 0.0,
        leg_mass=tuple(float(m) for m in (leg_mass if leg_mass is not None else [0.0] * 6)),
        payload_assumed=not payload_mass > 0.0,
    )


def reference_instant(samples):
    """The thermal reference instant of :func:`effect_design`: ``(s since the first row, the
    stamp, s)`` (the last row's)."""
    stamps = np.asarray(samples.stamps, dtype=float)
    if not stamps.size:
        return 0.0, 0.0
    return float(stamps[-1] - stamps[0]), float(stamps[-1])
