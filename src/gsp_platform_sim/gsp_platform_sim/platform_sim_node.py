"""``platform_sim`` node: a simulated Gough-Stewart platform (see docs/README_nodes_sim_driver.md).

Subscribes ``/gsp/platform/pose_command``; publishes ``/gsp/platform/leg_lengths`` and
``/gsp/platform/true_pose`` (one timer, one stamp), ``/gsp/platform/status`` (moving -> settled,
or rejected with the reason) and ``/gsp/platform/markers``. The controller geometry is the
``geometry.*`` parameters (changeable at run time); the true geometry is read once from
``true_geometry_file`` and never published. The logic is in :mod:`gsp_platform_sim.simulator`.
"""


import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from gsp_kinematics.geometry import (
    GeometryError,
    default_geometry,
    default_geometry_path,
    geometry_from_parameters,
    geometry_to_parameters,
    load_geometry,
)
from gsp_msgs_py import checks, conversions, names, node_tools, qos
from gsp_msgs_py.node_tools import first_failed_check, is_finite_number, parameter_descriptor

from .markers import make_marker_array
from .simulator import DEFAULT_MAX_CONDITION, PlatformSimulator

MARKER_RATE_HZ = 10.0
#: Random stream of this node: the device driver with the same ``seed`` draws independent noise.
RNG_STREAM = 1
WARN_THROTTLE_S = 1.0

_NOMINAL_PARAMETERS = geometry_to_parameters(default_geometry('nominal'))
GEOMETRY_PARAMETER_NAMES = tuple(_NOMINAL_PARAMETERS)
_GEOMETRY_DESCRIPTIONS = {
    'geometry.base_joints': 'Controller model: base joints A_1..A_6 as 18 values x1 y1 z1 ... (m, base frame)',
    'geometry.platform_joints': 'Controller model: platform joints B_1..B_6 as 18 values (m, platform frame)',
    'geometry.leg_offsets': 'Controller model: leg offsets L_off_1..L_off_6, L_i = q_i + L_off_i (m)',
    'geometry.device_length': 'Controller model: measuring device length D0 (m; unused by the simulator)',
    'geometry.inclinometer_axes_angle': 'Controller model: inclinometer axes angle gamma (rad; unused by the simulator)',
    'geometry.limits.leg_stroke_min': 'Smallest commandable articular variable q (m)',
    'geometry.limits.leg_stroke_max': 'Largest commandable articular variable q (m)',
    'geometry.limits.base_joint_max_angle': 'Largest leg angle to the base normal (rad)',
    'geometry.limits.platform_joint_max_angle': 'Largest leg angle to the platform normal (rad)',
}


class ConfigurationError(node_tools.ConfigurationError):
    """A parameter value prevents the node from starting; the message names the parameter."""



#: name -> (test, requirement): every non-geometry parameter's check, at start-up and at run time.
_SCALAR_CHECKS = {
    'true_geometry_file': (lambda v: bool(v.strip()), 'must name a geometry file'),
    'publish_rate': (lambda v: is_finite_number(v) and v > 0.0, 'must be > 0 Hz'),
    'leg_noise_std': (lambda v: is_finite_number(v) and v >= 0.0, 'must be >= 0 m'),
    'seed': (lambda v: v >= -1, 'must be >= 0, or -1 for a random seed'),
    'settle_time': (lambda v: is_finite_number(v) and v >= 0.0, 'must be >= 0 s'),
    'max_condition': (lambda v: is_finite_number(v) and v >= 1.0, 'must be >= 1'),
    'frame_id': (lambda v: bool(v.strip()), 'must not be empty'),
}


def check_scalar_parameters(values):
    """Reason ('' if none) why a ``{name: value}`` of non-geometry parameters is invalid."""
    return first_failed_check(_SCALAR_CHECKS, values)


