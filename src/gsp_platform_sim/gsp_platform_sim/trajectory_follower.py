"""An emulated joint_trajectory_controller for six prismatic legs (pure numpy, no rclpy).

A trajectory is a list of points ``(time_from_start s, positions (6,) m)``. From the positions
it holds when the trajectory arrives, :class:`TrajectoryFollower` interpolates linearly to each
point in turn at its time, never faster than ``max_speed`` (m/s) per leg: a point asked for too
soon is reached late, as a real axis at its speed limit would.
"""

import numpy as np


class TrajectoryFollower:
    """Leg positions following the latest trajectory; times are s on one clock."""

    def __init__(self, initial_positions, max_speed):
        self.positions = np.asarray(initial_positions, dtype=float).copy()
        self.max_speed = float(max_speed)
        self._segments = []  # [(end time s, target (6,))] still to run
        self._segment_start = None  # (time s, positions) where the current segment began
        self._last_s = None

    @property
    def moving(self):
        return bool(self._segments)

    def set_trajectory(self, points, now_s):
        """Replace the trajectory: ``points`` ``[(time_from_start, positions)]`` from ``now_s``.

        ValueError (nothing changes) when a point has not 6 finite positions or the times
        do not increase.
        """
        segments, previous = [], -np.inf
        for time_from_start, positions in points:
            positions = np.asarray(positions, dtype=float)
            if positions.shape != (6,) or not np.all(np.isfinite(positions)):
                raise ValueError(f'a trajectory point needs 6 finite positions, got {positions}')
            if not time_from_start > previous:
                raise ValueError('trajectory point times must increase')
            previous = time_from_start
            segments.append((now_s + max(0.0, float(time_from_start)), positions))
        self.step(now_s)
        self._segments = segments
        self._segment_start = (now_s, self.positions.copy())

    def step(self, now_s):
        """Advance to ``now_s``; returns the positions (6,) m."""
        dt = 0.0 if self._last_s is None else max(0.0, now_s - self._last_s)
        self._last_s = now_s
        if not self._segments:
            return self.positions.copy()
        end_s, target = self._segments[0]
        start_s, start = self._segment_start
        if now_s >= end_s:
            reference = target
        else:
            fraction = (now_s - start_s) / (end_s - start_s)
            reference = start + fraction * (target - start)
        difference = reference - self.positions
        reach = self.max_speed * dt
        # Land exactly on the reference when it is within reach (a + (b - a) may miss b).
        self.positions = np.where(
            np.abs(difference) <= reach,
            reference,
            self.positions + np.clip(difference, -reach, reach),
        )
        if np.array_equal(self.positions, target):
            self._segments.pop(0)
            self._segment_start = (now_s, self.positions.copy())
        return self.positions.copy()

    def abort(self, positions):
        """Stop at ``positions`` (6,) m and drop the rest of the trajectory (a fault)."""
        self.positions = np.asarray(positions, dtype=float).copy()
        self._segments = []
