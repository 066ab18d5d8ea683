"""The interface of a source of measuring device readings (pure, no rclpy); backends: :mod:`.backends`."""

import abc
import dataclasses

import numpy as np

from gsp_msgs_py.health import WARN, Health


class BackendError(ValueError):
    """A backend cannot be made or configured; the message says why."""


@dataclasses.dataclass(frozen=True)
class DeviceSample:
    """One reading of the device: ``stamp_s`` (s, the instant it refers to), ``alpha``, ``beta``
    (inclinometer, rad), ``phi`` (encoder, rad), ``d_m`` (LVDT, m)."""

    stamp_s: float
    alpha: float
    beta: float
    phi: float
    d_m: float

    def readings(self):
        """``[alpha, beta, phi, d_m]`` (4,) in ``gsp_kinematics.model.device.READING_NAMES`` order."""
        return np.array([self.alpha, self.beta, self.phi, self.d_m])


class DeviceBackend(abc.ABC):
    """Interface of a source of device readings."""

    #: Registry name (``sim``, ``hardware``...).
    name = ''
    #: Whether the node must feed it ``/gsp/platform/true_pose`` via :meth:`observe_true_pose`.
    needs_true_pose = False
    #: Whether the node must feed it ``/gsp/platform/device_truth`` (:meth:`observe_device_truth`).
    needs_device_truth = False
    #: Whether :meth:`update_noise` is supported (the noise parameters can change at run time).
    simulates_noise = False
    #: Whether a reading is taken at the node's publish timer (``now_s``: the scheduled tick), not
    #: received at the device's own pace.
    samples_at_tick = False
    #: Extra parameters of the backend (``ParameterSpec``).
    PARAMETERS = ()

    @classmethod
    @abc.abstractmethod
    def from_config(cls, **config):
        """Make the backend from the node's configuration (ignore unused keys)."""

    @abc.abstractmethod
    def read_available(self, now_s):
        """Every sample available at ``now_s`` (s), each once: a list, maybe empty."""

    def messages(self):
        """``[(level, text)]`` to log (``info`` or ``warning``) since the last call."""
        return []

    def describe(self):
        """One line for the node's start-up log: what the backend reads and how."""
        return ''

    def observe_true_pose(self, pose):
        """Ground-truth platform pose (6,) ``[x, y, z, psi, theta, phi]``; simulators only."""
        return None

    def observe_device_truth(self, stamp_s, readings):
        """Noise-free readings (4,) at ``stamp_s`` (s); physics simulators only (ValueError if
        unusable)."""
        return None

    def update_noise(self, noise):
        """Change the simulated true noise to ``noise`` (a ``SensorNoise``; its device sensors)."""
        raise BackendError(f"the '{self.name}' device backend has no simulated noise to change")

    def close(self):
        """Release the device (files, ports). Idempotent."""
        return None

    @property
    def hardware_id(self):
        """The ``hardware_id`` of the backend's status on ``/diagnostics``."""
        return self.name

    def health(self):
        """The device's :class:`~gsp_msgs_py.health.Health` since the previous call."""
        return Health(WARN, f"the '{self.name}' device backend reports no health")
