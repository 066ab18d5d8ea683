"""CollectionProtocol: the posture-collection protocol, offline with synthetic times (no ROS)."""

import math

import numpy as np
import pytest
from collection_streams import MS, NOISE, POSE, T0, Q, R, S

from gsp_calibrator.collection import protocol, timeouts, topics
from gsp_calibrator.collection.events import (
    FINAL_EVENTS,
    CollectionStarted,
    CommandAgain,
    NoSynchronisedPair,
    PairsCollected,
    PostureSkipped,
    RowReady,
    SampleDropped,
    TopicSilent,
)
from gsp_calibrator.collection.protocol import CollectionProtocol
from gsp_calibrator.collection.synchroniser import ENCODER, INCLINOMETER, LEG_LENGTHS, LVDT
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.motion import MotionLimits, move_time, posture_leg_lengths
from gsp_msgs_py import conversions, names


def status(command_id, state, reason):
    return conversions.parse_status(conversions.make_status(command_id, state, reason))


def make(samples=3, **kwargs):
    kwargs.setdefault('topic_timeout', 1.0)
    kwargs.setdefault('settle_timeout', 2.0)
    return CollectionProtocol(0.0025, samples, NOISE, **kwargs)


def instant(collection, stamp, q=Q, readings=R, now=None, skip=()):
    """One leg-length sample and the device instant 1 ms later; the events."""
    now = stamp + 2 * MS if now is None else now
    events = collection.sample(LEG_LENGTHS, stamp, (q,), now)
    device = {
        INCLINOMETER: (readings[0], readings[1]),
        ENCODER: (readings[2],),
        LVDT: (readings[3],),
    }
    for stream, values in device.items():
        if stream not in skip:
            events += collection.sample(stream, stamp + MS, values, now)
    return events


def settle(collection, posture=1, at=T0, command_id='c1'):
    """Command posture ``posture`` at ``at``, moving at +1 ms, settled at +10 ms."""
    events = collection.command(posture, POSE, command_id, at)
    events += collection.status(status(command_id, names.STATE_MOVING, ''), at + MS)
    events += collection.status(status(command_id, names.STATE_SETTLED, ''), at + 10 * MS)
    return events


def test_a_row_from_the_samples_after_the_settle():
    collection = make()
    instant(collection, T0 - 100 * MS, readings=R - 0.05)  # the previous posture's readings
    events = collection.command(1, POSE, 'c1', T0)
    # While moving: received before the settle, stamped before it: never averaged.
    events += instant(collection, T0 + 2 * MS, q=Q + 1.0, readings=R + 1.0)
    events += collection.status(status('c1', names.STATE_SETTLED, ''), T0 + 10 * MS)
    assert events == [CollectionStarted(1, 'c1', T0 + 10 * MS)]
    for j in range(4):  # the 4th: the pairs of the first 3 are final (set_horizon)
        events = instant(collection, T0 + 11 * MS + 5 * MS * j, q=Q + j * 1e-7)
    (row,) = events
    assert isinstance(row, RowReady) and row.posture == 1 and row.dropped == 0
    np.testing.assert_allclose(row.pose, POSE)
    np.testing.assert_allclose(row.sample.leg_lengths, Q + 1e-7, rtol=0, atol=1e-15)
    np.testing.assert_allclose(row.sample.readings, R, rtol=0, atol=1e-15)
    assert collection._posture is None and collection.poll(T0 + 100 * S) == []


def test_samples_received_before_the_settle_count_when_stamped_after_the_start():
    collection = make(samples=2)
    collection.command(1, POSE, 'c1', T0)
    instant(collection, T0 + 5 * MS)
    events = collection.status(
        status('c1', names.STATE_SETTLED, ''), T0 + 10 * MS, start_ns=T0 + 4 * MS
    )  # a noted start
    assert events[0] == CollectionStarted(1, 'c1', T0 + 4 * MS)
    assert instant(collection, T0 + 10 * MS) == []  # final once the streams pass it
    events = instant(collection, T0 + 15 * MS)
    assert isinstance(events[0], RowReady) and events[0].sample.n_samples == 2


