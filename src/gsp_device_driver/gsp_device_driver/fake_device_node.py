"""``gsp_fake_device``: the device's microcontroller, emulated on a pty (docs/hardware.md)."""

import argparse
import time

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node

from gsp_kinematics.channels import DEVICE_SENSORS
from gsp_kinematics.model.geometry import default_geometry_path
from gsp_kinematics.model.motion import DEFAULT_SENSOR_RATE_HZ
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, NOISE_UNITS
from gsp_msgs_py import conversions, message_checks, names, node_tools, parameter_specs, qos

from .backends import SimDeviceBackend
from .device_driver_node import DYNAMICS_PARAMETERS, NOISE_PARAMETERS, RNG_STREAM
from .fake_device import HELLO_PERIOD_S, FakeDevice, TruthFeed
from .serial_protocol import ANGLE_UNITS, LENGTH_UNITS

NODE_NAME = 'fake_device'


def parse_arguments(argv=None):
    parser = argparse.ArgumentParser(
        prog='gsp_fake_device',
        description='Emulate the measuring device on a pty, from /gsp/platform/true_pose.',
    )
    add = parser.add_argument
    add('--port', required=True, help='path of the symlink to the pty the driver opens')
    add(
        '--rate',
        type=float,
        default=DEFAULT_SENSOR_RATE_HZ,
        help=f'reading lines per second ({DEFAULT_SENSOR_RATE_HZ:g})',
    )
    add('--true-geometry', default=default_geometry_path('true'), help='device D0 and gamma')
    add('--seed', type=int, default=-1, help='noise seed (default -1: a fresh one at each start)')
    for sensor, name in zip(DEVICE_SENSORS, NOISE_PARAMETERS, strict=True):  # device_driver's
        add(
            f'--{name.replace("_", "-")}',
            type=float,
            default=getattr(DEFAULT_SENSOR_NOISE, sensor),
            help=NOISE_UNITS[sensor],
        )
    for name in DYNAMICS_PARAMETERS:  # as device_driver's parameters (docs/sensor_errors.md)
        add(f'--{name.replace("_", "-")}', type=float, default=0.0, help='s (0: instant / white)')
    add('--angle-unit', default='rad', choices=tuple(ANGLE_UNITS))
    add('--length-unit', default='m', choices=tuple(LENGTH_UNITS))
    add(
        '--hello-period',
        type=float,
        default=HELLO_PERIOD_S,
        help='s between hello lines (1; 0: only at connection and when the driver asks)',
    )
    add('--garbage-fraction', type=float, default=0.0, help='share of garbage lines (0..1)')
    add('--checksum-error-fraction', type=float, default=0.0, help='share of bad checksums')
    add('--silence-every', type=float, default=0.0, help='a silence every S seconds (0: never)')
    add('--silence-duration', type=float, default=2.0, help='length of a silence, s (2)')
    add('--disconnect-every', type=float, default=0.0, help='unplug every S seconds (0: never)')
    add('--disconnect-duration', type=float, default=1.0, help='time unplugged, s (1)')
    args, ros_args = parser.parse_known_args(argv)
    if not args.rate > 0:
        parser.error('--rate must be > 0')
    if not args.hello_period >= 0:
        parser.error('--hello-period must be >= 0')
    for name in DYNAMICS_PARAMETERS:
        if not 0.0 <= getattr(args, name) < float('inf'):
            parser.error(f'--{name.replace("_", "-")} must be finite and >= 0')
    for name in ('garbage_fraction', 'checksum_error_fraction'):
        if not 0.0 <= getattr(args, name) <= 1.0:
            parser.error(f'--{name.replace("_", "-")} must be in [0, 1]')
    return args, ros_args


class FakeDeviceNode(Node):
    """Feeds the true pose to the emulator; ``**kwargs`` go to ``Node``."""

    def __init__(self, args, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        seed = parameter_specs.resolve_seed(args.seed)
        try:
            self._model = SimDeviceBackend.from_config(
                args.true_geometry,
                **{name: getattr(args, name) for name in (*NOISE_PARAMETERS, *DYNAMICS_PARAMETERS)},
                rng=np.random.default_rng([seed, RNG_STREAM]),
            )
        except ValueError as error:
            raise parameter_specs.ConfigurationError(str(error)) from None
        self._truth = TruthFeed()
        self.device = FakeDevice(
            args.port,
            self._readings,
            timed_readings=True,
            rate_hz=args.rate,
            angle_unit=args.angle_unit,
            length_unit=args.length_unit,
            garbage_fraction=args.garbage_fraction,
            checksum_error_fraction=args.checksum_error_fraction,
            hello_period_s=args.hello_period,
            rng=np.random.default_rng([seed, RNG_STREAM + 100]),
        ).start()
        self.create_subscription(
            PoseStamped, names.TOPIC_TRUE_POSE, self._on_true_pose, qos.LATEST_STATE_QOS
        )
        if args.silence_every > 0:
            self.create_timer(args.silence_every, lambda: self._fault('silence', args))
        if args.disconnect_every > 0:
            self.create_timer(args.disconnect_every, lambda: self._fault('disconnect', args))
        self.get_logger().info(f'fake device on {args.port} at {args.rate:g} Hz, seed {seed}')

    def _readings(self):
        """Called from the emulator's thread (the only user of the model): ``(readings, instant
        on time.monotonic)`` of the newest true pose not sent yet, or None. The sensor dynamics
        advance to that instant (the monotonic clock the emulator samples on)."""
        taken = self._truth.take()
        if taken is None:
            return None
        pose, instant = taken
        try:
            self._model.observe_true_pose(pose)
        except ValueError as error:
            self.get_logger().warning(f'ignoring true pose: {error}', throttle_duration_sec=1.0)
            return None
        return self._model.read(instant).readings(), instant

    def _on_true_pose(self, msg):
        try:
            pose = message_checks.pose_in_frame(msg, names.FRAME_BASE)
        except ValueError as error:
            self.get_logger().warning(f'ignoring true pose: {error}', throttle_duration_sec=1.0)
            return
        # The instant the pose describes (its stamp, node clock) on the emulator's monotonic clock.
        # A zero stamp (none given) is taken as the receipt.
        stamp_ns = conversions.stamp_to_nanoseconds(msg.header.stamp)
        age_s = (self.get_clock().now().nanoseconds - stamp_ns) * 1e-9 if stamp_ns else 0.0
        self._truth.put(pose, time.monotonic() - age_s)

    def _fault(self, kind, args):
        duration = getattr(args, f'{kind}_duration')
        self.get_logger().warning(f'fault injection: {kind} for {duration:g} s')
        getattr(self.device, kind)(duration)

    def destroy_node(self):
        node_tools.close_opened(self, 'device')
        return super().destroy_node()


def main(argv=None):
    """Console script ``gsp_fake_device``."""
    import sys

    args, ros_args = parse_arguments(sys.argv[1:] if argv is None else argv)
    return node_tools.run_node(
        lambda: FakeDeviceNode(args), ['gsp_fake_device', *ros_args], logger_name=NODE_NAME
    )


if __name__ == '__main__':
    raise SystemExit(main())
