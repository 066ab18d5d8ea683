"""Noise of the averaged row from correlated samples, and the rest test, on known answers."""

import math

import numpy as np
import pytest

from gsp_kinematics.estimation.noise_estimate import (
    NoiseEstimateError,
    false_unsettled_rate,
    noise_of_mean,
    noise_of_mean_from_sums,
    rest_test,
    scatter_test,
    trend_std_factor,
    window_lag_sums,
)

DT = 0.005  # s, 200 Hz


def ar1_windows(rng, postures, n, phi, sigma):
    """(postures, n, len(sigma)) stationary AR(1) windows of stationary std ``sigma``."""
    sigma = np.asarray(sigma, dtype=float)
    z = np.empty((postures, n, sigma.size))
    z[:, 0] = rng.normal(size=(postures, sigma.size))
    for t in range(1, n):
        z[:, t] = phi * z[:, t - 1] + math.sqrt(1 - phi**2) * rng.normal(
            size=(postures, sigma.size)
        )
    return z * sigma


def exact_std_of_mean(n, phi, sigma):
    """Std of the mean of n stationary AR(1) samples: (sigma^2/n) [1 + 2 sum (1 - k/n) phi^k]."""
    k = np.arange(1, n)
    return sigma * math.sqrt((1 + 2 * np.sum((1 - k / n) * phi**k)) / n)


def test_white_noise_gives_n_eff_n_and_s_over_sqrt_n():
    postures, n, sigma = 2000, 20, np.array([1e-6, 1.7e-5, 3e-4])
    samples = np.random.default_rng(1).normal(size=(postures, n, 3)) * sigma + [0.1, 2, -3]
    estimate = noise_of_mean(samples)
    # The variance of the mean pools ~postures x (n - 1) squares: relative standard error of
    # its root 1/sqrt(2 postures (n - 1)), widened 3x for the summed lags; 5 of those.
    tolerance = 5 * 3 / math.sqrt(2 * postures * (n - 1))
    np.testing.assert_allclose(estimate.std_of_mean, sigma / math.sqrt(n), rtol=tolerance)
    np.testing.assert_allclose(estimate.sample_std, sigma, rtol=tolerance)
    np.testing.assert_allclose(estimate.n_eff, n, rtol=2 * tolerance)
    assert not estimate.window_too_short.any()


@pytest.mark.parametrize('phi', [0.5, 0.8, 0.9])
def test_ar1_std_of_mean_matches_the_exact_finite_n_formula(phi):
    postures, n, sigma = 2000, 100, np.array([1e-6, 2e-5])
    samples = ar1_windows(np.random.default_rng(2), postures, n, phi, sigma)
    estimate = noise_of_mean(samples)
    exact = np.array([exact_std_of_mean(n, phi, s) for s in sigma])
    # The std of the mean rests on about postures x n_eff independent values: relative
    # standard error of its root ~ 1/sqrt(2 postures n_eff), widened 3x for the summed lags.
    n_eff = n * (1 - phi) / (1 + phi)
    tolerance = 5 * 3 / math.sqrt(2 * postures * n_eff)
    np.testing.assert_allclose(estimate.std_of_mean, exact, rtol=tolerance)
    np.testing.assert_allclose(estimate.sample_std, sigma, rtol=tolerance)
    # Asymptotically n_eff = n (1 - phi) / (1 + phi); at finite n slightly more.
    exact_n_eff = (sigma / exact) ** 2
    np.testing.assert_allclose(estimate.n_eff, exact_n_eff, rtol=2 * tolerance)
    # And it is what the windows' means actually scatter by (their true level is 0).
    observed = np.sqrt(np.mean(samples.mean(axis=1) ** 2, axis=0))
    np.testing.assert_allclose(estimate.std_of_mean, observed, rtol=2 * tolerance)
    # The white formula s / sqrt(n) would be far too optimistic.
    assert np.all(samples.std(axis=1, ddof=1).mean(axis=0) / math.sqrt(n) < 0.6 * exact)


def test_short_white_windows_are_not_flagged():
    samples = np.random.default_rng(4).normal(size=(2000, 10, 2))
    estimate = noise_of_mean(samples)
    assert not estimate.window_too_short.any()
    np.testing.assert_allclose(estimate.n_eff, 10, rtol=0.15)


def test_windows_short_against_the_correlation_time_are_flagged():
    samples = ar1_windows(np.random.default_rng(3), 500, 10, 0.99, np.array([1.0]))
    assert noise_of_mean(samples).window_too_short.all()


@pytest.mark.parametrize(
    'shape, match',
    [((5, 10), 'postures, samples, channels'), ((3, 1, 2), 'at least 2 samples')],
)
def test_bad_windows_are_refused(shape, match):
    with pytest.raises(NoiseEstimateError, match=match):
        noise_of_mean(np.zeros(shape))


def test_trend_std_factor_is_the_white_trend_std():
    rng = np.random.default_rng(6)
    n = 10
    samples = rng.normal(size=(20000, n))
    t = np.arange(n) - (n - 1) / 2
    trend = samples @ t / (t @ t) * (n - 1)
    assert trend.std() == pytest.approx(
        trend_std_factor(n) / math.sqrt(n), rel=5 / math.sqrt(2 * 20000)
    )


def test_lag_sums_are_additive_over_windows_and_give_the_same_estimate():
    # What each posture contributes (its window's lag sums) pools into the estimate of all.
    samples = ar1_windows(np.random.default_rng(8), 40, 30, 0.7, np.array([1e-6, 3e-5]))
    parts = window_lag_sums(samples)
    pooled = noise_of_mean_from_sums(parts.sum(axis=0), 30, 40)
    direct = noise_of_mean(samples)
    np.testing.assert_allclose(pooled.std_of_mean, direct.std_of_mean, rtol=1e-12)
    np.testing.assert_array_equal(pooled.lags, direct.lags)
    with pytest.raises(NoiseEstimateError, match='fewer than n lags'):
        noise_of_mean_from_sums(parts.sum(axis=0), 10, 40)


