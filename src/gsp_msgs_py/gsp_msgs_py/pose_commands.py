"""The platform side of the pose command protocol, for any node that plays the platform."""

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped

from . import conversions, message_checks, names, qos
from .settle import CommandStatistics, SettleTracker

WARN_THROTTLE_S = 1.0


class PoseCommandServer:
    """Pose commands and their statuses on ``node``.

    ``move(command_id, pose)`` returns '' when accepted, else the reason of the rejection;
    ``travel_s()`` (optional, s) delays the settle. ``settle_time=None``: commands stay
    ``moving`` until :meth:`settled` or :meth:`reject_moving`.
    """

    def __init__(self, node, frame_id, settle_time, move, on_settled=None, travel_s=None):
        self.settle_time = settle_time
        self._travel_s = travel_s
        self._reports = settle_time is None
        self._node = node
        self._frame_id = frame_id
        self._move = move
        self._on_settled = on_settled
        self._tracker = SettleTracker()
        self._last_command_id = None
        self.statistics = CommandStatistics()  #: what became of the commands (/diagnostics)
        self._status_pub = node.create_publisher(
            DiagnosticStatus,
            names.TOPIC_PLATFORM_STATUS,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
        )
        node.create_subscription(
            PoseStamped,
            names.TOPIC_POSE_COMMAND,
            self._on_pose_command,
            qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND],
        )
        self._settle_timer = node.create_timer(1.0, self._on_settle_timer, autostart=False)

    def _now_ns(self):
        return self._node.get_clock().now().nanoseconds

    def _publish_status(self, command_id, state, reason=''):
        self._status_pub.publish(conversions.make_status(command_id, state, reason))

    def _reject(self, command_id, reason):
        self._publish_status(command_id, names.STATE_REJECTED, reason)
        self._node.get_logger().warning(
            f'pose command {command_id} rejected: {reason}', throttle_duration_sec=WARN_THROTTLE_S
        )

    def _on_pose_command(self, msg):
        try:
            command_id = conversions.command_id_from_stamp(msg.header.stamp)
        except (TypeError, ValueError) as error:  # pragma: no cover - a typed message
            self._node.get_logger().warning(
                f'ignoring a pose command: {error}', throttle_duration_sec=WARN_THROTTLE_S
            )
            return
        if command_id == self._last_command_id:
            return  # sent again while its status was on the way: the same command, answered
        self._last_command_id = command_id
        try:
            reason = self._move(command_id, message_checks.pose_in_frame(msg, self._frame_id))
        except (TypeError, ValueError) as error:
            reason = str(error)
        if reason:
            self.statistics.refused(command_id, reason)
            self._reject(command_id, reason)
            return
        now_ns = self._now_ns()
        wait_s = (self.settle_time or 0.0) + (self._travel_s() if self._travel_s else 0.0)
        superseded = self._tracker.accept(command_id, now_ns, wait_s)
        self.statistics.accepted(command_id, now_ns)
        if superseded is not None:
            reason = f'superseded by command {command_id} before settling'
            self.statistics.superseded(superseded, reason)
            self._reject(superseded, reason)
        self._publish_status(command_id, names.STATE_MOVING)
        if not self._reports:
            self._settle_or_wait(now_ns)

    def health(self):
        """The commands' :class:`~gsp_msgs_py.health.Health` (see :class:`CommandStatistics`)."""
        return self.statistics.health()

    @property
    def moving(self):
        """The command id that is moving, or None."""
        return self._tracker.moving

    def settled(self, command_id):
        """Report-mode: ``command_id`` (if still the moving one) has arrived: ``settled``."""
        now_ns = self._now_ns()
        if self._tracker.moving == command_id and self._tracker.due(now_ns) is not None:
            self._announce_settled(command_id, now_ns)

    def _announce_settled(self, command_id, now_ns):
        self.statistics.settled(command_id, now_ns)
        self._publish_status(command_id, names.STATE_SETTLED)
        if self._on_settled is not None:
            self._on_settled(command_id)

    def reject_moving(self, reason):
        """Report-mode: the moving command failed (``rejected`` with ``reason``)."""
        command_id = self._tracker.moving
        if command_id is not None:
            self._tracker.forget()
            self.statistics.abandoned(command_id, reason)
            self._reject(command_id, reason)

    def _settle_or_wait(self, now_ns):
        """Announce the moving command if it has settled, else (re)arm the timer for it."""
        settled = self._tracker.due(now_ns)
        if settled is not None:
            self._settle_timer.cancel()
            self._announce_settled(settled, now_ns)
            return
        wait_ns = self._tracker.wait_ns(now_ns)
        if wait_ns is not None:
            self._settle_timer.timer_period_ns = wait_ns
            self._settle_timer.reset()

    def _on_settle_timer(self):
        self._settle_timer.cancel()
        self._settle_or_wait(self._now_ns())