class PlatformSimNode(Node):
    """Simulated platform; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_PLATFORM_SIM, **kwargs)
        try:
            self._declare_parameters()
        except (InvalidParameterValueException, InvalidParameterTypeException) as error:
            raise ConfigurationError(str(error)) from None
        values = {name: self.get_parameter(name).value for name in _SCALAR_CHECKS}
        reason = check_scalar_parameters(values)
        if reason:
            raise ConfigurationError(reason)
        try:
            true_geometry = load_geometry(values['true_geometry_file'])
        except GeometryError as error:
            raise ConfigurationError(f'true_geometry_file: {error}') from None
        try:
            controller_geometry = geometry_from_parameters(self._geometry_parameters())
        except GeometryError as error:
            raise ConfigurationError(f'controller geometry: {error}') from None
        seed = values['seed'] if values['seed'] >= 0 else np.random.SeedSequence().entropy
        try:
            self._simulator = PlatformSimulator(
                true_geometry, controller_geometry, leg_noise_std=values['leg_noise_std'],
                rng=np.random.default_rng([seed, RNG_STREAM]),
                max_condition=values['max_condition'])
        except ValueError as error:
            raise ConfigurationError(str(error)) from None
        self._frame_id = values['frame_id']
        self._settle_time = values['settle_time']
        self._pending_command_id = None  # accepted command waiting for its 'settled' status

        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # All callbacks in the node's default (mutually exclusive) group: no locking needed.
        self._leg_lengths_pub = self.create_publisher(
            JointState, names.TOPIC_LEG_LENGTHS, qos.TOPIC_QOS[names.TOPIC_LEG_LENGTHS])
        self._true_pose_pub = self.create_publisher(
            PoseStamped, names.TOPIC_TRUE_POSE, qos.TOPIC_QOS[names.TOPIC_TRUE_POSE])
        self._status_pub = self.create_publisher(
            DiagnosticStatus, names.TOPIC_PLATFORM_STATUS,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS])
        self.create_subscription(
            PoseStamped, names.TOPIC_POSE_COMMAND, self._on_pose_command,
            qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND])
        self.create_timer(1.0 / values['publish_rate'], self._publish_state)
        self._settle_timer = self.create_timer(1.0, self._on_settle_timer, autostart=False)
        self._markers_pub = None
        if self.get_parameter('publish_markers').value:
            self._markers_pub = self.create_publisher(
                MarkerArray, names.TOPIC_MARKERS, qos.TOPIC_QOS[names.TOPIC_MARKERS])
            self.create_timer(1.0 / MARKER_RATE_HZ, self._publish_markers)

        self.get_logger().info(
            f'platform_sim ready: true geometry from {values["true_geometry_file"]}, '
            f'publishing at {values["publish_rate"]:g} Hz, leg noise {values["leg_noise_std"]:g} m, '
            f'settle time {self._settle_time:g} s, seed {seed}, '
            f'home pose {self._simulator.true_pose.round(6).tolist()}')

    # ------------------------------------------------------------------------- parameters

    def _declare_parameters(self):
        self.declare_parameter(
            'true_geometry_file', default_geometry_path('true'), parameter_descriptor(
                'Geometry params file of the real (true) platform, read once at start-up; never '
                'published', read_only=True))
        for name in GEOMETRY_PARAMETER_NAMES:
            self.declare_parameter(name, _NOMINAL_PARAMETERS[name], parameter_descriptor(
                _GEOMETRY_DESCRIPTIONS[name],
                constraints='the whole geometry.* set must be valid (geometry_from_parameters); '
                            'applies from the next pose command'))
        self.declare_parameter('publish_rate', 200.0, parameter_descriptor(
            'Rate of leg_lengths and true_pose (Hz)', read_only=True, constraints='> 0'))
        self.declare_parameter('leg_noise_std', 1e-6, parameter_descriptor(
            'Standard deviation of the Gaussian leg length sensor noise (m)',
            float_range=(0.0, 1.0)))
        self.declare_parameter('seed', 0, parameter_descriptor(
            'Seed of the noise generator; -1 = random', read_only=True,
            integer_range=(-1, 2**31 - 1)))
        self.declare_parameter('settle_time', 0.05, parameter_descriptor(
            "Time from the 'moving' to the 'settled' status of an accepted command (s)",
            float_range=(0.0, 60.0)))
        self.declare_parameter('max_condition', DEFAULT_MAX_CONDITION, parameter_descriptor(
            'Commands whose dq/dX condition number is not below this are rejected '
            '(singularity guard)', float_range=(1.0, 1e12)))
        self.declare_parameter('publish_markers', True, parameter_descriptor(
            f'Publish RViz markers on {names.TOPIC_MARKERS} at {MARKER_RATE_HZ:g} Hz',
            read_only=True))
        self.declare_parameter('frame_id', names.FRAME_BASE, parameter_descriptor(
            'Base frame: of the published messages, and required of pose commands',
            read_only=True))

    def _geometry_parameters(self):
        return {name: self.get_parameter(name).value for name in GEOMETRY_PARAMETER_NAMES}

    def _validate_parameters(self, parameters):
        """on-set callback: reject a bad value with the reason (nothing is applied here)."""
        values = {p.name: p.value for p in parameters}
        reason = check_scalar_parameters(values)
        if not reason and any(name in GEOMETRY_PARAMETER_NAMES for name in values):
            candidate = self._geometry_parameters()
            candidate.update({k: v for k, v in values.items() if k in GEOMETRY_PARAMETER_NAMES})
            try:
                geometry_from_parameters(candidate)
            except GeometryError as error:
                reason = str(error)
        return SetParametersResult(successful=not reason, reason=reason)

    def _apply_parameters(self, parameters):
        """post-set callback: apply the accepted values."""
        values = {p.name: p.value for p in parameters}
        if 'leg_noise_std' in values:
            self._simulator.leg_noise_std = values['leg_noise_std']
        if 'max_condition' in values:
            self._simulator.max_condition = values['max_condition']
        if 'settle_time' in values:
            self._settle_time = values['settle_time']
        changed = sorted(name for name in values if name in GEOMETRY_PARAMETER_NAMES)
        if changed:
            self._simulator.set_controller_geometry(
                geometry_from_parameters(self._geometry_parameters()))
            self.get_logger().info(
                f'controller geometry updated ({", ".join(changed)}); applies from the next '
                'pose command')

    # --------------------------------------------------------------------------- commands

    def _publish_status(self, command_id, state, reason=''):
        self._status_pub.publish(conversions.make_status(command_id, state, reason))

    def _reject(self, command_id, reason):
        self._publish_status(command_id, names.STATE_REJECTED, reason)
        self.get_logger().warning(f'pose command {command_id} rejected: {reason}',
                                  throttle_duration_sec=WARN_THROTTLE_S)

    def _on_pose_command(self, msg):
        command_id = conversions.command_id_from_stamp(msg.header.stamp)
        try:
            pose = checks.pose_in_frame(msg, self._frame_id)
        except ValueError as error:
            self._reject(command_id, str(error))
            return
        outcome = self._simulator.command(pose)
        if not outcome.accepted:
            self._reject(command_id, outcome.reason)
            return
        if self._pending_command_id is not None:
            self._reject(self._pending_command_id,
                         f'superseded by command {command_id} before settling')
        self._publish_status(command_id, names.STATE_MOVING)
        self.get_logger().debug(f'pose command {command_id} accepted: {pose.tolist()}')
        if self._settle_time <= 0.0:
            self._pending_command_id = None
            self._publish_status(command_id, names.STATE_SETTLED)
            return
        self._pending_command_id = command_id
        self._settle_timer.timer_period_ns = int(round(self._settle_time * 1e9))
        self._settle_timer.reset()

    def _on_settle_timer(self):
        self._settle_timer.cancel()
        if self._pending_command_id is not None:
            self._publish_status(self._pending_command_id, names.STATE_SETTLED)
            self._pending_command_id = None

    # ------------------------------------------------------------------------ publishing

    def _publish_state(self):
        stamp = self.get_clock().now().to_msg()
        self._leg_lengths_pub.publish(conversions.leg_lengths_to_msg(
            self._simulator.measured_leg_lengths(), stamp, self._frame_id))
        self._true_pose_pub.publish(conversions.pose_to_pose_stamped(
            self._simulator.true_pose, stamp, self._frame_id))

    def _publish_markers(self):
        self._markers_pub.publish(make_marker_array(
            self._simulator.controller_geometry, self._simulator.true_pose,
            self.get_clock().now().to_msg(), self._frame_id))


def main(args=None):
    """Console script ``platform_sim``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(PlatformSimNode, args, logger_name=names.NODE_PLATFORM_SIM)


if __name__ == '__main__':
    raise SystemExit(main())
