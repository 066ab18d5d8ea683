"""Noise of an averaged row from correlated samples, and a settle test for a window (pure numpy).

A posture's row is the mean of ``n`` samples. With correlated samples its std is not ``s/sqrt(n)``:
``var(mean) = (1/n) [g0 + 2 sum_k (1 - k/n) g_k]``, with ``g_k`` the lag-k autocovariance, and
the effective sample count is ``n_eff = g0 / var(mean)``. :func:`noise_of_mean` estimates both per
channel from the scatter within each posture (the posture's own level is removed), pooled over
postures. docs/sensor_errors.md explains the choices (truncation, the bias of removing each
posture's mean, and the windows too short to tell).
"""

import dataclasses
import math

import numpy as np

#: Default of :func:`settled`: a channel is still moving when its trend exceeds this many
#: standard deviations of the trend of a settled window.
DEFAULT_SETTLE_SIGMAS = 3.0


#: Below this effective sample count a window is too short against the correlation time: the
#: estimate of the std of the mean is then biased low (about 6 % at n_eff 6, 15 % at n_eff 4;
#: docs/sensor_errors.md).
MIN_N_EFF = 10.0

#: Fewest samples over which :func:`settle_test` counts the correlation of the noise.
MIN_CORRELATED_SPAN = 16

#: Rounds of :func:`noise_of_mean`'s truncation and bias correction (they settle in 2 to 4).
MAX_ROUNDS = 20


class NoiseEstimateError(ValueError):
    """The samples cannot give an estimate; the message says why."""


@dataclasses.dataclass(frozen=True)
class NoiseOfMean:
    """Per channel (C,): ``sample_std`` (the std of one sample, the channel's unit),
    ``std_of_mean`` (of the mean of ``n_samples`` samples), ``n_eff`` (``(sample_std /
    std_of_mean)^2``), ``lags`` (autocovariance lags summed), and ``window_too_short`` (the
    autocorrelation was still positive at the largest usable lag (always so below 4 samples),
    or ``n_eff`` < :data:`MIN_N_EFF` and < n/2: the windows are not long against the
    correlation time, and ``std_of_mean`` is biased low, a lower bound)."""

    n_samples: int
    sample_std: np.ndarray
    std_of_mean: np.ndarray
    n_eff: np.ndarray
    lags: np.ndarray
    window_too_short: np.ndarray


def _check_windows(samples):
    samples = np.asarray(samples, dtype=float)
    if samples.ndim != 3:
        raise NoiseEstimateError(
            f'samples must be (postures, samples, channels), got shape {samples.shape}'
        )
    if samples.shape[0] < 1 or samples.shape[1] < 2:
        raise NoiseEstimateError(
            f'need at least 1 posture of at least 2 samples, got shape {samples.shape}'
        )
    if not np.all(np.isfinite(samples)):
        raise NoiseEstimateError('samples must be finite (drop non-finite readings first)')
    return samples


def _initial_positive_lags(autocovariance):
    """Per channel, the number of lags K to sum: Geyer's initial positive sequence. The pair sums
    ``g_{2m-1} + g_{2m}`` (m >= 1) are summed while they stay positive; returns K (C,) and whether
    the sequence was still positive at the last full pair (C,)."""
    max_lag = autocovariance.shape[0] - 1
    pairs = max_lag // 2
    if pairs == 0:
        return np.zeros(autocovariance.shape[1], dtype=int), np.ones(
            autocovariance.shape[1], dtype=bool
        )
    pair_sums = autocovariance[1 : 2 * pairs : 2] + autocovariance[2 : 2 * pairs + 1 : 2]
    positive = pair_sums > 0.0
    # Number of leading positive pairs per channel.
    leading = np.where(positive.all(axis=0), pairs, np.argmin(positive, axis=0))
    return 2 * leading, leading == pairs


