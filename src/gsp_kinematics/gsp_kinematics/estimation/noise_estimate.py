"""Noise of an averaged row from correlated samples, and a rest test for a window (pure numpy)
(docs/sensor_errors.md)."""

import dataclasses
import math

import numpy as np
from scipy import special

#: Default of :func:`rest_test`: a channel is still moving when its trend exceeds this many
#: standard deviations of the trend of a settled window.
DEFAULT_REST_SIGMAS = 3.0


#: Below this effective sample count a window is too short against the correlation time: the
#: estimate of the std of the mean is then biased low (docs/sensor_errors.md).
MIN_N_EFF = 10.0

#: Fewest samples over which :func:`rest_test` counts the correlation of the noise.
MIN_CORRELATED_SPAN = 16

#: Rounds of :func:`noise_of_mean`'s truncation and bias correction (they settle in 2 to 4).
MAX_ROUNDS = 20


class NoiseEstimateError(ValueError):
    """The samples cannot give an estimate; the message says why."""


@dataclasses.dataclass(frozen=True)
class NoiseOfMean:
    """Per channel (C,): ``sample_std`` (one sample, the channel's unit), ``std_of_mean`` (of
    the mean of ``n_samples``), ``n_eff`` (``(sample_std / std_of_mean)^2``), ``lags`` (summed),
    and ``window_too_short`` (``std_of_mean`` only a lower bound; docs/sensor_errors.md)."""

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
        channels = autocovariance.shape[1]
        return np.zeros(channels, dtype=int), np.ones(channels, dtype=bool)
    pair_sums = autocovariance[1 : 2 * pairs : 2] + autocovariance[2 : 2 * pairs + 1 : 2]
    positive = pair_sums > 0.0
    # Number of leading positive pairs per channel.
    leading = np.where(positive.all(axis=0), pairs, np.argmin(positive, axis=0))
    return 2 * leading, leading == pairs


def window_lag_sums(samples, max_lag=None):
    """Per window of ``samples`` (P, n, C) centred on its mean, ``sum_i x_i x_(i+k)`` for
    k = 0..``max_lag`` (default ``n // 2``): (P, max_lag + 1, C), the channel's unit squared."""
    samples = _check_windows(samples)
    n = samples.shape[1]
    max_lag = n // 2 if max_lag is None else int(max_lag)
    if not 0 <= max_lag < n:
        raise NoiseEstimateError(f'max_lag must be in [0, {n - 1}] for {n} samples, got {max_lag}')
    centred = samples - samples.mean(axis=1, keepdims=True)
    return np.stack(
        [np.einsum('pic,pic->pc', centred[:, : n - k], centred[:, k:]) for k in range(max_lag + 1)],
        axis=1,
    )


def noise_of_mean(samples, max_lag=None, white_level=None, fitted=1):
    """Per channel, the std of one sample and of the mean of a posture's window.

    ``samples`` (P, n, C): P windows of n equally spaced samples of C channels. ``max_lag``:
    default ``n // 2``. ``white_level``, ``fitted``: see :func:`noise_of_mean_from_sums`."""
    samples = _check_windows(samples)
    sums = window_lag_sums(samples, max_lag).sum(axis=0)
    return noise_of_mean_from_sums(sums, samples.shape[1], samples.shape[0], white_level, fitted)


def white_statistic(autocovariance, n, windows):
    """Per channel (C,): the pooled lag-1 autocorrelation of ``windows`` centred windows of
    ``n`` samples (``autocovariance`` (>= 2, C)), centring-corrected, in units of its standard
    error for white samples: about N(0, 1) for white samples."""
    with np.errstate(divide='ignore', invalid='ignore'):
        rho = np.where(autocovariance[0] > 0, autocovariance[1] / autocovariance[0], 0.0)
    return (rho + 1.0 / (n - 1)) * math.sqrt(windows * (n - 1))


