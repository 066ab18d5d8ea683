"""``replay`` node: publishes a recorded calibration run back onto the suite's topics.
See docs/nodes.md."""

import rclpy.time
from rclpy.node import Node

from gsp_calibrator.replay.recorded_run import PostureServer, RecordedRun, ReplayError
from gsp_msgs_py import conversions, names, node_tools, parameter_specs
from gsp_msgs_py.diagnostics import Component, DiagnosticsPublisher
from gsp_msgs_py.parameter_specs import ParameterSpec, greater_than, not_blank
from gsp_msgs_py.pose_commands import PoseCommandServer

NODE_NAME = names.NODE_REPLAY
REASON_NOT_RECORDED = 'not in the recording'
#: Periods of silence after a ``settled`` status before the posture's stream restarts.
RESTART_PERIODS = 2

PARAMETERS = (
    ParameterSpec(
        'run',
        '',
        'Recorded run to replay: a run directory (its samples.csv, else every recording part '
        'of it), a samples.csv or a recording.mcap (with the later parts of a resumed run)',
        read_only=True,
        constraints='required, readable',
        check=not_blank(reason='required: a run directory, samples.csv or recording.mcap'),
    ),
    parameter_specs.publish_rate_spec('the replayed samples'),
    parameter_specs.settle_time_spec('a recorded posture'),
    ParameterSpec(
        'pose_tolerance',
        1e-6,
        'Largest distance of a command to a recorded commanded pose: position (m) and '
        'rotation angle (rad)',
        float_range=(0.0, 1.0),
        constraints='> 0',
        check=greater_than(0.0, reason='must be > 0 (m and rad)'),
    ),
    parameter_specs.frame_id_spec(
        'Base frame: of the published messages, and required of pose commands'
    ),
    parameter_specs.diagnostics_period_spec(),
)


class ReplayNode(Node):
    """Replay of a recorded run; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        values = parameter_specs.declare_parameters(self, PARAMETERS)
        try:
            #: The :class:`~gsp_calibrator.replay.recorded_run.RecordedRun` being replayed.
            self.run = RecordedRun.load(values['run'])
        except (ReplayError, OSError) as error:
            raise parameter_specs.ConfigurationError(f'run: {error}') from None
        self._frame_id = values['frame_id']
        self._server = PostureServer(self.run, values['pose_tolerance'])
        self._period_ns = int(round(1e9 / values['publish_rate']))
        self._stream = self.run.initial_stream
        self._cursor = 0
        self._resume_ns = None  # the stream is silent until then (after a 'settled' status)
        # The stamp of the restarted stream's first sample (the recorded timing).
        self._first_stamp_ns = None
        self._last_stamp_ns = 0
        parameter_specs.watch_parameters(self, PARAMETERS, apply=self._apply_parameters)

        # All callbacks in the node's default (mutually exclusive) group: no locking needed.
        topics = (names.TOPIC_LEG_LENGTHS, *node_tools.DEVICE_TOPICS)
        if self.run.has_true_pose:
            topics += (names.TOPIC_TRUE_POSE,)
        self._pubs = node_tools.create_publishers(self, topics)
        self._commands = PoseCommandServer(
            self, self._frame_id, values['settle_time'], self._move, on_settled=self._restart_stream
        )
        self.create_timer(1.0 / values['publish_rate'], self._publish_sample)
        self._diagnostics = DiagnosticsPublisher(
            self,
            values['diagnostics_period'],
            [Component('commands', names.STATUS_HARDWARE_ID, self._commands.health)],
        )

        run = self.run
        samples = sum(len(p.stream) for p in run.postures)
        later = f' and {len(run.parts) - 1} later part(s)' if len(run.parts) > 1 else ''
        self.get_logger().info(
            f'replay ready: {len(run)} posture(s), {samples} sample(s) from {run.source}{later} '
            f'({run.kind}), publishing at {values["publish_rate"]:g} Hz, settle time '
            f'{values["settle_time"]:g} s, pose tolerance {self._server.tolerance:g}, true pose '
            f'{"replayed" if run.has_true_pose else "not recorded"}'
        )
        for k, why in run.skipped:
            self.get_logger().info(f'recorded command {k} gives no posture: {why}')

    def _apply_parameters(self, changes):
        """Apply accepted run-time changes (checked by parameter_specs.watch_parameters)."""
        if 'settle_time' in changes:
            self._commands.settle_time = changes['settle_time']
        if 'pose_tolerance' in changes:
            self._server.tolerance = changes['pose_tolerance']

    def _move(self, command_id, pose):
        """PoseCommandServer callback: stream the recorded posture of ``pose``, or refuse it."""
        posture = self._server.serve(pose)
        if posture is None:
            return REASON_NOT_RECORDED
        self._stream, self._cursor, self._resume_ns = posture.stream, 0, None
        self._first_stamp_ns = None  # fresh stamps until the settle
        self.get_logger().debug(f'pose command {command_id}: recorded posture {posture.posture}')
        return ''

    def _restart_stream(self, command_id):
        """After a 'settled' status: pause, then restart at the posture's first sample."""
        self._cursor = 0
        self._resume_ns = self.get_clock().now().nanoseconds + RESTART_PERIODS * self._period_ns
        self._first_stamp_ns = None

    # ------------------------------------------------------------------------ publishing

    def _publish_sample(self):
        now = self.get_clock().now()
        if self._resume_ns is not None:
            if now.nanoseconds < self._resume_ns:
                return
            self._resume_ns = None
            self._first_stamp_ns = now.nanoseconds if self._stream.offsets_ns is not None else None
        stream = self._stream
        if len(stream) == 0:
            return
        stamp_ns = max(now.nanoseconds, self._last_stamp_ns + 1)
        if self._first_stamp_ns is not None:  # the recorded timing, until the stream wraps
            stamp_ns = self._first_stamp_ns + int(stream.offsets_ns[self._cursor])
            if stamp_ns > now.nanoseconds:
                return  # a gap in the recording (messages the original never got)
        sample = stream.sample(self._cursor)
        self._last_stamp_ns = stamp_ns
        self._cursor = (self._cursor + 1) % len(stream)
        if self._cursor == 0:
            self._first_stamp_ns = None
        stamp = rclpy.time.Time(nanoseconds=stamp_ns, clock_type=now.clock_type).to_msg()
        node_tools.publish_messages(
            self, self._pubs, 'a recorded sample', self._sample_messages, *sample, stamp
        )

    def _sample_messages(self, q, readings, true_pose, stamp):
        """``{topic: message}`` of one recorded instant; ValueError naming a non-finite value."""
        messages = {
            names.TOPIC_LEG_LENGTHS: conversions.leg_lengths_to_msg(q, stamp, self._frame_id),
            **node_tools.device_messages(readings, stamp, self._frame_id),
        }
        if names.TOPIC_TRUE_POSE in self._pubs and true_pose is not None:
            messages[names.TOPIC_TRUE_POSE] = conversions.pose_to_pose_stamped(
                true_pose, stamp, self._frame_id
            )
        return messages


def main(args=None):
    """Console script ``replay``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(ReplayNode, args, logger_name=NODE_NAME)


if __name__ == '__main__':
    raise SystemExit(main())
