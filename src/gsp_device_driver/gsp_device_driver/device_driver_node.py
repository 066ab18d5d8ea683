"""``device_driver`` node: publishes the measuring device's readings (see
docs/README_nodes_sim_driver.md).

On one timer it reads a :class:`~gsp_device_driver.backends.DeviceBackend` and publishes
``/gsp/device/inclinometer`` (alpha, beta), ``/gsp/device/encoder`` (phi) and ``/gsp/device/lvdt``
(d_m) with one shared stamp. The ``sim`` backend is fed ``/gsp/platform/true_pose``.
"""

import math

import numpy as np
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from sensor_msgs.msg import JointState

from gsp_kinematics.geometry import default_geometry_path
from gsp_msgs_py import checks, conversions, names, node_tools, qos
from gsp_msgs_py.node_tools import first_failed_check, is_finite_number, parameter_descriptor

from .backends import BackendError, backend_class, backend_names

#: Random stream of this node: platform_sim with the same ``seed`` draws independent noise.
RNG_STREAM = 2
WARN_THROTTLE_S = 1.0
DEFAULT_ANGLE_NOISE_STD = math.radians(0.001)  # rad (Table 3, first level)
DEFAULT_LENGTH_NOISE_STD = 1e-6  # m

#: Noise parameter -> keyword of DeviceBackend.update_noise.
NOISE_PARAMETERS = {
    'inclinometer_noise_std': 'inclinometer_std',
    'encoder_noise_std': 'encoder_std',
    'lvdt_noise_std': 'lvdt_std',
}


class ConfigurationError(node_tools.ConfigurationError):
    """A parameter value prevents the node from starting; the message names the parameter."""



#: name -> (test, requirement), at start-up and at run time.
_CHECKS = {
    'backend': (lambda v: bool(v.strip()), 'must name a backend'),
    'true_geometry_file': (lambda v: bool(v.strip()), 'must name a geometry file'),
    'publish_rate': (lambda v: is_finite_number(v) and v > 0.0, 'must be > 0 Hz'),
    'seed': (lambda v: v >= -1, 'must be >= 0, or -1 for a random seed'),
    'inclinometer_noise_std': (lambda v: is_finite_number(v) and v >= 0.0, 'must be >= 0 rad'),
    'encoder_noise_std': (lambda v: is_finite_number(v) and v >= 0.0, 'must be >= 0 rad'),
    'lvdt_noise_std': (lambda v: is_finite_number(v) and v >= 0.0, 'must be >= 0 m'),
    'frame_id': (lambda v: bool(v.strip()), 'must not be empty'),
}


def check_parameters(values):
    """Reason ('' if none) why a ``{name: value}`` of this node's parameters is invalid."""
    return first_failed_check(_CHECKS, values)