def noise_of_mean(samples, max_lag=None, fitted=1):
    """Estimate, per channel, the std of one sample and of the mean of a posture's window.

    ``samples`` (P, n, C): P postures' windows of n consecutive samples (equally spaced in time)
    of C channels. ``max_lag``: the largest autocovariance lag considered (default ``n // 2``;
    beyond it too few pairs remain in each window). ``fitted``: terms fitted to each window
    before (1: its mean; 2: the caller removed a straight line, see :func:`settle_test`).

    The autocovariance ``c_k`` is pooled over postures, each window centred on its own mean and
    ``c_k`` averaged over its ``n - k`` pairs. Centring biases every ``c_k`` low by about
    ``var(mean)`` (the windows' own means scatter), which is corrected in closed form: with
    ``g_k = c_k + V`` in ``V = (1/n) [g0 + 2 sum_{k<=K} (1 - k/n) g_k]``,
    ``V = [c0 + 2 sum (1 - k/n) c_k] / (n - S)``, ``S = 1 + 2 sum_{k<=K} (1 - k/n)``. For white
    noise (K = 0) this is the usual ``s^2 / n`` with ddof 1 (ddof ``fitted`` in general: each
    fitted term absorbs about one ``V`` more). Returns :class:`NoiseOfMean`.
    """
    samples = _check_windows(samples)
    n_postures, n, n_channels = samples.shape
    max_lag = n // 2 if max_lag is None else int(max_lag)
    fitted = int(fitted)
    if not 1 <= fitted < n:
        raise NoiseEstimateError(f'fitted must be in [1, {n - 1}] for {n} samples, got {fitted}')
    if not 0 <= max_lag < n:
        raise NoiseEstimateError(f'max_lag must be in [0, {n - 1}] for {n} samples, got {max_lag}')
    centred = samples - samples.mean(axis=1, keepdims=True)
    # c_k (max_lag + 1, C): products of pairs k apart, averaged over pairs and postures.
    autocovariance = np.stack(
        [
            np.einsum('pic,pic->c', centred[:, : n - k], centred[:, k:]) / (n_postures * (n - k))
            for k in range(max_lag + 1)
        ]
    )
    weights = 1.0 - np.arange(max_lag + 1) / n  # (1 - k/n)
    doubled = np.where(np.arange(max_lag + 1) == 0, 1.0, 2.0)[:, None] * weights[:, None]
    # Truncate on the corrected autocovariance c_k + V: the centred c_k cross 0 early. V and
    # the truncation depend on each other; a few rounds settle them.
    variance_of_mean = np.zeros(n_channels)
    lags = None
    for _ in range(MAX_ROUNDS):
        previous = lags
        lags, window_too_short = _initial_positive_lags(autocovariance + variance_of_mean)
        included = np.arange(max_lag + 1)[:, None] <= lags[None, :]  # (max_lag + 1, C)
        weighted = np.sum(np.where(included, doubled * autocovariance, 0.0), axis=0)
        weight_sum = np.sum(np.where(included, doubled, 0.0), axis=0)
        variance_of_mean = np.clip(weighted / (n - weight_sum - (fitted - 1)), 0.0, None)
        if previous is not None and np.array_equal(lags, previous):
            break
    sample_variance = autocovariance[0] + variance_of_mean
    with np.errstate(divide='ignore', invalid='ignore'):
        n_eff = np.where(variance_of_mean > 0.0, sample_variance / variance_of_mean, float(n))
    return NoiseOfMean(
        n_samples=n,
        sample_std=np.sqrt(sample_variance),
        std_of_mean=np.sqrt(variance_of_mean),
        n_eff=n_eff,
        lags=lags,
        # White windows of few samples are not short: n_eff < MIN_N_EFF only counts when the
        # samples are correlated (n_eff well below n).
        window_too_short=window_too_short | ((n_eff < MIN_N_EFF) & (n_eff < 0.5 * n)),
    )


def trend_std_factor(n_samples):
    """Std of the least-squares trend (slope x window length) of ``n`` equally spaced white
    samples over the std of their mean: ``sqrt(12 (n - 1) / (n + 1))``."""
    n = int(n_samples)
    if n < 2:
        raise NoiseEstimateError(f'a trend needs at least 2 samples, got {n}')
    return math.sqrt(12.0 * (n - 1) / (n + 1))


def window_trend(window, times=None):
    """Per channel, the least-squares slope of ``window`` (n, C) against ``times`` (n,) s
    (default: 0..n-1) times the window's length (last - first time): the change the trend
    makes across the window, in the channel's unit (C,)."""
    window = np.asarray(window, dtype=float)
    if window.ndim != 2 or window.shape[0] < 2:
        raise NoiseEstimateError(f'window must be (samples >= 2, channels), got {window.shape}')
    times = np.arange(window.shape[0], dtype=float) if times is None else np.asarray(times, float)
    if times.shape != (window.shape[0],) or not np.all(np.diff(times) > 0):
        raise NoiseEstimateError('times must be (samples,) and strictly increasing')
    centred_t = times - times.mean()
    slope = centred_t @ (window - window.mean(axis=0)) / (centred_t @ centred_t)
    return slope * (times[-1] - times[0])


def settled(window, std_of_mean, times=None, sigmas=DEFAULT_SETTLE_SIGMAS):
    """Per channel (C,) bools: is the window's trend within ``sigmas`` stds of the trend a
    settled window's noise gives? Also returns the trend in those stds (C,).

    ``std_of_mean`` (C,): the std of the window's mean (from :func:`noise_of_mean`). The trend's
    std is ``std_of_mean`` x :func:`trend_std_factor` (exact for white noise; for correlated
    noise an approximation that scales with the same effective sample count). A channel whose
    ``std_of_mean`` is 0 is settled only when it does not move at all.
    """
    window = np.asarray(window, dtype=float)
    trend = window_trend(window, times)
    scale = np.asarray(std_of_mean, dtype=float) * trend_std_factor(window.shape[0])
    if scale.shape != trend.shape or np.any(~np.isfinite(scale) | (scale < 0)):
        raise NoiseEstimateError(
            f'std_of_mean must be {trend.shape[0]} finite values >= 0, got {scale.shape}'
        )
    with np.errstate(divide='ignore', invalid='ignore'):
        z = np.where(scale > 0, np.abs(trend) / np.where(scale > 0, scale, 1.0), np.inf)
    z = np.where((scale == 0) & (trend == 0), 0.0, z)
    return z <= sigmas, z