def test_the_collection_starts_at_the_settled_status_publish_instant_when_plausible():
    received = T0 + 10 * MS
    # The platform published settled 3 ms before it was received: samples count from then.
    assert protocol.settle_start_ns(T0 + 7 * MS, received, 1.0) == T0 + 7 * MS
    assert protocol.settle_start_ns(received, received, 1.0) == received
    # Unknown, after the receipt (a clock ahead), or older than topic_timeout (another time
    # base): the receipt.
    for published in (None, 0, received + MS, received - 2 * S):
        assert protocol.settle_start_ns(published, received, 1.0) == received
    # The samples received before the status and stamped from the publish instant count.
    collection = make(samples=2)
    collection.command(1, POSE, 'c1', T0)
    instant(collection, T0 + 6 * MS, now=T0 + 8 * MS)  # before the publish instant: not used
    instant(collection, T0 + 7 * MS, q=Q + 1e-7, now=T0 + 9 * MS)
    start = protocol.settle_start_ns(T0 + 7 * MS, received, 1.0)
    events = collection.status(status('c1', names.STATE_SETTLED, ''), received, start)
    assert events == [CollectionStarted(1, 'c1', T0 + 7 * MS)]
    assert instant(collection, T0 + 12 * MS, q=Q + 3e-7) == []
    (row,) = instant(collection, T0 + 17 * MS)
    assert isinstance(row, RowReady) and row.sample.n_samples == 2
    np.testing.assert_allclose(row.sample.leg_lengths, Q + 2e-7, rtol=0, atol=1e-15)


def test_a_rejected_posture_is_skipped_and_reported():
    collection = make()
    events = collection.command(1, POSE, 'c1', T0)
    events += collection.status(
        status('other', names.STATE_REJECTED, 'x'), T0 + MS
    )  # another command's status: ignored
    events += collection.status(status('c1', names.STATE_REJECTED, 'out of reach'), T0 + 2 * MS)
    assert events == [
        PostureSkipped(1, 'rejected by the platform: out of reach', True, 'out of reach')
    ]
    assert collection.summary()['skipped'] == [
        {
            'posture': 1,
            'reason': 'rejected by the platform: out of reach',
            'rejected_by_platform': True,
        }
    ]


def poll_until(collection, end, since, step=100 * MS):
    """Poll every ``step`` (as the node's watchdog does) from ``since`` to ``end``; the events."""
    events = []
    for now in range(since + step, end + 1, step):
        events += collection.poll(now)
    return events


def test_timeouts_of_the_status_and_the_settle():
    collection = make()
    collection.command(1, POSE, 'c1', T0)
    assert poll_until(collection, T0 + 900 * MS, T0) == [CommandAgain('c1')] * 3
    (silent,) = poll_until(collection, T0 + S, T0 + 900 * MS)
    assert isinstance(silent, TopicSilent) and silent.topic == names.TOPIC_PLATFORM_STATUS
    assert 'no status for posture 1 (command c1) within 1 s' in silent.message

    collection.command(2, POSE, 'c2', T0 + 2 * S)
    collection.status(status('c2', names.STATE_MOVING, ''), T0 + 2 * S + 10 * MS)
    # settle_timeout 2 s from the first status
    assert poll_until(collection, T0 + 4 * S, T0 + 2 * S + 10 * MS) == []
    assert poll_until(collection, T0 + 4 * S + 100 * MS, T0 + 4 * S) == [
        PostureSkipped(2, 'not settled within 2 s (the planned move 0 s + settle_timeout 2 s)')
    ]


def test_an_unanswered_command_is_sent_again_each_quarter_of_the_topic_timeout():
    """A platform that had not matched the calibrator's publisher yet missed the command: it is
    sent again (same id) each topic_timeout / 4 without a status, until a status comes; a stall
    of the caller counts from its end, as the timeout does."""
    collection = make(topic_timeout=4.0)
    collection.command(1, POSE, 'c1', T0)
    assert poll_until(collection, T0 + 900 * MS, T0) == []
    assert poll_until(collection, T0 + S, T0 + 900 * MS) == [CommandAgain('c1')]
    assert poll_until(collection, T0 + 1900 * MS, T0 + S) == []
    assert poll_until(collection, T0 + 2 * S, T0 + 1900 * MS) == [CommandAgain('c1')]
    collection.status(status('c1', names.STATE_MOVING, ''), T0 + 2100 * MS)
    assert poll_until(collection, T0 + 4 * S, T0 + 2100 * MS) == []  # answered: never again
    collection.command(2, POSE, 'c2', T0 + 10 * S)
    assert collection.poll(T0 + 14 * S) == []  # a stall of the caller (4 s): from its end
    assert collection.poll(T0 + 15 * S) == [CommandAgain('c2')]