def noise_of_mean_from_sums(sums, n, windows, white_level=None, fitted=1):
    """:class:`NoiseOfMean` from the pooled :func:`window_lag_sums` ``sums`` (K + 1, C) of ``windows``
    windows of ``n`` samples each, the centring bias corrected in closed form
    (docs/sensor_errors.md). ``fitted``: terms fitted to each window before (1: its mean; 3: a
    line and a parabola). ``white_level``: None, or the one-sided significance of a whiteness test
    (:func:`white_statistic`) under which a channel is taken as white (K = 0)."""
    sums = np.asarray(sums, dtype=float)
    if sums.ndim != 2 or sums.shape[0] < 1:
        raise NoiseEstimateError(f'sums must be (lags, channels), got shape {sums.shape}')
    n, windows, fitted = int(n), int(windows), int(fitted)
    max_lag = sums.shape[0] - 1
    if not 1 <= fitted < n:
        raise NoiseEstimateError(f'fitted must be in [1, {n - 1}] for {n} samples, got {fitted}')
    if n < 2 or windows < 1 or max_lag >= n:
        raise NoiseEstimateError(
            f'need windows >= 1 of n >= 2 samples and fewer than n lags, got {windows} windows '
            f'of {n} samples and {max_lag + 1} lags'
        )
    if not np.all(np.isfinite(sums)):
        raise NoiseEstimateError('lag sums must be finite')
    n_channels = sums.shape[1]
    # c_k (max_lag + 1, C): products of pairs k apart, averaged over pairs and windows.
    autocovariance = sums / (windows * (n - np.arange(max_lag + 1)))[:, None]
    weights = 1.0 - np.arange(max_lag + 1) / n  # (1 - k/n)
    doubled = np.where(np.arange(max_lag + 1) == 0, 1.0, 2.0)[:, None] * weights[:, None]
    white = np.zeros(n_channels, dtype=bool)
    if white_level is not None and max_lag >= 1:
        white = white_statistic(autocovariance, n, windows) < special.ndtri(1.0 - white_level)
    # Truncate on the corrected autocovariance c_k + V: the centred c_k cross 0 early. V and
    # the truncation depend on each other; a few rounds settle them.
    variance_of_mean = np.zeros(n_channels)
    lags = None
    for _ in range(MAX_ROUNDS):
        previous = lags
        lags, window_too_short = _initial_positive_lags(autocovariance + variance_of_mean)
        lags, window_too_short = np.where(white, 0, lags), window_too_short & ~white
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


def ar1_std_of_mean(sigma, rho, n_samples):
    """Std of the mean of ``n`` consecutive samples of a stationary AR(1) noise of std ``sigma``
    and lag-1 correlation ``rho`` (``exp(-dt / correlation time)``, see
    :mod:`gsp_kinematics.model.sensor_dynamics`): ``(sigma / n) sqrt(sum_ij rho^|i - j|)``."""
    n = int(n_samples)
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    return float(sigma) * math.sqrt(float(np.sum(float(rho) ** lags))) / n


def trend_std_factor(n_samples):
    """Std of the least-squares trend (slope x window length) of ``n`` equally spaced white
    samples over the std of their mean: ``sqrt(12 (n - 1) / (n + 1))``."""
    n = int(n_samples)
    if n < 2:
        raise NoiseEstimateError(f'a trend needs at least 2 samples, got {n}')
    return math.sqrt(12.0 * (n - 1) / (n + 1))


@dataclasses.dataclass(frozen=True)
class SettleTest:
    """Per channel (..., C): ``settled`` (bools), ``z`` (the trend in stds of a settled span's
    trend), ``threshold`` (the Student-t quantile ``z`` may reach), ``trend`` (across the span,
    the channel's unit) and ``std_of_mean``."""

    settled: np.ndarray
    z: np.ndarray
    threshold: np.ndarray
    trend: np.ndarray
    std_of_mean: np.ndarray


def rest_test(values, times=None, sigmas=DEFAULT_REST_SIGMAS, noise_floor=None):
    """Is each channel of ``values`` (..., n, C) at rest over its span? Noise from the span.

    The least-squares trend (slope times span against ``times`` (n,) s, default 0..n-1) is
    judged against the noise of the residuals about a parabola (:func:`noise_of_mean`,
    ``fitted=3``), ``threshold`` stds of the trend (docs/sensor_errors.md). ``noise_floor`` (C,):
    the least per-sample std believed (the channel's unit). Returns :class:`SettleTest`."""
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


def scatter_test(values, noise_std, sigmas=DEFAULT_REST_SIGMAS):
    """Does each channel of ``values`` (..., n, C) scatter about its mean no more than its
    at-rest noise allows? ``(ratio, threshold)`` (..., C) and (): the span's sample std over the
    noise (``noise_std`` (C,), or the rms successive difference over sqrt 2 if larger), and the
    chi-square ratio white noise exceeds at :func:`false_unsettled_rate` (``sigmas``)."""
    from scipy import stats

    values = np.asarray(values, dtype=float)
    if values.ndim < 2 or values.shape[-2] < 2:
        raise NoiseEstimateError(
            f'values must be (..., samples >= 2, channels), got shape {values.shape}'
        )
    n = values.shape[-2]
    noise_std = np.asarray(noise_std, dtype=float)
    if noise_std.shape != values.shape[-1:] or not np.all(noise_std > 0):
        raise NoiseEstimateError(f'noise_std must be {values.shape[-1]} values > 0')
    successive = np.sqrt(0.5 * np.mean(np.diff(values, axis=-2) ** 2, axis=-2))
    ratio = values.std(axis=-2, ddof=1) / np.maximum(noise_std, successive)
    threshold = math.sqrt(stats.chi2.isf(false_unsettled_rate(sigmas), n - 1) / (n - 1))
    return ratio, threshold


def false_unsettled_rate(sigmas=DEFAULT_REST_SIGMAS):
    """Share of settled white-noise windows :func:`rest_test` calls moving, per channel."""
    return math.erfc(sigmas / math.sqrt(2.0))
