"""``replay`` node: publishes a recorded calibration run back onto the suite's topics.

It stands in for both ``platform_sim`` and ``device_driver`` (see docs/README_replay.md). The
recorded run (:class:`gsp_calibrator.replay.RecordedRun`: a run directory, ``samples.csv`` or
``recording.mcap``) gives, per recorded posture, its commanded pose and its samples. For each
``PoseStamped`` on ``/gsp/platform/pose_command`` (``command_id`` = its header stamp in ns):

* a pose within ``pose_tolerance`` of a recorded commanded pose: ``moving``, then ``settled``
  ``settle_time`` later on ``/gsp/platform/status``, exactly as platform_sim; then that posture's
  recorded samples are published in order, cyclically;
* any other pose: ``rejected`` with the reason ``not in the recording`` (a wrong frame or a bad
  quaternion: ``rejected`` with that reason); the stream does not change.

Each instant of the stream, at ``publish_rate``, publishes ``/gsp/platform/leg_lengths`` and the
three ``/gsp/device/*`` readings (and ``/gsp/platform/true_pose`` when the recording has it) with
one shared, fresh stamp. Before the first command it streams the recorded idle samples (from a
recording), else the last recorded posture (where the recorded run left the platform). After a ``settled`` status the stream pauses for
:data:`RESTART_PERIODS` periods and restarts at the posture's first sample, so that the first
sample a calibrator counts is the first one recorded after the settle.
"""


from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from sensor_msgs.msg import JointState

from gsp_msgs_py import checks, conversions, names, node_tools, qos
from gsp_msgs_py.node_tools import first_failed_check, is_finite_number, parameter_descriptor

from .replay import RecordedRun, ReplayError

NODE_NAME = 'replay'
REASON_NOT_RECORDED = 'not in the recording'
#: Periods of silence after a ``settled`` status before the posture's stream restarts.
RESTART_PERIODS = 2
WARN_THROTTLE_S = 1.0


class ConfigurationError(node_tools.ConfigurationError):
    """A parameter value prevents the node from starting; the message names the parameter."""



#: name -> (test, requirement): each parameter's check, at start-up and at run time.
_CHECKS = {
    'run': (lambda v: bool(str(v).strip()),
            'required: a run directory, samples.csv or recording.mcap'),
    'publish_rate': (lambda v: is_finite_number(v) and v > 0.0, 'must be > 0 Hz'),
    'settle_time': (lambda v: is_finite_number(v) and v >= 0.0, 'must be >= 0 s'),
    'pose_tolerance': (lambda v: is_finite_number(v) and v > 0.0, 'must be > 0 (m and rad)'),
    'frame_id': (lambda v: bool(str(v).strip()), 'must not be empty'),
}


def check_parameters(values):
    """Reason ('' if none) why a ``{name: value}`` of this node's parameters is invalid."""
    return first_failed_check(_CHECKS, values)