def test_the_settle_waits_for_the_planned_move_besides_settle_timeout():
    """A move at the legs' limits takes longer than settle_timeout: the posture is skipped
    only once the planned move (from the latest leg lengths, at the limits) and settle_timeout
    are over."""
    nominal, limits = default_geometry('nominal'), MotionLimits()
    pose = home_pose() + [0.05, 0.0, 0.05, 0.0, 0.0, 0.0]
    start = posture_leg_lengths(nominal, home_pose())[0]
    move_s = float(move_time(start, posture_leg_lengths(nominal, pose)[0], limits))
    assert move_s > 1.0  # s: the case the rule is for
    collection = make(planned_move=timeouts.planned_move(nominal, limits))
    collection.sample(LEG_LENGTHS, T0 - 100 * MS, (start,), T0 - 99 * MS)
    collection.command(1, pose, 'c1', T0)
    collection.status(status('c1', names.STATE_MOVING, ''), T0 + 10 * MS)
    last_quiet = T0 + 10 * MS + int((2.0 + move_s - 0.1) * S)
    assert poll_until(collection, last_quiet, T0 + 10 * MS, step=10 * MS) == []
    (skip,) = poll_until(collection, last_quiet + 200 * MS, last_quiet, step=10 * MS)
    assert skip.reason == (
        f'not settled within {2.0 + move_s:g} s (the planned move {move_s:g} s '
        '+ settle_timeout 2 s)'
    )


def test_a_stall_of_the_caller_is_not_a_silence():
    """No call for 2 topic timeouts (the calibrator did not run): the topics get a new timeout
    from the end of the gap, and a posture whose messages come again is collected."""
    collection = make()
    settle(collection)
    assert collection.poll(T0 + 10 * MS + 2 * S) == []  # the stall ends here
    assert poll_until(collection, T0 + 2 * S + 900 * MS, T0 + 10 * MS + 2 * S, 10 * MS) == []
    events = []
    for j in range(4):
        events += instant(collection, T0 + 3 * S + 5 * MS * j)
    assert isinstance(events[0], RowReady)
    # ... but a topic that stays silent after the stall is named one timeout later.
    settle(collection, 2, T0 + 4 * S, 'c2')
    assert collection.poll(T0 + 7 * S) == []  # another stall
    (silent,) = poll_until(collection, T0 + 8 * S, T0 + 7 * S)
    assert isinstance(silent, TopicSilent) and silent.doing == 'collecting posture 2'


def test_a_backlog_of_the_caller_is_not_a_lack_of_progress():
    """A listener 1.5 s behind (a starved process) still delivers samples stamped before the
    start, for longer than topic_timeout: no failure; the samples after them make the row."""
    collection = make()
    settle(collection)
    start = T0 + 10 * MS
    for j in range(30):  # received over 1.5 s, stamped 1.5 s earlier
        now = start + 50 * MS * (j + 1)
        assert instant(collection, now - 1500 * MS, now=now) == []
    events = []
    for j in range(4):
        events += instant(collection, start + 5 * MS * j, now=start + 1550 * MS + MS * j)
    assert isinstance(events[0], RowReady)


def late_instants(collection, lag, until, skip=(), step=20 * MS):
    """Instants stamped from the command on (every ``step``, then every 5 ms from the start at
    T0 + 10 ms), each handled ``lag`` ns after its stamp, until one is stamped ``until``; the
    events."""
    events, stamp = [], T0
    while stamp <= until and not any(isinstance(e, FINAL_EVENTS) for e in events):
        events += instant(collection, stamp, now=stamp + lag, skip=skip)
        if skip:
            events += collection.poll(stamp + lag + MS)
        stamp += step if stamp < T0 + 10 * MS else 5 * MS
    return events


