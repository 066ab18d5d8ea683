"""The noise of the measuring sensors: one type, :class:`SensorNoise`, and its conversions."""

import dataclasses
import math

import numpy as np

from gsp_kinematics import channels

#: The fields of :class:`SensorNoise`: the sensors of :data:`gsp_kinematics.channels.CHANNELS`.
NOISE_FIELDS = channels.SENSORS
#: Each field's SI unit (its channels' unit).
NOISE_UNITS = {channel.sensor: channel.unit for channel in channels.CHANNELS}


class SensorNoiseError(ValueError):
    """A noise value or record is unusable; the message names it."""


@dataclasses.dataclass(frozen=True)
class SensorNoise:
    """Standard deviation of one sample of each sensor (m, rad); also the residual weights."""

    leg_lengths: float = 1e-6
    inclinometer: float = math.radians(0.001)
    encoder: float = math.radians(0.001)
    lvdt: float = 1e-6

    def validate(self):
        """SensorNoiseError unless every standard deviation is positive and finite."""
        for name, value in self.channels().items():
            if not (math.isfinite(value) and value > 0.0):
                raise SensorNoiseError(f'sigma for {name} must be positive and finite, got {value}')

    # --- channels ------------------------------------------------------------------------------

    def readings(self):
        """Standard deviations of the device readings ``[alpha, beta, phi, d_m]`` (4,)."""
        return np.array([getattr(self, channel.sensor) for channel in channels.DEVICE_CHANNELS])

    def channel_std(self):
        """The collector's ten channel standard deviations ``[q_1..q_6, alpha, beta, phi, d_m]``."""
        return np.array([getattr(self, channel.sensor) for channel in channels.CHANNELS])

    def channels(self):
        """``{field: std}`` in :data:`NOISE_FIELDS` order."""
        return {name: float(getattr(self, name)) for name in NOISE_FIELDS}

    @classmethod
    def from_channels(cls, values, default=None):
        """From ``{field: std}`` (e.g. a noise estimate); a missing or None field is taken from
        ``default`` (a :class:`SensorNoise`; SensorNoiseError if there is none)."""
        fields = {}
        for name in NOISE_FIELDS:
            value = values.get(name)
            if value is None:
                if default is None:
                    raise SensorNoiseError(f'no noise value for {name}')
                value = getattr(default, name)
            fields[name] = float(value)
        return cls(**fields)

    def averaged(self, n_samples):
        """The noise of rows that average ``n_samples`` samples each: ``sigma / sqrt(n)`` with
        the median ``n`` (unchanged when ``n_samples`` is empty or holds a count below 1)."""
        n_samples = np.asarray(n_samples, dtype=float)
        if n_samples.size == 0 or not np.all(n_samples >= 1):
            return self
        factor = 1.0 / math.sqrt(float(np.median(n_samples)))
        return SensorNoise(**{name: value * factor for name, value in self.channels().items()})


#: The suite's default noise: Table 3's first level (0.001 deg, 0.001 mm) on every sensor.
DEFAULT_SENSOR_NOISE = SensorNoise()
#: No noise at all (a simulated sensor's default when no noise is given).
NO_NOISE = SensorNoise(0.0, 0.0, 0.0, 0.0)
