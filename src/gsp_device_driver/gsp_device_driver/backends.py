"""Sources of measuring device readings (pure, no rclpy): ``sim``, ``physics`` and ``serial``.

A new backend subclasses :class:`.device_backend.DeviceBackend` with a ``from_config(**config)``
classmethod (its extra parameters as ``PARAMETERS``, declared read-only as ``<backend>.<name>``;
unused keys ignored) and is added to :data:`_BACKENDS`.
"""

import collections
import math

import numpy as np

from gsp_kinematics import channels
from gsp_kinematics.model.device import (
    READING_NAMES,
    SENSORS,
    DeviceModelError,
    device_readings,
    per_reading,
)
from gsp_kinematics.model.geometry import Geometry, SensorErrors, load_geometry
from gsp_kinematics.model.sensor_dynamics import SensorDynamics
from gsp_kinematics.model.sensor_noise import NO_NOISE, NOISE_UNITS
from gsp_msgs_py.health import OK, WARN, Health
from gsp_msgs_py.noise_parameters import (
    TRUE_NOISE_PARAMETER,
    noise_from_parameters,
    noise_parameter_names,
)

from .device_backend import BackendError, DeviceBackend, DeviceSample
from .serial_backend import SerialDeviceBackend

#: The device sensors' true noise parameters (``inclinometer_noise_std``...).
NOISE_PARAMETERS = noise_parameter_names(TRUE_NOISE_PARAMETER, channels.DEVICE_SENSORS)


class SimDeviceBackend(DeviceBackend):
    """Simulated device: readings of the latest true pose through each sensor's dynamics, + noise.

    ``sensors``: the real device's ``SensorErrors`` (None: ideal); ``response_times`` and
    ``correlation_times`` (s): ``(inclinometer, encoder, lvdt)``, 0 for instant/white.
    """

    name = 'sim'
    needs_true_pose = True
    simulates_noise = True
    samples_at_tick = True

    def __init__(
        self,
        device_length,
        inclinometer_axes_angle,
        noise=NO_NOISE,
        rng=None,
        sensors=None,
        response_times=(0.0, 0.0, 0.0),
        correlation_times=(0.0, 0.0, 0.0),
    ):
        # device_readings needs only D0 and gamma (checked by load_geometry) of a Geometry.
        self._device = Geometry(
            base_joints=np.zeros((6, 3)),
            platform_joints=np.zeros((6, 3)),
            leg_offsets=np.zeros(6),
            device_length=float(device_length),
            inclinometer_axes_angle=float(inclinometer_axes_angle),
            sensors=sensors if sensors is not None else SensorErrors(),
        )
        self.update_noise(noise)
        try:
            self._dynamics = SensorDynamics(
                per_reading(*response_times),
                per_reading(*correlation_times),
                len(READING_NAMES),
                circular=[channel.circular for channel in channels.DEVICE_CHANNELS],
            )
        except ValueError as error:
            raise BackendError(str(error)) from None
        self._rng = rng if rng is not None else np.random.default_rng()
        self._pose = None
        self._exact = None  # cached noise-free readings of self._pose
        # For health(): readings taken, true poses taken and refused; at the previous report.
        self._counts = dict.fromkeys(('readings', 'true_poses', 'true_poses_refused'), 0)
        self._reported = (dict(self._counts), None)  # counts and the latest reading's time
        self._latest_s = None  # time (s) of the latest reading

    @classmethod
    def from_config(cls, true_geometry_file, rng=None, **config):
        """From the true geometry file (D0, gamma, sensor errors) and the node's
        ``*_noise_std``, ``*_response_time`` and ``*_noise_correlation_time`` parameters."""
        geometry = load_geometry(true_geometry_file)
        return cls(
            geometry.device_length,
            geometry.inclinometer_axes_angle,
            noise_from_parameters(config, TRUE_NOISE_PARAMETER, NO_NOISE),
            rng=rng,
            sensors=geometry.sensors,
            response_times=[config.get(f'{sensor}_response_time', 0.0) for sensor in SENSORS],
            correlation_times=[
                config.get(f'{sensor}_noise_correlation_time', 0.0) for sensor in SENSORS
            ],
        )

    def update_noise(self, noise):
        for sensor in channels.DEVICE_SENSORS:
            std = float(getattr(noise, sensor))
            if not (math.isfinite(std) and std >= 0.0):
                name = TRUE_NOISE_PARAMETER.format(sensor)
                raise BackendError(f'{name} must be finite and >= 0, got {std}')
        self.noise = noise  #: the true noise drawn (a ``SensorNoise``, rad and m)

    def observe_true_pose(self, pose):
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (6,) or not np.all(np.isfinite(pose)):
            raise ValueError(f'true pose must be 6 finite values, got {pose.tolist()}')
        if self._pose is None or not np.array_equal(pose, self._pose):
            try:
                ideal = device_readings(self._device, pose[None])[0]
                exact = self._device.sensors.device_readings(ideal)
            except DeviceModelError as error:
                self._counts['true_poses_refused'] += 1
                raise ValueError(
                    f'no device reading for true pose {pose.tolist()}: {error}'
                ) from None
            self._exact, self._pose = exact, pose
        self._counts['true_poses'] += 1

    def describe(self):
        line = 'noise std ' + ', '.join(
            f'{sensor} {getattr(self.noise, sensor):g} {NOISE_UNITS[sensor]}'
            for sensor in channels.DEVICE_SENSORS
        )
        if self._dynamics.is_white_and_instant:
            return line
        tau, tc = self._dynamics.response_time, self._dynamics.correlation_time
        for sensor, (column, *_) in SENSORS.items():
            line += f', {sensor} response {tau[column]:g} s, noise correlation {tc[column]:g} s'
        return line

    def read_available(self, now_s):
        sample = self.read(now_s)
        return [] if sample is None else [sample]

    def read(self, now_s):
        """The sample of the latest true pose at ``now_s`` (s), or None before the first."""
        if self._exact is None:
            return None
        values = self._dynamics.step(now_s, self._exact, self.noise.readings(), self._rng)
        self._counts['readings'] += 1
        if self._latest_s is None:  # the first reading opens the first window of the rate
            self._reported[0]['readings'] = self._counts['readings']
            self._reported = (self._reported[0], float(now_s))
        self._latest_s = float(now_s)
        return DeviceSample(float(now_s), *(float(v) for v in values))

    def health(self):
        """OK while readings of fresh true poses flow. WARN before the first true pose, and when
        no true pose came since the previous report (the readings repeat the last one: is
        platform_sim running?). Keys: counts, reading rate, noise stds."""
        (before, before_s), counts = self._reported, dict(self._counts)
        self._reported = (counts, self._latest_s)
        new = {key: counts[key] - before[key] for key in counts}
        span_s = self._latest_s - before_s if before_s is not None else 0.0
        rate = (new['readings'] / span_s) if span_s > 0 else 0.0
        values = {
            **counts,
            'reading_rate_hz': f'{rate:.1f}',
            **{
                f'{name}_{NOISE_UNITS[sensor]}': f'{getattr(self.noise, sensor):.6g}'
                for sensor, name in zip(channels.DEVICE_SENSORS, NOISE_PARAMETERS, strict=True)
            },
        }
        if self._exact is None:
            return Health(WARN, 'waiting for the first true pose', values)
        if new['true_poses'] == 0:
            return Health(
                WARN, 'no true pose since the last report: readings of a stale pose', values
            )
        return Health(OK, f'simulating readings at {rate:.1f} Hz', values)


