"""SettleTracker: moving -> settled, or superseded (pure, no ROS)."""

from gsp_msgs_py.settle import SettleTracker

MS = 1_000_000


def test_a_command_settles_after_the_settle_time():
    tracker = SettleTracker()
    assert tracker.moving is None and tracker.wait_ns(0) is None and tracker.due(0) is None
    assert tracker.accept('1', 10 * MS, 0.05) is None
    assert tracker.moving == '1'
    assert tracker.wait_ns(20 * MS) == 40 * MS
    assert tracker.due(59 * MS) is None
    assert tracker.due(60 * MS) == '1'
    assert tracker.moving is None and tracker.due(100 * MS) is None  # announced once


def test_zero_settle_time_is_due_at_once():
    tracker = SettleTracker()
    tracker.accept('1', 5 * MS, 0.0)
    assert tracker.wait_ns(5 * MS) == 0
    assert tracker.due(5 * MS) == '1'


def test_a_new_command_supersedes_the_moving_one():
    tracker = SettleTracker()
    tracker.accept('1', 0, 0.3)
    assert tracker.accept('2', 100 * MS, 0.3) == '1'
    assert tracker.due(300 * MS) is None  # the superseded command never settles
    assert tracker.due(400 * MS) == '2'
    assert tracker.accept('3', 500 * MS, 0.3) is None  # '2' has settled: nothing superseded


def test_command_statistics_count_each_outcome_and_time_the_settles():
    from gsp_msgs_py.health import ERROR, OK, WARN
    from gsp_msgs_py.settle import CommandStatistics

    stats = CommandStatistics()
    assert stats.health().level == OK and stats.health().message == 'no command yet'
    stats.accepted('1', 0)
    stats.settled('1', 50 * MS)
    stats.accepted('2', 100 * MS)
    stats.superseded('2', 'superseded by command 3 before settling')
    stats.accepted('3', 120 * MS)
    stats.settled('3', 270 * MS)
    health = stats.health()
    assert health.level == OK, health  # a superseded command is not a fault of the platform
    assert health.values['commands'] == '3' and health.values['accepted'] == '3'
    assert health.values['settled'] == '2' and health.values['superseded'] == '1'
    assert health.values['rejected'] == '1'
    # Settle times: 50 ms and 150 ms, from the acceptance to the settled status.
    assert abs(float(health.values['settle_time_last_s']) - 0.150) < 1e-4
    assert abs(float(health.values['settle_time_mean_s']) - 0.100) < 1e-4
    assert abs(float(health.values['settle_time_max_s']) - 0.150) < 1e-4

    stats.refused('4', 'stroke limit of leg 3')
    health = stats.health()
    assert health.level == WARN and 'stroke limit of leg 3' in health.message
    assert health.values['refused'] == '1' and health.values['rejected'] == '2'
    assert health.values['last_rejection'] == '4: stroke limit of leg 3'

    stats.accepted('5', 300 * MS)
    assert stats.health().level == OK  # the latest command is moving
    stats.abandoned('5', 'goal not reached in time')
    health = stats.health()
    assert health.level == ERROR and 'goal not reached in time' in health.message
    assert health.values['abandoned'] == '1' and health.values['rejected'] == '3'
    assert health.values['settled'] == '2'


class _PlatformNode:
    """What PoseCommandServer uses of a node: its statuses kept, its command callback exposed."""

    def __init__(self):
        from types import SimpleNamespace

        self.statuses, self.on_command, self.now_ns = [], None, 0
        self._timer = SimpleNamespace(cancel=lambda: None, reset=lambda: None, timer_period_ns=0)
        self._clock = SimpleNamespace(now=lambda: SimpleNamespace(nanoseconds=self.now_ns))

    def create_publisher(self, *_):
        from types import SimpleNamespace

        return SimpleNamespace(publish=self.statuses.append)

    def create_subscription(self, _type, _topic, callback, _qos):
        self.on_command = callback

    def create_timer(self, *_, **__):
        return self._timer

    def get_clock(self):
        return self._clock


def test_a_command_sent_again_with_its_stamp_is_answered_once_and_moves_once():
    """The calibrator sends an unanswered command again with the same stamp (its id): the
    platform neither moves again nor supersedes it; a new stamp is a new command."""
    from gsp_msgs_py import conversions, names
    from gsp_msgs_py.pose_commands import PoseCommandServer

    node, moves = _PlatformNode(), []
    server = PoseCommandServer(node, names.FRAME_BASE, 0.0, lambda i, pose: moves.append(i) or '')
    pose = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    first = conversions.pose_to_pose_stamped(pose, conversions.seconds_to_stamp(0.005))
    for _ in range(3):
        node.on_command(first)
    states = [conversions.parse_status(s) for s in node.statuses]
    assert moves == ['5000000'] and [(s.command_id, s.state) for s in states] == [
        ('5000000', names.STATE_MOVING),
        ('5000000', names.STATE_SETTLED),
    ]
    assert server.statistics.counts['commands'] == 1
    node.on_command(conversions.pose_to_pose_stamped(pose, conversions.seconds_to_stamp(0.006)))
    assert moves == ['5000000', '6000000'] and server.statistics.counts['commands'] == 2