@dataclasses.dataclass(frozen=True)
class SettleTest:
    """Per channel (..., C): ``settled`` (bools), ``z`` (the trend in stds of a settled
    span's trend), ``threshold`` (the ``z`` a channel may reach: ``sigmas`` turned into the
    Student-t quantile of the same two-sided rate, ``n_eff - 2`` degrees of freedom),
    ``trend`` (the change across the span, the channel's unit) and ``std_of_mean``."""

    settled: np.ndarray
    z: np.ndarray
    threshold: np.ndarray
    trend: np.ndarray
    std_of_mean: np.ndarray


def settle_test(values, times=None, sigmas=DEFAULT_SETTLE_SIGMAS, noise_floor=None):
    """Is each channel of ``values`` (..., n, C) at rest over its span? Noise from the span.

    The least-squares trend of each channel (:func:`window_trend` against ``times`` (n,) s,
    default 0..n-1) is judged against the noise of the span itself: the residuals about the
    straight line and a parabola, through :func:`noise_of_mean` (``fitted=3``; correlation
    counted over lags up to n // 4 from :data:`MIN_CORRELATED_SPAN` samples on; each
    channel and leading index on its own). The trend's std is ``std_of_mean`` x
    :func:`trend_std_factor`; a channel is settled when ``|trend|`` is within ``threshold`` of
    those stds: for white noise ``z`` is then Student-t with ``n - 3`` degrees of freedom, so a
    settled channel is called moving at exactly :func:`false_unsettled_rate` (``sigmas``).
    ``noise_floor`` (C,): the least per-sample std believed (the channel's unit), so a
    quantised or noiseless channel whose samples barely differ is not called moving over a
    rounding error. Returns :class:`SettleTest`.
    """
    from scipy import stats

    values = np.asarray(values, dtype=float)
    if values.ndim < 2 or values.shape[-2] < 4:
        raise NoiseEstimateError(
            f'values must be (..., samples >= 4, channels), got shape {values.shape}'
        )
    n, n_channels = values.shape[-2:]
    times = np.arange(n, dtype=float) if times is None else np.asarray(times, dtype=float)
    if times.shape != (n,) or not np.all(np.diff(times) > 0):
        raise NoiseEstimateError('times must be (samples,) and strictly increasing')
    centred_t = times - times.mean()
    centred = values - values.mean(axis=-2, keepdims=True)
    slope = np.einsum('i,...ic->...c', centred_t, centred) / (centred_t @ centred_t)
    # The noise is the scatter about a parabola: an exponential approach bends, and its bend
    # would otherwise count as noise and hide the trend (orthogonal to the line's slope, so
    # for white noise the slope and this scatter are independent).
    bend = centred_t**2 - np.mean(centred_t**2)
    bend = bend - centred_t * (centred_t @ bend) / (centred_t @ centred_t)
    curvature = np.einsum('i,...ic->...c', bend, centred) / (bend @ bend)
    residuals = (
        centred - centred_t[:, None] * slope[..., None, :] - bend[:, None] * curvature[..., None, :]
    )
    lead = values.shape[:-2]
    # Every (leading index, channel) is a channel of its own for noise_of_mean.
    columns = np.moveaxis(residuals, -2, 0).reshape(1, n, -1)
    # Short spans cannot show their correlation (and its lags would eat the few degrees of
    # freedom left): white below MIN_CORRELATED_SPAN samples.
    max_lag = n // 4 if n >= MIN_CORRELATED_SPAN else 0
    noise = noise_of_mean(columns, max_lag=max_lag, fitted=3)
    std_of_mean = noise.std_of_mean.reshape(lead + (n_channels,))
    n_eff = noise.n_eff.reshape(lead + (n_channels,))
    if noise_floor is not None:
        floor = np.broadcast_to(np.asarray(noise_floor, dtype=float), (n_channels,))
        std_of_mean = np.maximum(std_of_mean, floor / np.sqrt(n_eff))
    trend = slope * (times[-1] - times[0])
    scale = std_of_mean * trend_std_factor(n)
    with np.errstate(divide='ignore', invalid='ignore'):
        z = np.where(scale > 0, np.abs(trend) / np.where(scale > 0, scale, 1.0), np.inf)
    z = np.where((scale == 0) & (trend == 0), 0.0, z)
    threshold = stats.t.isf(0.5 * false_unsettled_rate(sigmas), np.maximum(n_eff - 1.0, 1.0))
    return SettleTest(z <= threshold, z, threshold, trend, std_of_mean)


def false_unsettled_rate(sigmas=DEFAULT_SETTLE_SIGMAS):
    """Share of settled white-noise windows :func:`settled` calls moving, per channel."""
    return math.erfc(sigmas / math.sqrt(2.0))


__all__ = [
    'DEFAULT_SETTLE_SIGMAS',
    'NoiseEstimateError',
    'NoiseOfMean',
    'SettleTest',
    'false_unsettled_rate',
    'noise_of_mean',
    'settle_test',
    'settled',
    'trend_std_factor',
    'window_trend',
]