def test_the_whiteness_test_gives_white_samples_exactly_the_pooled_scatter():
    samples = np.random.default_rng(9).normal(size=(60, 10, 4)) * [1e-6, 1.0, 3.0, 1e-3]
    estimate = noise_of_mean(samples, white_level=0.01)
    pooled = np.sqrt(samples.var(axis=1, ddof=1).mean(axis=0) / 10)
    np.testing.assert_allclose(estimate.std_of_mean, pooled, rtol=1e-12)
    assert (estimate.lags == 0).all() and not estimate.window_too_short.any()
    # Correlated samples pass the test and keep their lags.
    correlated = ar1_windows(np.random.default_rng(10), 60, 10, 0.9, np.array([1.0]))
    assert noise_of_mean(correlated, white_level=0.01).lags[0] > 0


def first_settled_windows(signal, times, lookback, window):
    """Per seed, the start index of the first ``window``-sample window judged settled over the
    ``lookback`` samples ending with it (rest_test vectorised over seeds), or -1."""
    seeds, n = signal.shape[:2]
    first = np.full(seeds, -1)
    for end in range(lookback - 1, n):
        span = slice(end - lookback + 1, end + 1)
        verdict = rest_test(signal[:, span], times[span])
        newly = (first < 0) & verdict.settled[:, 0]
        first[newly] = end - window + 1
    return first


def test_settle_rule_waits_out_an_exponential_approach_until_the_offset_is_below_the_noise():
    """The issue's numbers: tau 0.3 s at 200 Hz, 10-sample window, judged over 2 tau."""
    rng = np.random.default_rng(11)
    seeds, sigma, tau, window, lookback = 400, 1.0, 0.3, 10, 120
    times = np.arange(600) * DT  # 3 s after the platform settled
    offset = 300.0 * sigma * np.exp(-times / tau)  # a tilt step of 300 sigma, lagging
    signal = (offset + rng.normal(size=(seeds, times.size)) * sigma)[:, :, None]
    first = first_settled_windows(signal, times, lookback, window)
    assert np.all(first >= 0)
    # The bias left in the averaged window, against the per-sample noise and the mean's noise.
    left = np.array([offset[f : f + window].mean() for f in first])
    assert np.median(left) < sigma / math.sqrt(window)
    assert np.percentile(left, 95) < sigma
    # The worked example's window (still 18 sigma off) is never taken: it would have been
    # without the rule (the old consistency rule accepts it, see the test above).
    start_18 = int(np.searchsorted(-offset, -18.0 * sigma))
    assert np.all(first > start_18)


@pytest.mark.parametrize('n', [10, 40])
def test_settle_test_calls_settled_white_spans_moving_at_the_nominal_rate(n):
    rng = np.random.default_rng(12 + n)
    spans, sigma = 40000, 3e-6
    verdict = rest_test(rng.normal(size=(spans, n, 1)) * sigma + 0.2, np.arange(n) * DT)
    rate, expected = 1 - verdict.settled.mean(), false_unsettled_rate()
    standard_error = math.sqrt(expected / spans)
    # Exact (Student-t) for spans too short to count correlation; slightly below the nominal
    # rate where the chance lags the truncation keeps make the noise a little larger.
    assert expected - 5 * standard_error < rate < expected + 5 * standard_error


@pytest.mark.parametrize('n', [10, 50])
def test_scatter_test_calls_white_spans_moving_at_most_at_the_nominal_rate(n):
    """At the configured noise a white span is called moving at most at the nominal rate; at
    3 times it (a device noisier than configured: the noise between successive samples is
    believed, estimated from the span) at most 4 times that (0.76 % measured at 10 samples)."""
    rng = np.random.default_rng(30 + n)
    spans, sigma = 40000, 3e-6
    expected = false_unsettled_rate()
    for true_sigma, limit in ((sigma, expected), (3 * sigma, 4 * expected)):
        values = rng.normal(size=(spans, n, 1)) * true_sigma + 0.2
        ratio, threshold = scatter_test(values, [sigma])
        assert np.mean(ratio > threshold) < limit + 5 * math.sqrt(expected / spans)


def test_a_ringing_span_shows_no_trend_but_scatters_beyond_its_noise():
    """5 Hz for 0.25 s, 4 sigma peak, on white noise: whole periods have no trend, so the trend
    test (its noise the span's own) passes it; its scatter is 2.5 times the noise."""
    rng = np.random.default_rng(4)
    sigma, times = 2e-5, np.arange(50) * DT
    values = (4 * sigma * np.sin(2 * math.pi * 5.0 * times) + rng.normal(size=50) * sigma)[:, None]
    assert rest_test(values, times, noise_floor=[sigma]).settled.all()
    ratio, threshold = scatter_test(values, [sigma])
    assert ratio[0] > 1.5 * threshold
    assert scatter_test(values, [3 * sigma])[0][0] < threshold  # a noisier sensor
    with pytest.raises(NoiseEstimateError, match='noise_std'):
        scatter_test(values, [0.0])


def test_settle_test_noise_floor_keeps_a_noiseless_channel_settled():
    flat = np.full((12, 2), 0.3) + np.arange(12)[:, None] * np.array([1e-15, 0.0])
    assert not rest_test(flat).settled[0]  # a ramp of a few ulps on no noise
    assert rest_test(flat, noise_floor=[1e-9, 1e-9]).settled.all()