def test_a_posture_whose_samples_are_handled_30_s_late_gives_its_row():
    """The calibrator 30 s behind its streams (issue 26): the posture settles at T0 + 10 ms,
    its samples are handled 30 s later, each one; the bounds count in the samples' stamps, so
    the row comes (it was skipped after settle_timeout + topic_timeout of receipt time)."""
    collection = make()
    settle(collection)
    # The samples of the 30 s before, handled meanwhile (a backlog), then those of the posture.
    events = []
    for j in range(1500):
        stamp = T0 + 10 * MS - 30 * S + 20 * MS * j
        events += instant(collection, stamp, now=stamp + 30 * S)
    assert events == []
    events = late_instants(collection, 30 * S, T0 + 100 * MS)
    (row,) = events
    assert isinstance(row, RowReady) and row.posture == 1
    assert row.sample.stamp_ns >= T0 + 10 * MS
    np.testing.assert_allclose(row.sample.readings, R, rtol=0, atol=1e-12)


def test_a_silent_topic_is_named_also_when_the_others_are_handled_late():
    collection = make()
    settle(collection)
    events = late_instants(collection, 30 * S, T0 + 40 * S, skip=(ENCODER,))
    (silent,) = events
    assert isinstance(silent, TopicSilent) and silent.topic == names.TOPIC_ENCODER


def test_samples_stamped_before_the_start_but_off_the_wire_after_it_are_no_backlog():
    """A sensor clock 1 h behind: its samples, received after the settle, are no backlog; the
    pairs do not grow for topic_timeout and the run ends naming the counts."""
    collection = make()
    settle(collection)
    events = []
    for j in range(300):
        now = T0 + 11 * MS + 10 * MS * j
        stamp = now - 3600 * S
        events += collection.sample(LEG_LENGTHS, stamp, (Q,), now, received_ns=now)
        for stream, values in ((INCLINOMETER, R[:2]), (ENCODER, R[2:3]), (LVDT, R[3:])):
            events += collection.sample(stream, stamp + MS, tuple(values), now, received_ns=now)
        if events:
            break
    (failed,) = events
    assert isinstance(failed, NoSynchronisedPair)
    assert '0 leg-length and 0 complete device samples since settling' in failed.message


def test_a_silent_topic_is_named_while_the_others_are_handled_after_a_late_settle():
    """The platform dies as its settled status is handled, 3 s late: the device's samples from
    the start are handled quickly (a backlog), so their stamps pass topic_timeout before the
    handling time does. The leg-length topic is silent, and named: the data's time counts only
    once every stream has given samples."""
    collection = make()
    collection.command(1, POSE, 'c1', T0)
    late = T0 + 3 * S
    collection.status(status('c1', names.STATE_SETTLED, ''), late, start_ns=T0 + 10 * MS)
    events = []
    for j in range(1000):
        stamp, now = T0 + 11 * MS + 5 * MS * j, late + 5 * MS * j // 4
        for stream, values in ((INCLINOMETER, R[:2]), (ENCODER, R[2:3]), (LVDT, R[3:])):
            events += collection.sample(stream, stamp, tuple(values), now)
        if events:
            break
    (silent,) = events
    assert isinstance(silent, TopicSilent), silent
    assert silent.topic == names.TOPIC_LEG_LENGTHS


def test_of_several_silent_topics_the_one_silent_longest_is_named():
    collection = make()
    settle(collection)
    start = T0 + 10 * MS
    for j in range(11):  # the encoder stops first; 0.1 s later every topic stops
        assert instant(collection, start + 10 * MS * j, skip=(ENCODER,) if j else ()) == []
    assert collection.poll(start + 500 * MS) == []
    assert collection.poll(start + 990 * MS) == []
    (silent,) = collection.poll(start + 1450 * MS)  # all silent for over 1 s by now
    assert silent.topic == names.TOPIC_ENCODER


def test_a_resumed_run_compares_its_first_posture_with_the_last_kept_row():
    """The platform still stands at the posture cut short: its readings before the command
    equal the posture's, which is not a stale device."""
    collection = make()
    collection.continue_after(R - 0.05)  # the last kept row's readings
    instant(collection, T0 - 100 * MS)  # the platform already stands at posture 1
    settle(collection)
    for j in range(4):
        events = instant(collection, T0 + 11 * MS + 5 * MS * j)
    assert isinstance(events[0], RowReady)


