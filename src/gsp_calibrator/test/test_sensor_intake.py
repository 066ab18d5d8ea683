"""How the calibrator takes its sensor streams: JointState CDR bytes read without building the
message, and the processing lag it reports on /diagnostics (no ROS graph)."""

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from gsp_calibrator.collection.events import SampleDropped
from gsp_calibrator.collection.joint_state_cdr import read_joint_state
from gsp_calibrator.collection.protocol import CollectionProtocol
from gsp_calibrator.collection.topics import read_sensor
from gsp_calibrator.run.health import (
    LAG_CEILING_S,
    LAG_FLOOR_S,
    LAG_WARN_S,
    LagHistogram,
    ProcessingLags,
    calibrator_health,
    topic_lag_key,
)
from gsp_msgs_py import conversions, names
from gsp_msgs_py.health import OK, WARN

MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000


def joint_state(names_, position, velocity=(), effort=(), frame='gsp_base', stamp=(7, 123)):
    msg = JointState()
    msg.header.stamp = Time(sec=stamp[0], nanosec=stamp[1])
    msg.header.frame_id = frame
    msg.name, msg.position, msg.velocity, msg.effort = list(names_), position, velocity, effort
    return msg


@pytest.mark.parametrize(
    'msg',
    [
        joint_state(names.LEG_JOINT_NAMES, [0.5, 0.51, 0.52, 0.53, 0.54, 0.55]),
        joint_state(['alpha', 'beta'], [1e-3, -2e-3], velocity=[0.1], effort=[1.0, 2.0]),
        joint_state(['phi'], [math.pi], frame='', stamp=(-1, 999_999_999)),
        joint_state(['lvdt_ü', 'x'], [math.nan, -0.0], frame='a_frame_of_odd_length'),
        joint_state([], []),
    ],
)
def test_the_cdr_reader_gives_the_fields_of_the_message(msg):
    fields = read_joint_state(serialize_message(msg))
    assert (fields.header.stamp.sec, fields.header.stamp.nanosec) == (
        msg.header.stamp.sec,
        msg.header.stamp.nanosec,
    )
    assert fields.header.frame_id == msg.header.frame_id and fields.name == list(msg.name)
    for field in ('position', 'velocity', 'effort'):
        np.testing.assert_array_equal(getattr(fields, field), list(getattr(msg, field)))
    assert read_joint_state(serialize_message(msg)).name == list(msg.name)  # (names cached)


def test_truncated_or_foreign_bytes_are_dropped_with_a_reason_and_non_finite_ones_counted():
    good = serialize_message(conversions.encoder_to_msg(0.3, Time(sec=1)))
    for bad in (good[:40], good[:10], b'', b'\x01\x02\x03\x04garbage'):
        with pytest.raises(ValueError):
            read_joint_state(bad)
        with pytest.raises(ValueError, match='not a sensor_msgs/JointState'):
            read_sensor(names.TOPIC_ENCODER, bad)
    collection = CollectionProtocol(0.0025, 3)
    (dropped,) = collection.sensor(names.TOPIC_ENCODER, good[:40], T0)
    assert isinstance(dropped, SampleDropped) and not dropped.non_finite
    nan = serialize_message(joint_state(['phi'], [math.nan]))
    (dropped,) = collection.sensor(names.TOPIC_ENCODER, nan, T0)
    assert dropped.non_finite and collection.summary()['non_finite_dropped']['encoder'] == 1


def test_a_posture_collected_from_cdr_bytes_equals_the_one_from_messages():
    rng = np.random.default_rng(0)
    stamps = [T0 + 20 * MS + 5 * MS * j for j in range(12)]
    values = [(rng.normal(0.5, 1e-6, 6), rng.normal(0.0, 1e-5, 4)) for _ in stamps]
    rows = []
    for raw in (False, True):
        collection = CollectionProtocol(0.0025, 10, [1e-6] * 6 + [1e-5] * 4)
        collection.command(1, np.zeros(6), 'c1', T0)
        settled = conversions.make_status('c1', names.STATE_SETTLED, '')
        collection.status(conversions.parse_status(settled), T0 + 10 * MS)
        events = []
        for stamp_ns, (q, r) in zip(stamps, values, strict=True):
            stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
            for topic, msg in (
                (names.TOPIC_LEG_LENGTHS, conversions.leg_lengths_to_msg(q, stamp)),
                (names.TOPIC_INCLINOMETER, conversions.inclinometer_to_msg(r[0], r[1], stamp)),
                (names.TOPIC_ENCODER, conversions.encoder_to_msg(r[2], stamp)),
                (names.TOPIC_LVDT, conversions.lvdt_to_msg(r[3], stamp)),
            ):
                msg = serialize_message(msg) if raw else msg
                events += collection.sensor(topic, msg, stamp_ns + MS)
        (row,) = events
        rows.append(row.sample)
    np.testing.assert_array_equal(rows[0].leg_lengths, rows[1].leg_lengths)
    np.testing.assert_array_equal(rows[0].readings, rows[1].readings)
    assert rows[0].stamp_ns == rows[1].stamp_ns


