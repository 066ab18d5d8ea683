"""SampleCollector: stamp matching, filtering, averaging (pure, no ROS)."""

import math

import numpy as np
import pytest

from gsp_calibrator.collection.synchroniser import (
    ENCODER,
    INCLINOMETER,
    LEG_LENGTHS,
    LVDT,
    SampleCollector,
    seconds_to_ns,
)

MS = 1_000_000
T0 = 1_000_000 * MS
Q = np.array([0.5, 0.51, 0.52, 0.53, 0.54, 0.55])
R = np.array([0.01, -0.02, 0.3, 0.004])
NOISE = [1e-6] * 6 + [1.7e-5, 1.7e-5, 1.7e-5, 1e-6]


def add_device(collector, stamp, readings=R, skip=()):
    if INCLINOMETER not in skip:
        collector.add_inclinometer(stamp, readings[0], readings[1])
    if ENCODER not in skip:
        collector.add_encoder(stamp, readings[2])
    if LVDT not in skip:
        collector.add_lvdt(stamp, readings[3])


def feed(collector, count, leg_offset_ms=1.0, period_ms=5.0, start=T0, q=Q, readings=R):
    """``count`` leg samples and ``count`` device instants, device ``leg_offset_ms`` later."""
    for i in range(count):
        stamp = start + int(i * period_ms * MS)
        collector.add_leg_lengths(stamp, q)
        add_device(collector, stamp + int(leg_offset_ms * MS), readings)


def test_pairs_are_nearest_stamps_within_the_tolerance():
    collector = SampleCollector(sync_tolerance=0.0025, pairs_per_posture=3)
    collector.start(T0)
    feed(collector, 3, leg_offset_ms=2.0)
    assert collector._pairing.pairs == [
        (T0 + i * 5 * MS, T0 + i * 5 * MS + 2 * MS) for i in range(3)
    ]
    assert collector.ready()


def test_device_farther_than_the_tolerance_is_not_paired():
    collector = SampleCollector(sync_tolerance=0.001, pairs_per_posture=1)
    collector.start(T0)
    collector.add_leg_lengths(T0, Q)
    add_device(collector, T0 + 2 * MS)
    assert collector._pairing.pairs == [] and not collector.ready()
    add_device(collector, T0 + MS)  # exactly at the tolerance: paired
    assert collector._pairing.pairs == [(T0, T0 + MS)]


def test_pairing_is_one_to_one():
    collector = SampleCollector(sync_tolerance=0.003, pairs_per_posture=2)
    collector.start(T0)
    collector.add_leg_lengths(T0, Q)
    collector.add_leg_lengths(T0 + 2 * MS, Q)
    add_device(collector, T0 + MS)
    assert len(collector._pairing.pairs) == 1
    add_device(collector, T0 + 4 * MS)
    assert collector._pairing.pairs == [(T0, T0 + MS), (T0 + 2 * MS, T0 + 4 * MS)]


def test_out_of_order_messages_pair_the_same():
    ordered = SampleCollector(0.0025, 5)
    ordered.start(T0)
    feed(ordered, 5)
    shuffled = SampleCollector(0.0025, 5)
    shuffled.start(T0)
    events = []
    for i in range(5):
        stamp = T0 + i * 5 * MS
        events.append(lambda c, s=stamp: c.add_leg_lengths(s, Q))
        events.append(lambda c, s=stamp: c.add_lvdt(s + MS, R[3]))
        events.append(lambda c, s=stamp: c.add_encoder(s + MS, R[2]))
        events.append(lambda c, s=stamp: c.add_inclinometer(s + MS, R[0], R[1]))
    for index in np.random.default_rng(3).permutation(len(events)):
        events[index](shuffled)
    assert shuffled._pairing.pairs == ordered._pairing.pairs
    assert shuffled.ready()


def test_an_instant_with_a_missing_device_topic_is_never_used():
    collector = SampleCollector(0.0025, 2)
    collector.start(T0)
    collector.add_leg_lengths(T0, Q)
    add_device(collector, T0 + MS, skip=(ENCODER,))
    collector.add_leg_lengths(T0 + 5 * MS, Q)
    add_device(collector, T0 + 6 * MS)
    assert collector._pairing.pairs == [(T0 + 5 * MS, T0 + 6 * MS)]
    assert not collector.ready()
    collector.add_encoder(T0 + MS, R[2])  # the late message completes the instant
    assert collector.ready()


def test_non_finite_readings_are_dropped_and_counted():
    collector = SampleCollector(0.0025, 1)
    collector.start(T0)
    assert not collector.add_leg_lengths(T0, [np.nan, 0, 0, 0, 0, 0])
    assert not collector.add_inclinometer(T0, math.inf, 0.0)
    assert not collector.add_encoder(T0, -math.inf)
    assert not collector.add_lvdt(T0, math.nan)
    collector.record_non_finite(LVDT)
    assert collector.non_finite == {LEG_LENGTHS: 1, INCLINOMETER: 1, ENCODER: 1, LVDT: 2}
    assert collector._pairing.pairs == []


def test_samples_before_the_start_time_or_while_stopped_are_ignored():
    collector = SampleCollector(0.0025, 2)
    feed(collector, 2)  # not started: ignored
    assert collector.pair_count() == 0
    collector.start(T0 + 10 * MS)
    feed(collector, 4)  # stamps T0, +5, +10, +15 ms: the first two are too early
    assert [leg for leg, _ in collector._pairing.pairs] == [T0 + 10 * MS, T0 + 15 * MS]