class ReplayNode(Node):
    """Replay of a recorded run; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._declare_parameters()
        except (InvalidParameterValueException, InvalidParameterTypeException) as error:
            raise ConfigurationError(str(error)) from None
        values = {name: self.get_parameter(name).value for name in _CHECKS}
        reason = check_parameters(values)
        if reason:
            raise ConfigurationError(reason)
        try:
            self._run = RecordedRun.load(values['run'])
        except (ReplayError, OSError) as error:
            raise ConfigurationError(f'run: {error}') from None
        self._frame_id = values['frame_id']
        self._settle_time = values['settle_time']
        self._tolerance = values['pose_tolerance']
        self._period_ns = int(round(1e9 / values['publish_rate']))
        self._stream = self._run.initial_stream
        self._cursor = 0
        self._resume_ns = None  # the stream is silent until then (after a 'settled' status)
        self._pending = None  # (command_id, posture) accepted and waiting for 'settled'

        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # All callbacks in the node's default (mutually exclusive) group: no locking needed.
        self._leg_lengths_pub = self.create_publisher(
            JointState, names.TOPIC_LEG_LENGTHS, qos.TOPIC_QOS[names.TOPIC_LEG_LENGTHS])
        self._reading_pubs = {
            topic: self.create_publisher(JointState, topic, qos.TOPIC_QOS[topic])
            for topic in (names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER, names.TOPIC_LVDT)
        }
        self._true_pose_pub = None
        if self._run.has_true_pose:
            self._true_pose_pub = self.create_publisher(
                PoseStamped, names.TOPIC_TRUE_POSE, qos.TOPIC_QOS[names.TOPIC_TRUE_POSE])
        self._status_pub = self.create_publisher(
            DiagnosticStatus, names.TOPIC_PLATFORM_STATUS,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS])
        self.create_subscription(
            PoseStamped, names.TOPIC_POSE_COMMAND, self._on_pose_command,
            qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND])
        self.create_timer(1.0 / values['publish_rate'], self._publish_sample)
        self._settle_timer = self.create_timer(1.0, self._on_settle_timer, autostart=False)

        run = self._run
        samples = sum(len(p.stream) for p in run.postures)
        self.get_logger().info(
            f'replay ready: {len(run)} posture(s), {samples} sample(s) from {run.source} '
            f'({run.kind}), publishing at {values["publish_rate"]:g} Hz, settle time '
            f'{self._settle_time:g} s, pose tolerance {self._tolerance:g}, true pose '
            f'{"replayed" if run.has_true_pose else "not recorded"}')
        for k, why in run.skipped:
            self.get_logger().info(f'recorded command {k} gives no posture: {why}')

    # ------------------------------------------------------------------------- parameters

    def _declare_parameters(self):
        self.declare_parameter('run', '', parameter_descriptor(
            'Recorded run to replay: a run directory (its samples.csv, else its '
            'recording.mcap), a samples.csv or a recording.mcap', read_only=True,
            constraints='required, readable'))
        self.declare_parameter('publish_rate', 200.0, parameter_descriptor(
            'Rate of the replayed samples (Hz)', read_only=True, constraints='> 0'))
        self.declare_parameter('settle_time', 0.05, parameter_descriptor(
            "Time from the 'moving' to the 'settled' status of a recorded posture (s)",
            float_range=(0.0, 60.0)))
        self.declare_parameter('pose_tolerance', 1e-6, parameter_descriptor(
            'Largest distance of a command to a recorded commanded pose: position (m) and '
            'rotation angle (rad)', float_range=(0.0, 1.0), constraints='> 0'))
        self.declare_parameter('frame_id', names.FRAME_BASE, parameter_descriptor(
            'Base frame: of the published messages, and required of pose commands',
            read_only=True))

    def _validate_parameters(self, parameters):
        """on-set callback: reject a bad value with the reason (nothing is applied here)."""
        reason = check_parameters({p.name: p.value for p in parameters})
        return SetParametersResult(successful=not reason, reason=reason)

    def _apply_parameters(self, parameters):
        """post-set callback: apply the accepted values."""
        for parameter in parameters:
            if parameter.name == 'settle_time':
                self._settle_time = parameter.value
            elif parameter.name == 'pose_tolerance':
                self._tolerance = parameter.value

    # --------------------------------------------------------------------------- commands

    def _publish_status(self, command_id, state, reason=''):
        self._status_pub.publish(conversions.make_status(command_id, state, reason))

    def _reject(self, command_id, reason):
        self._publish_status(command_id, names.STATE_REJECTED, reason)
        self.get_logger().warning(f'pose command {command_id} rejected: {reason}',
                                  throttle_duration_sec=WARN_THROTTLE_S)

    def _on_pose_command(self, msg):
        try:
            command_id = conversions.command_id_from_stamp(msg.header.stamp)
        except (TypeError, ValueError) as error:  # pragma: no cover - a typed message
            self.get_logger().warning(f'ignoring a pose command: {error}',
                                      throttle_duration_sec=WARN_THROTTLE_S)
            return
        try:
            pose = checks.pose_in_frame(msg, self._frame_id)
            posture = self._run.match(pose, self._tolerance)
        except (TypeError, ValueError) as error:
            self._reject(command_id, str(error))
            return
        if posture is None:
            self._reject(command_id, REASON_NOT_RECORDED)
            return
        if self._pending is not None:
            self._reject(self._pending[0], f'superseded by command {command_id} before settling')
        self._stream, self._cursor, self._resume_ns = posture.stream, 0, None
        self._publish_status(command_id, names.STATE_MOVING)
        self.get_logger().debug(f'pose command {command_id}: recorded posture {posture.posture}')
        if self._settle_time <= 0.0:
            self._pending = None
            self._settle(command_id)
            return
        self._pending = (command_id, posture)
        self._settle_timer.timer_period_ns = int(round(self._settle_time * 1e9))
        self._settle_timer.reset()

    def _on_settle_timer(self):
        self._settle_timer.cancel()
        if self._pending is not None:
            command_id, _ = self._pending
            self._pending = None
            self._settle(command_id)

    def _settle(self, command_id):
        self._publish_status(command_id, names.STATE_SETTLED)
        self._cursor = 0
        self._resume_ns = self.get_clock().now().nanoseconds + RESTART_PERIODS * self._period_ns

    # ------------------------------------------------------------------------ publishing

    def _publish_sample(self):
        now = self.get_clock().now()
        if self._resume_ns is not None:
            if now.nanoseconds < self._resume_ns:
                return
            self._resume_ns = None
        stream = self._stream
        if len(stream) == 0:
            return
        q, readings, true_pose = stream.sample(self._cursor)
        self._cursor = (self._cursor + 1) % len(stream)
        stamp = now.to_msg()
        try:
            messages = [
                (self._leg_lengths_pub,
                 conversions.leg_lengths_to_msg(q, stamp, self._frame_id)),
                (self._reading_pubs[names.TOPIC_INCLINOMETER], conversions.inclinometer_to_msg(
                    readings[0], readings[1], stamp, self._frame_id)),
                (self._reading_pubs[names.TOPIC_ENCODER],
                 conversions.encoder_to_msg(readings[2], stamp, self._frame_id)),
                (self._reading_pubs[names.TOPIC_LVDT],
                 conversions.lvdt_to_msg(readings[3], stamp, self._frame_id)),
            ]
            if self._true_pose_pub is not None and true_pose is not None:
                messages.append((self._true_pose_pub, conversions.pose_to_pose_stamped(
                    true_pose, stamp, self._frame_id)))
        except ValueError as error:
            self.get_logger().warning(f'dropping a recorded sample: {error}',
                                      throttle_duration_sec=WARN_THROTTLE_S)
            return
        for publisher, msg in messages:
            publisher.publish(msg)

    @property
    def run(self):
        """The :class:`~gsp_calibrator.replay.RecordedRun` being replayed."""
        return self._run


def main(args=None):
    """Console script ``replay``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(ReplayNode, args, logger_name=NODE_NAME)


if __name__ == '__main__':
    raise SystemExit(main())