def test_a_silent_sensor_topic_ends_the_collection():
    collection = make()
    settle(collection)
    start = T0 + 10 * MS
    # The leg lengths and two device topics keep coming, the encoder says nothing.
    events = []
    for j in range(300):
        stamp = start + 7 * MS * j
        events += instant(collection, stamp, skip=(ENCODER,))
        if events:
            break
    (silent,) = events
    assert isinstance(silent, TopicSilent) and silent.topic == names.TOPIC_ENCODER
    assert silent.doing == 'collecting posture 1'
    assert silent.message == (
        'topic /gsp/device/encoder is silent: no message for 1 s while collecting posture 1'
    )


def test_no_synchronised_sample_ends_the_run_with_the_counts():
    collection = make()
    settle(collection)
    start = T0 + 10 * MS
    events = []
    for j in range(300):  # device instants 5 ms off: never within sync_tolerance
        stamp = start + 10 * MS * j
        events += collection.sample(LEG_LENGTHS, stamp, (Q,), stamp)
        for stream, values in ((INCLINOMETER, R[:2]), (ENCODER, R[2:3]), (LVDT, R[3:])):
            events += collection.sample(stream, stamp + 5 * MS, tuple(values), stamp)
        if events:
            break
    (failed,) = events
    assert isinstance(failed, NoSynchronisedPair) and failed.posture == 1
    assert 'no synchronised sample for 1 s at posture 1' in failed.message
    assert '0 within sync_tolerance' in failed.message


def test_the_collection_ends_at_its_deadline_even_while_pairs_keep_coming():
    """Pairs that never form a consistent window: skipped after settle + topic timeouts."""
    collection = make()
    instant(collection, T0 - 100 * MS)  # previous readings == the posture's: never usable
    settle(collection)
    events = []
    for j in range(50):  # one pair every 100 ms: progress, but no window
        stamp = T0 + 11 * MS + 100 * MS * j
        events += instant(collection, stamp)
        if events:
            break
    (skipped,) = events
    assert isinstance(skipped, PostureSkipped) and not skipped.rejected_by_platform
    assert skipped.reason.startswith(
        'no 3 consistent synchronised samples within 3 s '
        '(settle_timeout + topic_timeout) of settling'
    )


def test_too_many_pairs_without_a_consistent_window_skip_the_posture():
    collection = make(max_pairs_per_sample=2)
    instant(collection, T0 - 100 * MS)
    settle(collection)
    events = []
    for j in range(10):
        events += instant(collection, T0 + 11 * MS + 5 * MS * j)
    assert events == [
        PostureSkipped(
            1,
            'no 3 consistent samples among 6 synchronised ones (too noisy, or the device '
            'readings did not change from the previous posture)',
        )
    ]


def test_the_previous_row_is_the_reference_of_the_next_posture():
    collection = make()
    settle(collection)
    for j in range(4):
        events = instant(collection, T0 + 11 * MS + 5 * MS * j)
    assert isinstance(events[0], RowReady)
    settle(collection, 2, T0 + S, 'c2')
    for j in range(10):  # the device still reports posture 1: not usable
        events = instant(collection, T0 + S + 11 * MS + 5 * MS * j)
        assert not events
    for j in range(4):
        events = instant(collection, T0 + S + 80 * MS + 5 * MS * j, readings=R + 0.01)
    assert isinstance(events[0], RowReady) and events[0].posture == 2
    np.testing.assert_allclose(events[0].sample.readings, R + 0.01)


def test_malformed_and_non_finite_messages_are_dropped_and_counted():
    collection = make()
    settle(collection)
    legs = conversions.leg_lengths_to_msg(Q, (T0 + 20 * MS) / 1e9)
    legs.position = [math.nan] * 6
    (dropped,) = collection.sensor(names.TOPIC_LEG_LENGTHS, legs, T0 + 21 * MS)
    assert isinstance(dropped, SampleDropped) and dropped.non_finite and dropped.count == 1
    bad = conversions.leg_lengths_to_msg(Q)
    bad.name = ['leg_1']
    bad.position = [0.5]
    (dropped,) = collection.sensor(names.TOPIC_LEG_LENGTHS, bad, T0 + 22 * MS)
    assert not dropped.non_finite
    assert collection.heard(names.TOPIC_LEG_LENGTHS)
    assert collection.summary() == {
        'skipped': [],
        'inconsistent_dropped': 0,
        'settling_dropped': 0,
        'non_finite_dropped': {'leg_lengths': 1, 'inclinometer': 0, 'encoder': 0, 'lvdt': 0},
    }