def test_the_processing_lag_is_the_largest_since_the_previous_report():
    lags = ProcessingLags(['/a', '/b'])
    assert lags.note('/a', T0, T0 + 300 * MS) == pytest.approx(0.3)
    lags.note('/a', T0, T0 + 1200 * MS)
    lags.note('/a', T0, T0 + 100 * MS)
    assert lags.note('/b', 0, T0) is None  # no receive time from the middleware: not counted
    assert lags.take() == {'/a': pytest.approx(1.2), '/b': None}
    assert lags.take() == {'/a': None, '/b': None}


def test_the_lag_percentiles_are_the_nearest_rank_ones_to_one_percent():
    lags = np.random.default_rng(7).permutation(np.arange(1, 1001) * 1e-3)  # 1 ms .. 1 s
    histogram = LagHistogram()
    assert histogram.summary() == {'count': 0, 'p50_s': None, 'p99_s': None, 'max_s': None}
    for lag in lags:
        histogram.add(lag)
    summary = histogram.summary()
    assert summary['count'] == 1000 and summary['max_s'] == 1.0
    # Nearest rank: the 500th and the 990th smallest lags, to the bins' 1 %, never below them.
    assert 0.5 <= summary['p50_s'] <= 0.5 * 1.01
    assert 0.99 <= summary['p99_s'] <= 0.99 * 1.01
    assert histogram.percentile(100) == 1.0  # capped at the largest lag, not its bin's edge


def test_the_lag_histogram_keeps_tiny_negative_and_huge_lags():
    histogram = LagHistogram()
    for lag in (-0.5, 0.0, 1e-9):  # a clock step, none, below the first bin's edge
        histogram.add(lag)
    assert histogram.percentile(100) == 1e-9  # the largest, though its bin reaches LAG_FLOOR_S
    histogram.add(2 * LAG_FLOOR_S)
    assert histogram.percentile(75) == LAG_FLOOR_S  # the first bin's upper edge
    assert histogram.percentile(76) == 2 * LAG_FLOOR_S
    histogram.add(10 * LAG_CEILING_S)  # beyond the last bin: its percentile is the largest lag
    assert histogram.percentile(100) == 10 * LAG_CEILING_S and histogram.count == 5


def test_a_runs_lags_are_per_topic_and_start_afresh():
    run_lags = ProcessingLags(['/a', '/b'])
    for lag in (0.002, 0.004, 0.3):
        run_lags.note('/a', T0, T0 + int(lag * 1e9), in_run=True)
    run_lags.note('/a', T0, T0 + 500 * MS)  # not the run's
    run_lags.note('/b', 0, T0, in_run=True)  # an unknown receive time: not counted
    summary = run_lags.summary()
    assert summary['/a']['count'] == 3 and summary['/a']['max_s'] == pytest.approx(0.3)
    assert summary['/b'] == {'count': 0, 'p50_s': None, 'p99_s': None, 'max_s': None}
    run_lags.reset()
    assert run_lags.summary()['/a']['count'] == 0


def test_a_lag_above_one_second_warns_with_its_number():
    heard = dict.fromkeys(['/a', '/b'], T0)

    def health(lag_b):
        return calibrator_health(True, None, '', heard, T0, 2.0, lags={'/a': 0.01, '/b': lag_b})

    fine = health(LAG_WARN_S - 0.1)
    assert fine.level == OK and fine.values[topic_lag_key('/b')] == '0.900'
    behind = health(2.5)
    assert behind.level == WARN and behind.values[topic_lag_key('/b')] == '2.500'
    assert 'behind its streams by more than 1 s: /b 2.5 s' in behind.message
    assert '/a' not in behind.message.split('behind')[1]
    assert health(None).values[topic_lag_key('/b')] == 'none'
