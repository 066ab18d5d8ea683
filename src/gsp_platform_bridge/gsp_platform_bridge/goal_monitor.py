"""When a ros2_control goal is reached, from the controller's joint states (pure, no rclpy)."""

import numpy as np

from gsp_kinematics.model.motion import move_time
from gsp_msgs_py.health import ERROR, OK, Health
from gsp_msgs_py.names import STATE_REJECTED, STATE_SETTLED


class GoalMonitor:
    """Goal and joint-state bookkeeping of the bridge; one goal at a time."""

    def __init__(self, joint_names, position_tolerance, settle_time, state_timeout):
        self.joint_names = tuple(joint_names)
        self.position_tolerance = float(position_tolerance)
        self.settle_time = float(settle_time)
        self.state_timeout = float(state_timeout)
        self.positions = None  # (6,) m, latest complete joint state
        self.missing = ()  # leg joints absent from the latest joint state
        self.last_state_s = None
        self._target = None
        self._deadline_s = None
        self._within_since = None

    def observe(self, names, positions, now_s):
        """A joint state (names, positions) received at ``now_s``; returns the leg positions
        (6,) in :attr:`joint_names` order, or None when a leg joint is missing (see
        :attr:`missing`). Other joints are ignored."""
        by_name = dict(zip(names, positions, strict=False))
        self.last_state_s = now_s
        self.missing = tuple(name for name in self.joint_names if name not in by_name)
        if self.missing:
            return None
        values = np.array([by_name[name] for name in self.joint_names], dtype=float)
        if not np.all(np.isfinite(values)):
            self.missing = tuple(
                name for name, v in zip(self.joint_names, values, strict=True) if not np.isfinite(v)
            )
            return None
        self.positions = values
        if self._target is not None:  # the settle clock runs from the first state within
            if np.all(np.abs(values - self._target) <= self.position_tolerance):
                if self._within_since is None:
                    self._within_since = now_s
            else:
                self._within_since = None
        return values.copy()

    def state_problem(self, now_s):
        """Why the joint states cannot be trusted at ``now_s`` ('' when they can)."""
        if self.last_state_s is None:
            return 'no /joint_states received from the controller'
        age = now_s - self.last_state_s
        if age > self.state_timeout:
            return f'stale /joint_states: the last one is {age:.2f} s old (state_timeout {self.state_timeout:g} s)'
        if self.missing:
            return f'joint {", ".join(self.missing)} missing from /joint_states (or not finite)'
        if self.positions is None:
            return 'no complete /joint_states yet'
        return ''

    def health(self, now_s):
        """The controller's ``Health`` at ``now_s``: ERROR while :meth:`state_problem` says the
        joint states cannot be trusted (commands are then rejected), else OK."""
        age = '' if self.last_state_s is None else f'{now_s - self.last_state_s:.3f}'
        values = {
            'joint_states_age_s': age,
            'state_timeout_s': f'{self.state_timeout:g}',
            'missing_joints': ', '.join(self.missing),
            'goal_active': str(self.active).lower(),
        }
        problem = self.state_problem(now_s)
        if problem:
            return Health(ERROR, problem, values)
        return Health(OK, 'moving to a goal' if self.active else 'joint states fresh', values)

    @property
    def active(self):
        return self._target is not None

    def start(self, target, deadline_s):
        """Track a goal: leg targets (6,) m, to be settled by ``deadline_s``."""
        self._target = np.asarray(target, dtype=float).copy()
        self._deadline_s = float(deadline_s)
        self._within_since = None  # set by the next joint state within tolerance

    def clear(self):
        self._target = None

    def check(self, now_s):
        """``(STATE_SETTLED, '')``, ``(STATE_REJECTED, reason)`` or None (still moving) for the goal at
        ``now_s``; the goal ends with a verdict."""
        if self._target is None:
            return None
        problem = self.state_problem(now_s)
        if problem:
            self.clear()
            return STATE_REJECTED, problem
        errors = np.abs(self.positions - self._target)
        if self._within_since is not None and now_s - self._within_since >= self.settle_time:
            self.clear()
            return STATE_SETTLED, ''
        if now_s > self._deadline_s:
            worst = int(np.argmax(errors))
            self.clear()
            return STATE_REJECTED, (
                f'goal not reached in time: {self.joint_names[worst]} is '
                f'{errors[worst] * 1e3:.3f} mm from its target (tolerance '
                f'{self.position_tolerance * 1e3:g} mm)'
            )
        return None


def pose_path(start, goal, position_step, angle_step):
    """Poses (N, 6) from ``start`` (excluded) to ``goal`` (included) on the straight line in
    ``[x, y, z, psi, theta, phi]``, no step longer than ``position_step`` (m) or ``angle_step``
    (rad), so the legs follow the Cartesian path."""
    start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
    delta = goal - start
    steps = max(
        1,
        int(np.ceil(np.linalg.norm(delta[:3]) / position_step)),
        int(np.ceil(np.max(np.abs(delta[3:])) / angle_step)),
    )
    fractions = np.arange(1, steps + 1)[:, None] / steps
    return start[None] + fractions * delta[None]


def waypoint_times(current, waypoints, limits, min_duration):
    """``time_from_start`` (N,) s of leg waypoints (N, 6) m from ``current`` (6,): rest-to-rest
    moves at the legs' ``limits`` (``MotionLimits``), the whole at least ``min_duration`` (s)."""
    legs = np.vstack([np.asarray(current, dtype=float)[None], np.asarray(waypoints, dtype=float)])
    times = np.cumsum(move_time(legs[:-1], legs[1:], limits))
    if times[-1] < min_duration:
        times = (
            times * (min_duration / times[-1])
            if times[-1] > 0
            else np.linspace(min_duration / len(times), min_duration, len(times))
        )
    # Strictly increasing (a waypoint with no leg move still takes a little time).
    return np.maximum.accumulate(times + np.arange(len(times)) * 1e-6)