def test_keep_pairs_hands_over_every_pair_of_each_segment():
    collection = CollectionProtocol(0.0025, 1, keep_pairs=True)
    for j in range(3):
        instant(collection, T0 - 100 * MS + 5 * MS * j, q=Q + j)
    events = settle(collection)
    idle = events[0]
    assert isinstance(idle, PairsCollected) and idle.posture is None
    np.testing.assert_array_equal(idle.leg_lengths[:, 0], Q[0] + np.arange(3))
    for j in range(50):  # never ends a posture by itself
        assert not instant(collection, T0 + 11 * MS + 5 * MS * j, q=Q + j)
    events = collection.command(2, POSE, 'c2', T0 + S)
    events += collection.status(status('c2', names.STATE_REJECTED, 'no'), T0 + S + MS)
    (pairs, skipped) = events
    assert pairs.posture == 1 and pairs.command_id == 'c1' and len(pairs.stamps) == 50
    np.testing.assert_array_equal(pairs.leg_lengths[:, 0], Q[0] + np.arange(50))
    np.testing.assert_array_equal(pairs.readings, np.tile(R, (50, 1)))
    assert skipped.rejected_by_platform and skipped.platform_reason == 'no'
    collection.command(3, POSE, 'c3', T0 + 2 * S)
    assert collection.finish() == [PostureSkipped(3, 'never settled')]


def test_the_topic_table_and_the_noise_vector():
    assert topics.SENSOR_TOPICS == (
        names.TOPIC_LEG_LENGTHS,
        names.TOPIC_INCLINOMETER,
        names.TOPIC_ENCODER,
        names.TOPIC_LVDT,
    )
    stream, stamp, values = topics.read_sensor(
        names.TOPIC_INCLINOMETER, conversions.inclinometer_to_msg(0.1, 0.2, 1.5)
    )
    assert (stream, stamp, values) == (INCLINOMETER, 1_500_000_000, (0.1, 0.2))
    from gsp_kinematics.model.sensor_noise import SensorNoise

    sigmas = SensorNoise(leg_lengths=1.0, inclinometer=2.0, encoder=3.0, lvdt=4.0)
    assert sigmas.channel_std().tolist() == [1.0] * 6 + [2.0, 2.0, 3.0, 4.0]
    with pytest.raises(KeyError):
        topics.read_sensor('/not/a/sensor', None)


def settling_readings(rng, t, tau=0.1, step=2e-3):
    """Device readings at ``t`` s after the settle: alpha still approaches R with time
    constant ``tau`` from ``step`` rad off; every channel with its noise."""
    readings = R + rng.normal(size=4) * np.asarray(NOISE[6:])
    readings[0] += step * math.exp(-t / tau)
    return readings


def collect_settling(collection, rng, seconds, tau=0.1, step=2e-3):
    """Settle posture 1 (start T0 + 10 ms) and feed 200 Hz samples for ``seconds``; the
    events after the settle."""
    settle(collection)
    events = []
    for j in range(int(seconds * 200)):
        stamp = T0 + 11 * MS + 5 * MS * j
        t = (stamp - (T0 + 10 * MS)) * 1e-9
        q = Q + rng.normal(size=6) * 1e-6
        events += instant(collection, stamp, q=q, readings=settling_readings(rng, t, tau, step))
        if any(isinstance(e, FINAL_EVENTS) for e in events):
            break
    return events


def test_a_posture_waits_for_a_settling_sensor_and_its_wait_is_recorded():
    """alpha lags 2e-3 rad (118 sigma) with tau 0.1 s: the row waits until it is at rest."""
    rng = np.random.default_rng(3)
    collection = make(samples=10, rest_lookback=0.2)
    (*_, row) = collect_settling(collection, rng, 2.0)
    assert isinstance(row, RowReady)
    # The remaining lag at the averaged window is within the noise of the row's mean.
    wait = row.sample.rest_wait
    left = 2e-3 * math.exp(-wait / 0.1)
    assert left < 3 * NOISE[6] / math.sqrt(10)
    assert abs(row.sample.readings[0] - R[0]) < 5 * NOISE[6] / math.sqrt(10)
    assert wait >= 0.2 - 0.05  # not before the look-back is covered
    assert collection.summary()['settling_dropped'] == round(wait / 0.005)