class PhysicsDeviceBackend(SimDeviceBackend):
    """The ``sim`` backend fed the physics' own readings of the device (each with its stamp)
    instead of the true pose: every reading received is published once, through the real
    device's sensor errors, dynamics and noise."""

    name = 'physics'
    needs_true_pose = False
    needs_device_truth = True
    samples_at_tick = False
    #: Readings kept between two ticks (s of readings at 1 kHz); older ones are dropped.
    MAX_PENDING = 1000

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._pending = collections.deque(maxlen=self.MAX_PENDING)

    def observe_device_truth(self, stamp_s, readings):
        readings = np.asarray(readings, dtype=float)
        if readings.shape != (len(READING_NAMES),) or not np.all(np.isfinite(readings)):
            self._counts['true_poses_refused'] += 1
            raise ValueError(f'device readings must be 4 finite values, got {readings.tolist()}')
        self._pending.append((float(stamp_s), self._device.sensors.device_readings(readings)))
        self._counts['true_poses'] += 1
        self._exact = self._pending[-1][1]

    def read_available(self, now_s):
        samples = []
        while self._pending:
            stamp_s, exact = self._pending.popleft()
            values = self._dynamics.step(stamp_s, exact, self.noise.readings(), self._rng)
            self._counts['readings'] += 1
            if self._latest_s is None:
                self._reported = (dict(self._counts), stamp_s)
            self._latest_s = stamp_s
            samples.append(DeviceSample(stamp_s, *(float(v) for v in values)))
        return samples


_BACKENDS = {
    backend.name: backend
    for backend in (SimDeviceBackend, PhysicsDeviceBackend, SerialDeviceBackend)
}


def backend_names():
    """Names of the available backends, sorted."""
    return tuple(sorted(_BACKENDS))


def backend_class(name):
    """The backend class called ``name``; BackendError naming the valid backends otherwise."""
    try:
        return _BACKENDS[name]
    except KeyError:
        raise BackendError(
            f"unknown device backend '{name}'; valid backends: {', '.join(backend_names())}"
        ) from None


__all__ = [
    'READING_NAMES',
    'BackendError',
    'DeviceBackend',
    'DeviceSample',
    'PhysicsDeviceBackend',
    'SimDeviceBackend',
    'backend_class',
    'backend_names',
]