class DeviceDriverNode(Node):
    """Device driver; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_DEVICE_DRIVER, **kwargs)
        try:
            self._declare_parameters()
            values = {name: self.get_parameter(name).value for name in _CHECKS}
            reason = check_parameters(values)
            if reason:
                raise ConfigurationError(reason)
            backend_type = backend_class(values['backend'])
            extras = self._declare_backend_parameters(backend_type)
        except (InvalidParameterValueException, InvalidParameterTypeException,
                BackendError) as error:
            raise ConfigurationError(str(error)) from None
        seed = values['seed'] if values['seed'] >= 0 else np.random.SeedSequence().entropy
        try:
            self._backend = backend_type.from_config(
                true_geometry_file=values['true_geometry_file'],
                **{name: values[name] for name in NOISE_PARAMETERS},
                rng=np.random.default_rng([seed, RNG_STREAM]), **extras)
        except ValueError as error:  # BackendError, GeometryError
            raise ConfigurationError(f"backend '{values['backend']}': {error}") from None
        self._frame_id = values['frame_id']

        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # All callbacks in the node's default (mutually exclusive) group: no locking needed.
        self._reading_pubs = {
            topic: self.create_publisher(JointState, topic, qos.TOPIC_QOS[topic])
            for topic in (names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER, names.TOPIC_LVDT)
        }
        if self._backend.needs_true_pose:
            self.create_subscription(PoseStamped, names.TOPIC_TRUE_POSE, self._on_true_pose,
                                     qos.LATEST_STATE_QOS)
        self.create_timer(1.0 / values['publish_rate'], self._publish_readings)
        self.get_logger().info(
            f"device_driver ready: backend '{values['backend']}', publishing at "
            f"{values['publish_rate']:g} Hz, noise std inclinometer "
            f"{values['inclinometer_noise_std']:g} rad, encoder {values['encoder_noise_std']:g} "
            f"rad, lvdt {values['lvdt_noise_std']:g} m, seed {seed}")

    # ------------------------------------------------------------------------- parameters

    def _declare_parameters(self):
        self.declare_parameter('backend', 'sim', parameter_descriptor(
            f'Source of the readings: one of {", ".join(backend_names())}', read_only=True))
        self.declare_parameter(
            'true_geometry_file', default_geometry_path('true'), parameter_descriptor(
                'sim backend: geometry params file of the real platform; its device_length D0 and '
                'inclinometer_axes_angle gamma are used', read_only=True))
        self.declare_parameter('publish_rate', 200.0, parameter_descriptor(
            'Rate of the readings (Hz)', read_only=True, constraints='> 0'))
        self.declare_parameter('seed', 0, parameter_descriptor(
            'Seed of the noise generator; -1 = random', read_only=True,
            integer_range=(-1, 2**31 - 1)))
        self.declare_parameter(
            'inclinometer_noise_std', DEFAULT_ANGLE_NOISE_STD, parameter_descriptor(
                'Std of the Gaussian noise on alpha and beta (rad)', float_range=(0.0, 1.0)))
        self.declare_parameter('encoder_noise_std', DEFAULT_ANGLE_NOISE_STD, parameter_descriptor(
            'Std of the Gaussian noise on phi (rad)', float_range=(0.0, 1.0)))
        self.declare_parameter('lvdt_noise_std', DEFAULT_LENGTH_NOISE_STD, parameter_descriptor(
            'Std of the Gaussian noise on d_m (m)', float_range=(0.0, 1.0)))
        self.declare_parameter('frame_id', names.FRAME_BASE, parameter_descriptor(
            'Frame of the published readings, and required of true_pose', read_only=True))

    def _declare_backend_parameters(self, backend_type):
        """Declare ``<backend>.<name>`` for each extra parameter; ``{name: value}``."""
        extras = {}
        for spec in backend_type.PARAMETERS:
            full_name = f'{backend_type.name}.{spec.name}'
            self.declare_parameter(full_name, spec.default,
                                   parameter_descriptor(spec.description, read_only=True))
            extras[spec.name] = self.get_parameter(full_name).value
        return extras

    def _validate_parameters(self, parameters):
        """on-set callback: reject a bad value with the reason (nothing is applied here)."""
        values = {p.name: p.value for p in parameters}
        reason = check_parameters(values)
        if not reason and not self._backend.simulates_noise:
            changed = [name for name in values if name in NOISE_PARAMETERS]
            if changed:
                reason = (f"{', '.join(changed)}: the '{self._backend.name}' backend has no "
                          'simulated noise')
        return SetParametersResult(successful=not reason, reason=reason)

    def _apply_parameters(self, parameters):
        """post-set callback: apply the accepted noise levels."""
        noise = {NOISE_PARAMETERS[p.name]: p.value for p in parameters if p.name in NOISE_PARAMETERS}
        if noise:
            self._backend.update_noise(**noise)
            self.get_logger().info(f'noise std updated: {noise}')

    # -------------------------------------------------------------------------- callbacks

    def _on_true_pose(self, msg):
        try:
            self._backend.observe_true_pose(checks.pose_in_frame(msg, self._frame_id))
        except ValueError as error:
            self.get_logger().warning(f'ignoring true pose: {error}',
                                      throttle_duration_sec=WARN_THROTTLE_S)

    def _publish_readings(self):
        now = self.get_clock().now()
        now_s = now.nanoseconds * 1e-9
        try:
            sample = self._backend.read(now_s)
        except (BackendError, OSError, ValueError, RuntimeError) as error:
            self.get_logger().warning(f'device read failed: {error}',
                                      throttle_duration_sec=WARN_THROTTLE_S)
            return
        if sample is None:
            self.get_logger().info('waiting for the first device reading (true pose)',
                                   throttle_duration_sec=5.0)
            return
        stamp = now.to_msg() if sample.stamp_s == now_s else conversions.seconds_to_stamp(
            sample.stamp_s)
        try:
            messages = {
                names.TOPIC_INCLINOMETER: conversions.inclinometer_to_msg(
                    sample.alpha, sample.beta, stamp, self._frame_id),
                names.TOPIC_ENCODER: conversions.encoder_to_msg(sample.phi, stamp, self._frame_id),
                names.TOPIC_LVDT: conversions.lvdt_to_msg(sample.d_m, stamp, self._frame_id),
            }
        except ValueError as error:
            self.get_logger().warning(f'dropping device sample: {error}',
                                      throttle_duration_sec=WARN_THROTTLE_S)
            return
        for topic, msg in messages.items():
            self._reading_pubs[topic].publish(msg)

    def destroy_node(self):
        backend = getattr(self, '_backend', None)
        if backend is not None:
            backend.close()
        return super().destroy_node()


def main(args=None):
    """Console script ``device_driver``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(DeviceDriverNode, args, logger_name=names.NODE_DEVICE_DRIVER)


if __name__ == '__main__':
    raise SystemExit(main())