def test_settle_timeout_bounds_the_wait_with_a_reason_naming_the_channel():
    rng = np.random.default_rng(4)
    collection = make(samples=10, rest_lookback=0.2, settle_timeout=0.5)
    (*_, skip) = collect_settling(collection, rng, 2.0, tau=30.0, step=0.1)  # a slow drift
    assert isinstance(skip, PostureSkipped) and skip.posture == 1
    assert 'not settled within settle_timeout 0.5 s' in skip.reason
    assert 'alpha still moving' in skip.reason


def test_the_look_back_sees_a_lag_the_window_alone_cannot():
    """The issue's case: tau 0.3 s, alpha 25 sigma off at the settle. Over the 50 ms window
    alone (rest_lookback 0) the trend is within the noise and the row comes at once,
    biased; judged over 0.6 s (2 tau) the row waits until the lag is within its noise."""
    sigma_of_mean = NOISE[6] / math.sqrt(10)
    step = 25 * NOISE[6]
    rows = {}
    for lookback in (0.0, 0.6):
        rng = np.random.default_rng(5)
        collection = make(samples=10, rest_lookback=lookback, settle_timeout=5.0)
        (*_, rows[lookback]) = collect_settling(collection, rng, 5.0, tau=0.3, step=step)
    biased, settled = rows[0.0].sample, rows[0.6].sample
    assert biased.rest_wait < 0.02 and biased.readings[0] - R[0] > 10 * sigma_of_mean
    assert settled.rest_wait > 0.6 and abs(settled.readings[0] - R[0]) < 4 * sigma_of_mean
    # The pairs waited out are counted as settling, not as inconsistent.
    assert rows[0.6].dropped == 0


def test_the_sample_rate_is_the_slowest_stream_s_as_heard():
    """Legs every 5 ms, the device every 20 ms (the LVDT at 50 Hz too): 50 Hz, the rate pairs
    can come at; unknown until every stream has given two samples."""
    collection = make()
    assert collection.latest.sample_rate_hz() is None
    for k in range(40):
        collection.sample(LEG_LENGTHS, T0 + k * 5 * MS, (Q,), T0 + k * 5 * MS)
    assert collection.latest.sample_rate_hz() is None  # no device sample yet
    for k in range(10):
        instant(collection, T0 + k * 20 * MS)
    assert collection.latest.sample_rate_hz() == pytest.approx(50.0)


def test_a_platform_the_device_measures_far_from_the_command_stops_the_run_without_its_row():
    from gsp_calibrator.collection.events import PlatformElsewhere
    from gsp_calibrator.settings import CalibratorSettings
    from gsp_kinematics.model.device import device_readings

    settings = CalibratorSettings.from_values({})
    nominal = settings.nominal
    at_command = device_readings(nominal, POSE[None])[0]
    # 60 mm lower along the link than commanded (an LVDT short by 60 mm): beyond the default.
    for readings, ends in ((at_command, RowReady), (at_command - [0, 0, 0, 0.06], None)):
        collection = CollectionProtocol.for_settings(settings)
        settle(collection)
        events = []
        for j in range(120):  # the rest rule's look-back and the window (0.6 s at 200 Hz)
            events += instant(collection, T0 + 11 * MS + 5 * MS * j, readings=readings)
        final = [event for event in events if isinstance(event, FINAL_EVENTS)]
        if ends is RowReady:
            assert isinstance(final[0], RowReady)
            continue
        (event,) = final
        assert isinstance(event, PlatformElsewhere) and event.posture == 1
        assert event.distance_m == pytest.approx(0.06, abs=1e-9)  # m
        assert event.limit_m == settings.max_posture_error == 0.05
        assert 'measures the platform 60 mm from the commanded position' in event.message
        assert collection._posture is None and collection.poll(T0 + 100 * S) == []
