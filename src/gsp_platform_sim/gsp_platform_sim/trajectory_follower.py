"""An emulated joint_trajectory_controller for six prismatic legs (pure numpy, no rclpy)."""

import numpy as np

from gsp_kinematics.model.motion import LegMove


class TrajectoryFollower:
    """Leg positions following the latest trajectory; times are s on one clock; ``limits`` a
    :class:`gsp_kinematics.model.motion.MotionLimits`."""

    def __init__(self, initial_positions, limits):
        self.positions = np.asarray(initial_positions, dtype=float).copy()
        self.limits = limits
        self._points = []  # [(time s, target (6,))] still to reach
        self._move = None  # LegMove toward the first point

    def set_trajectory(self, points, now_s):
        """Replace the trajectory: ``points`` ``[(time_from_start, positions)]`` from ``now_s``."""
        targets, previous = [], -np.inf
        for time_from_start, positions in points:
            positions = np.asarray(positions, dtype=float)
            if positions.shape != (6,) or not np.all(np.isfinite(positions)):
                raise ValueError(f'a trajectory point needs 6 finite positions, got {positions}')
            if not time_from_start > previous:
                raise ValueError('trajectory point times must increase')
            previous = time_from_start
            targets.append((now_s + max(0.0, float(time_from_start)), positions))
        self.step(now_s)
        self._points = targets
        self._start_move(now_s)

    def _start_move(self, start_s):
        if not self._points:
            self._move = None
            return
        time_s, target = self._points[0]
        self._move = LegMove(self.positions, target, self.limits, start_s, time_s - start_s)

    def step(self, now_s):
        """Advance to ``now_s``; returns the positions (6,) m."""
        while self._move is not None and now_s >= self._move.end_s:
            # Arrived at this point: the next move starts when this one ended.
            self.positions = self._move.end.copy()
            self._points.pop(0)
            self._start_move(self._move.end_s)
        if self._move is not None:
            self.positions = self._move.legs(now_s)
        return self.positions.copy()

    def abort(self, positions):
        """Stop at ``positions`` (6,) m and drop the rest of the trajectory (a fault)."""
        self.positions = np.asarray(positions, dtype=float).copy()
        self._points = []
        self._move = None
