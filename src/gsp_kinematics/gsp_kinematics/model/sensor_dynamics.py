"""Sensor dynamics of a simulated device: first-order response and coloured noise (pure numpy)
(docs/sensor_errors.md)."""

import numpy as np

from ..rotation import wrap_angle


class SensorDynamicsError(ValueError):
    """A dynamics parameter is unusable; the message names it."""


def _times(values, name, n_channels):
    values = np.broadcast_to(np.asarray(values, dtype=float), (n_channels,)).copy()
    bad = ~(np.isfinite(values) & (values >= 0.0))
    if bad.any():
        raise SensorDynamicsError(
            f'{name} must be finite and >= 0 s, got {values.tolist()} (channel(s) '
            f'{np.flatnonzero(bad).tolist()})'
        )
    return values


def decay_factor(dt, time_constant):
    """``exp(-dt / time_constant)`` per channel (``dt`` s >= 0, ``time_constant`` (C,) s); 0
    where the time constant is 0 (no memory)."""
    time_constant = np.asarray(time_constant, dtype=float)
    with np.errstate(divide='ignore'):
        return np.where(
            time_constant > 0.0,
            np.exp(-dt / np.where(time_constant > 0.0, time_constant, 1.0)),
            0.0,
        )


class SensorDynamics:
    """First-order response and AR(1) noise of ``C`` channels, vectorised over leading axes:
    ``response_time``, ``correlation_time`` (C,) or scalars, s; ``circular`` (C,) bools, angles."""

    def __init__(self, response_time, correlation_time, n_channels, circular=None):
        self.n_channels = int(n_channels)
        self.response_time = _times(response_time, 'response time', self.n_channels)
        self.correlation_time = _times(correlation_time, 'noise correlation time', self.n_channels)
        circular = False if circular is None else circular
        self.circular = np.broadcast_to(np.asarray(circular, dtype=bool), (self.n_channels,)).copy()
        self.reset()

    @property
    def is_white_and_instant(self):
        """True when every time constant is 0 (the readings are true value + white noise)."""
        return not (self.response_time.any() or self.correlation_time.any())

    def reset(self):
        """Forget the state: the next step starts settled and stationary."""
        self._time = None
        self._response = None  # y, (..., C)
        self._noise = None  # z, (..., C), unit variance

    def step(self, time_s, true_values, stds, rng):
        """Readings (..., C) at ``time_s`` (s) of ``true_values`` (..., C) held since the previous
        step, noise stds ``stds`` (C,) drawn from ``rng``; a time not after the last one
        advances nothing."""
        true_values = np.asarray(true_values, dtype=float)
        draw = rng.normal(0.0, 1.0, size=true_values.shape)
        if self._time is None or self._response.shape != true_values.shape:
            self._response = true_values.copy()
            self._noise = draw
        else:
            dt = max(float(time_s) - self._time, 0.0)
            lag = decay_factor(dt, self.response_time)
            lagging = self._response - true_values
            lagging = np.where(self.circular, wrap_angle(lagging), lagging)
            self._response = true_values + lag * lagging
            memory = decay_factor(dt, self.correlation_time)
            self._noise = memory * self._noise + np.sqrt(1.0 - memory**2) * draw
        if self._time is None or float(time_s) > self._time:
            self._time = float(time_s)
        return self._response + self._noise * np.asarray(stds, dtype=float)
