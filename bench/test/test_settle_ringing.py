"""The default rest rule on a platform that rings after each move (pure, no ROS).

The platform reports ``settled`` while it still oscillates (0.4 mm/s peak, decaying); the
inclinometer, an accelerometer, sees the oscillation's acceleration
(:mod:`gsp_bench.settle_ringing`). At the calibrator's default rest rule the
rows are averaged only once the readings are at rest: their error is the noise's, not the
ringing's.
"""

import numpy as np
import pytest

from gsp_bench.settle_ringing import RATE_HZ, RINGS, collect
from gsp_calibrator.collection.synchroniser import SampleCollector
from gsp_calibrator.settings import DEFAULTS
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE

POSES = sample_valid_postures(default_geometry('nominal'), 12, np.random.default_rng(7))


def test_a_ringing_platform_is_waited_out_by_the_default_rule():
    """5 Hz, 0.4 mm/s, decaying with 0.1 s: the inclinometer reads up to 1.3 mrad (73 sigma)
    of acceleration at the settle. The rows wait until it is gone: their error is noise (RMS
    about 1 of their stds; a row averaged while it rings is off by tens)."""
    errors, waits = collect(POSES, RINGS['5 Hz, 0.1 s'], seed=1)
    rms = np.sqrt(np.mean(errors**2, axis=0))
    assert rms.max() < 2.0, rms  # chi-square 99.9 % bound of 12 unit normals: RMS 1.62
    assert np.all(waits > DEFAULTS['rest_lookback'])


def test_a_still_platform_waits_only_for_the_look_back():
    """The kinematic backend (no ringing, instant white sensors): each row is the first whose
    look-back is covered (the look-back less the window), rarely a few samples more."""
    errors, waits = collect(POSES, RINGS['still'], seed=2)
    first = DEFAULTS['rest_lookback'] - (DEFAULTS['pairs_per_posture'] - 1) / RATE_HZ
    assert np.median(waits) == pytest.approx(first, abs=0.5 / RATE_HZ)
    assert waits.max() < first + 0.05
    assert np.sqrt(np.mean(errors**2)) < 1.6


def test_the_look_back_counts_from_the_first_pair_wherever_the_stream_starts():
    """The same samples, starting 0.5 ms or 10.5 ms after the settle (a replay restarts the
    stream at its first recorded sample, later than the original did), give the same row."""
    rng = np.random.default_rng(3)
    noise = DEFAULT_SENSOR_NOISE
    legs = 0.6 + rng.normal(size=(80, 6)) * noise.leg_lengths
    readings = np.array([0.01, -0.02, 0.3, 0.004]) + rng.normal(size=(80, 4)) * noise.readings()
    rows = []
    for lead_ns in (500_000, 10_500_000):
        collector = SampleCollector(
            0.5 / RATE_HZ,
            DEFAULTS['pairs_per_posture'],
            noise_std=noise.channel_std(),
            rest_lookback=DEFAULTS['rest_lookback'],
        )
        collector.start(0)
        for i in range(80):
            stamp = lead_ns + i * 5_000_000
            collector.add_leg_lengths(stamp, legs[i])
            collector.add_inclinometer(stamp, *readings[i, :2])
            collector.add_encoder(stamp, readings[i, 2])
            collector.add_lvdt(stamp, readings[i, 3])
            if collector.ready():
                rows.append((i, collector.take_posture()))
                break
    (first, row), (again, replayed) = rows
    assert first == again
    np.testing.assert_array_equal(row.readings, replayed.readings)
