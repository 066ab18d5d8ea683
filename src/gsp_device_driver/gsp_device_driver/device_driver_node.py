"""``device_driver`` node: publishes the measuring device's readings (see docs/nodes.md)."""

import dataclasses

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState

from gsp_kinematics.channels import DEVICE_SENSORS, sensor_channel_names
from gsp_kinematics.model.device import SENSORS
from gsp_msgs_py import conversions, message_checks, names, node_tools, parameter_specs, qos
from gsp_msgs_py.diagnostics import Component, DiagnosticsPublisher
from gsp_msgs_py.noise_parameters import TRUE_NOISE_PARAMETER, noise_from_parameters
from gsp_msgs_py.parameter_specs import ParameterSpec, not_blank

from .backends import NOISE_PARAMETERS, BackendError, backend_class, backend_names

#: Random stream of this node: platform_sim with the same ``seed`` draws independent noise.
RNG_STREAM = 2
WARN_THROTTLE_S = 1.0

#: sim backend: each sensor's dynamics (docs/sensor_errors.md), s; 0 = instant / white.
DYNAMICS_PARAMETERS = tuple(
    f'{sensor}_{what}' for sensor in SENSORS for what in ('response_time', 'noise_correlation_time')
)


def _dynamics_spec(name):
    sensor, what = name.split('_', 1)
    description = (
        f'sim backend: first-order time constant of the {sensor} reading after a change '
        '(0: instant)'
        if what == 'response_time'
        else f'sim backend: correlation time of the {sensor} noise, a Gauss-Markov process whose '
        f'stationary std is {sensor}_noise_std (0: white)'
    )
    return parameter_specs.non_negative_spec(
        name, 0.0, description, 's', read_only=True, float_range=(0.0, 60.0)
    )


PARAMETERS = (
    ParameterSpec(
        'backend',
        'sim',
        f'Source of the readings: one of {", ".join(backend_names())}',
        read_only=True,
        check=not_blank('a backend'),
    ),
    parameter_specs.true_geometry_file_spec(
        'sim backend: geometry params file of the real platform; its device_length D0 '
        'and inclinometer_axes_angle gamma are used'
    ),
    parameter_specs.publish_rate_spec('the readings'),
    parameter_specs.seed_spec(),
    *(
        parameter_specs.true_noise_spec(
            sensor,
            f'sim backend: std of the Gaussian noise on {" and ".join(sensor_channel_names(sensor))}',
        )
        for sensor in DEVICE_SENSORS
    ),
    *(_dynamics_spec(name) for name in DYNAMICS_PARAMETERS),
    parameter_specs.frame_id_spec('Frame of the published readings, and required of true_pose'),
    parameter_specs.diagnostics_period_spec(),
)


def backend_parameters(backend_type):
    """The specs of a backend's extra parameters, as the node declares them: read-only
    ``<backend>.<name>``."""
    return tuple(
        dataclasses.replace(spec, name=f'{backend_type.name}.{spec.name}', read_only=True)
        for spec in backend_type.PARAMETERS
    )


def startup_line(values, seed, backend):
    """The node's start-up log line: what it publishes, and what the backend reads (a serial
    device has no simulated noise to report)."""
    line = (
        f"device_driver ready: backend '{values['backend']}', publishing at "
        f'{values["publish_rate"]:g} Hz, seed {seed}'
    )
    described = backend.describe()
    return f'{line}, {described}' if described else line


