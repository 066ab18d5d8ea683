"""SettleTracker: moving -> settled, or superseded (pure, no ROS)."""

from gsp_msgs_py.settle import SettleTracker, superseded_reason

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
    assert superseded_reason('2') == 'superseded by command 2 before settling'
