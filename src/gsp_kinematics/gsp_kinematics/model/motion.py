"""How long the platform takes to move between postures, and how its legs move (pure numpy)
(docs/planning.md)."""

import dataclasses
import math

import numpy as np

from .kinematics import inverse_kinematics

#: The sensors' default publish rate (Hz): the simulated nodes' ``publish_rate`` and the rate a
#: plan's dwell at a posture assumes when none was measured.
DEFAULT_SENSOR_RATE_HZ = 200.0
#: Synchronised pairs averaged per posture by default (the calibrator's ``pairs_per_posture``).
DEFAULT_PAIRS_PER_POSTURE = 10

#: Leg speed limit (m/s) of a positioning hexapod: the order of magnitude of the maximum
#: platform speeds in PI (Physik Instrumente) and Symetrie hexapod datasheets, tens of mm/s
#: (docs/planning.md); not the figure of one particular model.
REALISTIC_MAX_SPEED = 0.05
#: Leg acceleration limit (m/s^2): full speed in 0.25 s. Datasheets rarely state it; an
#: assumption of the same order as the speed, not a datasheet figure.
REALISTIC_MAX_ACCELERATION = 0.2


@dataclasses.dataclass(frozen=True)
class MotionLimits:
    """Per-leg speed (m/s) and acceleration (m/s^2) limits; ``inf`` removes a limit (both:
    a move is instantaneous, the platform jumps)."""

    max_speed: float = REALISTIC_MAX_SPEED
    max_acceleration: float = REALISTIC_MAX_ACCELERATION

    def __post_init__(self):
        for name in ('max_speed', 'max_acceleration'):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value > 0 and not math.isnan(value)):
                raise ValueError(f'{name} must be a number > 0 (inf: no limit), got {value!r}')

    @classmethod
    def from_parameters(cls, max_speed, max_acceleration):
        """From node parameters, where 0 means "no limit"."""
        return cls(max_speed or math.inf, max_acceleration or math.inf)

    @property
    def instantaneous(self):
        return math.isinf(self.max_speed) and math.isinf(self.max_acceleration)


def leg_travel_time(distance, limits):
    """Time (s) for one leg to travel ``distance`` (m, array, >= 0) from rest to rest."""
    distance = np.abs(np.asarray(distance, dtype=float))
    speed, acceleration = limits.max_speed, limits.max_acceleration
    if math.isinf(acceleration):
        return distance / speed  # a pure speed limit (0 when both are infinite)
    if math.isinf(speed):
        return 2.0 * np.sqrt(distance / acceleration)
    # Trapezoid when the leg reaches full speed, triangle otherwise.
    cruise = distance >= speed * speed / acceleration
    with np.errstate(invalid='ignore'):
        return np.where(
            cruise, distance / speed + speed / acceleration, 2.0 * np.sqrt(distance / acceleration)
        )


def move_time(start_legs, end_legs, limits):
    """Synchronised move time (s) from ``start_legs`` to ``end_legs`` (..., 6) m: the slowest
    leg's; broadcasts (``move_time(q[:, None], q[None], limits)``: the (N, N) matrix of a set)."""
    distance = np.max(np.abs(np.asarray(end_legs) - np.asarray(start_legs)), axis=-1)
    return leg_travel_time(distance, limits)


def profile_fraction(elapsed, distance, limits):
    """Fraction ``s`` in [0, 1] of a move of the slowest leg over ``distance`` m, ``elapsed`` s
    after it started (time-optimal trapezoid or triangle)."""
    elapsed = np.asarray(elapsed, dtype=float)
    if distance <= 0.0:
        return np.ones_like(elapsed)
    total = float(leg_travel_time(distance, limits))
    if total <= 0.0:
        return np.ones_like(elapsed)
    speed, acceleration = limits.max_speed, limits.max_acceleration
    t = np.clip(elapsed, 0.0, total)
    if math.isinf(acceleration):
        return t / total
    # The peak speed: the limit, or that of the triangle.
    peak = min(speed, math.sqrt(distance * acceleration))
    ramp = peak / acceleration
    accelerating = 0.5 * acceleration * t * t
    cruising = 0.5 * acceleration * ramp * ramp + peak * (t - ramp)
    remaining = total - t
    braking = distance - 0.5 * acceleration * remaining * remaining
    travelled = np.where(t < ramp, accelerating, np.where(t <= total - ramp, cruising, braking))
    return np.clip(travelled / distance, 0.0, 1.0)


class LegMove:
    """A synchronised move of the six legs from ``start`` to ``end`` (6,) m, starting at
    ``start_s``; ``duration`` (s) may stretch it beyond the limits' minimum (a trajectory point
    asked for later): the profile is then slowed in time, so it stays within the limits."""

    def __init__(self, start, end, limits, start_s=0.0, duration=None):
        self.start = np.asarray(start, dtype=float).copy()
        self.end = np.asarray(end, dtype=float).copy()
        self.limits = limits
        self.start_s = float(start_s)
        self._distance = float(np.max(np.abs(self.end - self.start)))
        self.minimum_s = float(leg_travel_time(self._distance, limits))
        self.duration_s = self.minimum_s if duration is None else max(self.minimum_s, duration)

    @property
    def end_s(self):
        return self.start_s + self.duration_s

    def fraction(self, now_s):
        """The common fraction ``s`` in [0, 1] of the move at ``now_s``."""
        if now_s >= self.end_s or self.duration_s <= 0.0:
            return 1.0
        stretch = self.minimum_s / self.duration_s
        return float(
            profile_fraction((now_s - self.start_s) * stretch, self._distance, self.limits)
        )

    def legs(self, now_s):
        """Leg lengths (6,) m at ``now_s`` (exactly ``end`` once arrived)."""
        fraction = self.fraction(now_s)
        if fraction >= 1.0:
            return self.end.copy()
        return self.start + fraction * (self.end - self.start)


def posture_leg_lengths(geometry, poses):
    """The leg readings (N, 6) m a controller with ``geometry`` commands for ``poses`` (N, 6)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    return geometry.sensors.leg_readings(inverse_kinematics(geometry, poses))