class DeviceDriverNode(Node):
    """Device driver; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_DEVICE_DRIVER, **kwargs)
        values = parameter_specs.declare_parameters(self, PARAMETERS)
        try:
            backend_type = backend_class(values['backend'])
        except BackendError as error:
            raise parameter_specs.ConfigurationError(str(error)) from None
        prefix = f'{backend_type.name}.'
        extras = {
            name[len(prefix) :]: value
            for name, value in parameter_specs.declare_parameters(
                self, backend_parameters(backend_type)
            ).items()
        }
        seed = parameter_specs.resolve_seed(values['seed'])
        try:
            self._backend = backend_type.from_config(
                true_geometry_file=values['true_geometry_file'],
                **{name: values[name] for name in (*NOISE_PARAMETERS, *DYNAMICS_PARAMETERS)},
                rng=np.random.default_rng([seed, RNG_STREAM]),
                # A backend receiving at its own pace stamps on this clock when a line arrives.
                stamp_clock=self._now_s,
                **extras,
            )
        except ValueError as error:  # BackendError, GeometryError
            raise parameter_specs.ConfigurationError(
                f"backend '{values['backend']}': {error}"
            ) from None
        self._frame_id = values['frame_id']
        parameter_specs.watch_parameters(
            self, PARAMETERS, apply=self._apply_noise, validate=self._check_noise_change
        )

        # All callbacks in the node's default (mutually exclusive) group: no locking needed.
        self._pubs = node_tools.create_publishers(self, node_tools.DEVICE_TOPICS)
        if self._backend.needs_true_pose:
            self.create_subscription(
                PoseStamped, names.TOPIC_TRUE_POSE, self._on_true_pose, qos.LATEST_STATE_QOS
            )
        if self._backend.needs_device_truth:
            self.create_subscription(
                JointState,
                names.TOPIC_DEVICE_TRUTH,
                self._on_device_truth,
                qos.SENSOR_SUBSCRIPTION_QOS,
            )
        self._timer = self.create_timer(1.0 / values['publish_rate'], self._publish_readings)
        self._diagnostics = DiagnosticsPublisher(
            self,
            values['diagnostics_period'],
            [Component('device', self._backend.hardware_id, self._backend.health)],
        )
        self.get_logger().info(startup_line(values, seed, self._backend))

    def _now_s(self):
        """The node's clock (s); thread-safe (read by a backend's reader thread)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _check_noise_change(self, changes, current):
        """Run-time check: only a backend that simulates noise takes new noise levels."""
        changed = [name for name in changes if name in NOISE_PARAMETERS]
        if changed and not self._backend.simulates_noise:
            return (
                f"{', '.join(changed)}: the '{self._backend.name}' backend has no simulated noise"
            )
        return ''

    def _apply_noise(self, changes):
        """Apply accepted noise levels (checked by parameter_specs.watch_parameters)."""
        if any(name in NOISE_PARAMETERS for name in changes):
            noise = noise_from_parameters(changes, TRUE_NOISE_PARAMETER, self._backend.noise)
            self._backend.update_noise(noise)
            self.get_logger().info(f'noise std updated: {self._backend.describe()}')

    def _on_true_pose(self, msg):
        try:
            self._backend.observe_true_pose(message_checks.pose_in_frame(msg, self._frame_id))
        except ValueError as error:
            self.get_logger().warning(
                f'ignoring true pose: {error}', throttle_duration_sec=WARN_THROTTLE_S
            )

    def _on_device_truth(self, msg):
        try:
            if msg.header.frame_id != self._frame_id:
                raise ValueError(f"frame '{msg.header.frame_id}' is not '{self._frame_id}'")
            self._backend.observe_device_truth(
                conversions.stamp_to_seconds(msg.header.stamp), conversions.msg_to_device_truth(msg)
            )
        except ValueError as error:
            self.get_logger().warning(
                f'ignoring device truth: {error}', throttle_duration_sec=WARN_THROTTLE_S
            )

    def _publish_readings(self):
        # A backend sampling at the timer (sim) reads the instant of the scheduled tick: the
        # callback's delay would jitter its stamps against the leg lengths'.
        if self._backend.samples_at_tick:
            now = node_tools.timer_tick_time(self, self._timer)
        else:
            now = self.get_clock().now()
        now_s = now.nanoseconds * 1e-9
        try:
            samples = self._backend.read_available(now_s)
        except (BackendError, OSError, ValueError, RuntimeError) as error:
            self.get_logger().warning(
                f'device read failed: {error}', throttle_duration_sec=WARN_THROTTLE_S
            )
            return
        for level, text in self._backend.messages():
            # One call site per severity: rclpy refuses a severity change at one call site.
            if level == 'warning':
                self.get_logger().warning(text)
            else:
                self.get_logger().info(text)
        if not samples:
            if self._backend.needs_true_pose:
                self.get_logger().info(
                    'waiting for the first device reading (true pose)', throttle_duration_sec=5.0
                )
            return
        for sample in samples:
            stamp = (
                now.to_msg()
                if sample.stamp_s == now_s
                else conversions.seconds_to_stamp(sample.stamp_s)
            )
            node_tools.publish_messages(
                self, self._pubs, 'device sample', self._sample_messages, sample, stamp
            )

    def _sample_messages(self, sample, stamp):
        return node_tools.device_messages(sample.readings(), stamp, self._frame_id)

    def destroy_node(self):
        node_tools.close_opened(self, '_backend')
        return super().destroy_node()


def main(args=None):
    """Console script ``device_driver``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(DeviceDriverNode, args, logger_name=names.NODE_DEVICE_DRIVER)


if __name__ == '__main__':
    raise SystemExit(main())