def test_average_and_take_posture():
    collector = SampleCollector(0.0025, 4)
    collector.start(T0)
    rng = np.random.default_rng(0)
    legs, readings = Q + rng.normal(0, 1e-6, (6, 6)), R + rng.normal(0, 1e-5, (6, 4))
    for i in range(6):
        collector.add_leg_lengths(T0 + i * 5 * MS, legs[i])
        add_device(collector, T0 + i * 5 * MS + MS, readings[i])
    row = collector.take_posture()
    np.testing.assert_allclose(row.leg_lengths, legs[:4].mean(axis=0), rtol=0, atol=1e-15)
    np.testing.assert_allclose(row.readings, readings[:4].mean(axis=0), rtol=0, atol=1e-15)
    np.testing.assert_allclose(row.leg_lengths_std, legs[:4].std(axis=0, ddof=1))
    # The window's lag sums (lags 0..2) per noise channel: lag 0 is (n - 1) s^2 summed over
    # the channel's columns (m^2, rad^2).
    assert row.lag_sums.shape == (4, 3)
    np.testing.assert_allclose(
        row.lag_sums[0, 0], 3 * np.sum(legs[:4].var(axis=0, ddof=1)), rtol=1e-9
    )
    np.testing.assert_allclose(
        row.lag_sums[1, 0], 3 * np.sum(readings[:4, :2].var(axis=0, ddof=1)), rtol=1e-9
    )
    centred = readings[:4, 3] - readings[:4, 3].mean()
    np.testing.assert_allclose(row.lag_sums[3, 1], centred[:-1] @ centred[1:], rtol=1e-9)
    assert row.n_samples == 4
    assert row.stamp_ns == T0 + 7 * MS + MS // 2 and row.stamp == pytest.approx(row.stamp_ns / 1e9)
    # Collection stops after taking the posture.
    assert collector.start_ns is None and collector.pair_count() == 0
    with pytest.raises(ValueError, match='synchronised samples'):
        collector.take_posture()


def test_phi_is_averaged_on_the_circle():
    collector = SampleCollector(0.0025, 2)
    collector.start(T0)
    collector.add_leg_lengths(T0, Q)
    add_device(collector, T0, [0.0, 0.0, math.pi - 0.01, 0.0])
    collector.add_leg_lengths(T0 + 5 * MS, Q)
    add_device(collector, T0 + 5 * MS, [0.0, 0.0, -math.pi + 0.03, 0.0])
    row = collector.take_posture()
    assert row.readings[2] == pytest.approx(-math.pi + 0.01, abs=1e-12)


def test_inconsistent_first_pairs_are_dropped_for_a_consistent_window():
    """Readings that still describe the previous posture (a lagging stream) are not averaged."""
    collector = SampleCollector(0.0025, 3, noise_std=NOISE)
    collector.start(T0)
    stale = R + np.array([0.05, 0.0, 0.2, 0.01])
    feed(collector, 2, readings=stale)
    feed(collector, 2, start=T0 + 10 * MS)
    assert collector.pair_count() == 4 and not collector.ready()
    feed(collector, 1, start=T0 + 20 * MS)
    assert collector.ready()
    row = collector.take_posture()
    np.testing.assert_allclose(row.readings, R, atol=1e-15)
    assert collector.inconsistent == 2


def test_a_window_unchanged_from_the_previous_posture_is_not_used():
    collector = SampleCollector(0.0025, 3, noise_std=NOISE)
    previous = R + np.array([0.05, 0.0, 0.2, 0.01])
    collector.start(T0, previous_readings=previous)
    feed(collector, 3, readings=previous)  # the device has not caught up yet
    assert not collector.ready()
    feed(collector, 3, start=T0 + 15 * MS)
    row = collector.take_posture()
    np.testing.assert_allclose(row.readings, R, atol=1e-15)
    # Without the previous readings, the same (stale) window would have been taken.
    plain = SampleCollector(0.0025, 3, noise_std=NOISE)
    plain.start(T0)
    feed(plain, 3, readings=previous)
    assert plain.ready()


def test_noise_does_not_make_a_window_inconsistent():
    rng = np.random.default_rng(7)
    collector = SampleCollector(0.0025, 10, noise_std=NOISE)
    collector.start(T0)
    for i in range(10):
        collector.add_leg_lengths(T0 + i * 5 * MS, Q + rng.normal(0, 1e-6, 6))
        add_device(collector, T0 + i * 5 * MS + MS, R + rng.normal(0, 1, 4) * NOISE[6:])
    assert collector.ready()
    assert collector.take_posture().n_samples == 10 and collector.inconsistent == 0


def test_buffers_are_bounded():
    collector = SampleCollector(0.0025, 2, max_buffer=5)
    collector.start(T0)
    feed(collector, 20)
    assert collector.counts()[LEG_LENGTHS] == 5 and collector.counts()['device'] == 5


@pytest.mark.parametrize(
    'kwargs, match',
    [
        ({'sync_tolerance': -1.0, 'pairs_per_posture': 1}, 'sync_tolerance'),
        ({'sync_tolerance': math.nan, 'pairs_per_posture': 1}, 'sync_tolerance'),
        ({'sync_tolerance': 0.001, 'pairs_per_posture': 0}, 'pairs_per_posture'),
        ({'sync_tolerance': 0.001, 'pairs_per_posture': 5, 'max_buffer': 2}, 'max_buffer'),
        ({'sync_tolerance': 0.001, 'pairs_per_posture': 5, 'noise_std': [0.0] * 10}, 'noise_std'),
    ],
)
def test_invalid_settings_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SampleCollector(**kwargs)


def test_seconds_to_ns():
    assert seconds_to_ns(0.0025) == 2_500_000
