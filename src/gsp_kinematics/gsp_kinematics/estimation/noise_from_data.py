"""The noise of the averaged posture rows, estimated from the run itself (docs/sensor_errors.md)."""

import dataclasses
import math

import numpy as np
from scipy import special

from ..model.sensor_noise import NOISE_FIELDS, SensorNoise
from . import goodness, noise_estimate
from .identification import identify

#: Where the weights come from: the run's data, or the configured sigmas.
NOISE_SOURCES = ('estimated', 'configured')
DEFAULT_NOISE_SOURCE = 'estimated'
#: Most fits of the variance-component iteration, and the relative change of every row sigma
#: below which it stops (the factors settle in 2-3 fits).
MAX_ROUNDS = 5
TOLERANCE = 1e-3
#: A channel whose residuals hold less redundancy than this gives no between-posture estimate.
MIN_CHANNEL_REDUNDANCY = 2.0


class NoiseSourceError(ValueError):
    """An unknown noise source; the message names the choices."""


def noise_source_error(source):
    """Reason ('' if none) why ``source`` is not a noise source: the one check of
    the noise source, for the calibrator, the identification and every command line."""
    return (
        '' if source in NOISE_SOURCES else f'must be one of {list(NOISE_SOURCES)}, got {source!r}'
    )


def validate_noise_source(source):
    """``source``, or NoiseSourceError (:func:`noise_source_error`)."""
    reason = noise_source_error(source)
    if reason:
        raise NoiseSourceError(f'noise_source {reason}')
    return source


@dataclasses.dataclass(frozen=True)
class ChannelNoise:
    """One channel's row noise (std of an averaged row, m or rad) and where it came from."""

    row: float  #: the estimate (what the weights use in 'estimated' mode)
    source: str  #: 'pooled', 'between' or 'within'
    within: float | None  #: from the within-posture scatter (None: not recorded)
    within_dof: float
    between: float | None  #: from the between-posture residuals (None: too little redundancy)
    redundancy: float  #: the sum of the channel's redundancy numbers
    p_value: float  #: F test of between against within (NaN unless both exist and it is used)
    #: the within estimate is only a lower bound (windows too short against the correlation)
    within_lower_bound: bool = False
    within_n_eff: float = math.nan  #: effective sample count of a row (within-posture)
    #: the measurement noise of a row: the within estimate where it is usable, else ``row``
    noise: float | None = None
    #: the excess of the between-posture residuals over the noise (a row std; 0: none shown)
    unmodelled: float = 0.0

    def __post_init__(self):
        if self.noise is None:
            object.__setattr__(self, 'noise', self.row)


#: The channels of :func:`posture_lag_sums`, in order.
LAG_SUMS_CHANNELS = tuple(goodness.NOISE_CHANNELS)


@dataclasses.dataclass(frozen=True)
class WithinNoise:
    """One channel's within-posture estimate of its row noise: ``row`` (std of the averaged row,
    m or rad), ``dof``, ``n_eff`` (per row) and ``lower_bound`` (``row`` biased low)."""

    row: float
    dof: float
    n_eff: float = math.nan
    lower_bound: bool = False


def posture_lag_sums(values):
    """A posture's window's lag sums (lags 0..n // 2) per channel of :data:`LAG_SUMS_CHANNELS`,
    summed over the channel's columns (m^2, rad^2): ``values`` (n, 10) or (P, n, 10) of ``[q_1..q_6,
    alpha, beta, phi, d_m]`` (``phi`` unwrapped) give (4, n // 2 + 1) or (P, 4, n // 2 + 1)."""
    values = np.asarray(values, dtype=float)
    if values.ndim not in (2, 3) or values.shape[-1] != 10:
        raise ValueError(f'windows must be (samples, 10) or (P, samples, 10), got {values.shape}')
    sums = noise_estimate.window_lag_sums(values.reshape((-1,) + values.shape[-2:]))
    grouped = np.stack(
        [sums[:, :, columns].sum(axis=2) for columns in goodness.NOISE_CHANNELS.values()], axis=1
    )
    return grouped[0] if values.ndim == 2 else grouped


def within_row_noise(lag_sums, n_samples):
    """``{channel: WithinNoise}`` from the rows' :func:`posture_lag_sums` ``lag_sums``
    (M, 4, L; NaN where a row has none) and their ``n_samples`` (M,): the rows of the most common
    sample count pooled per channel through
    :func:`~gsp_kinematics.estimation.noise_estimate.noise_of_mean_from_sums`
    (docs/sensor_errors.md). A channel that does not scatter within a posture is left out."""
    n_samples = np.asarray(n_samples, dtype=int).reshape(-1)
    if n_samples.size == 0 or lag_sums is None:
        return {}
    lag_sums = np.asarray(lag_sums, dtype=float).reshape(n_samples.size, 4, -1)
    counts = np.bincount(n_samples[n_samples >= 2]) if np.any(n_samples >= 2) else []
    if not len(counts):
        return {}
    n = int(np.argmax(counts))
    lags = min(n // 2 + 1, lag_sums.shape[2])
    if lags < 1:
        return {}
    estimates = {}
    for index, (channel, columns) in enumerate(goodness.NOISE_CHANNELS.items()):
        sums = lag_sums[n_samples == n, index, :lags]
        sums = sums[np.all(np.isfinite(sums), axis=1)]
        if not len(sums) or np.sum(sums[:, 0]) <= 0.0:
            continue
        windows = len(sums) * len(range(10)[columns])
        noise = noise_estimate.noise_of_mean_from_sums(
            sums.sum(axis=0)[:, None], n, windows, goodness.DEFAULT_SIGNIFICANCE
        )
        n_eff = float(noise.n_eff[0])
        estimates[channel] = WithinNoise(
            float(noise.std_of_mean[0]),
            windows * max(n_eff - 1.0, 0.0),
            n_eff,
            bool(noise.window_too_short[0]),
        )
    return estimates


def _combine(between, redundancy, within, significance):
    """A :class:`ChannelNoise` from a between-posture row std (or None) and a
    :class:`WithinNoise` (or None). A within estimate that is only a lower bound is reported
    but not used where the between estimate exists (nor tested against it)."""
    if within is None:
        return ChannelNoise(between, 'between', None, 0.0, between, redundancy, math.nan)
    parts = (within.row, within.dof, between, redundancy)
    flags = (within.lower_bound, within.n_eff)
    if between is None:
        return ChannelNoise(within.row, 'within', *parts, math.nan, *flags)
    if within.lower_bound:
        return ChannelNoise(between, 'between', *parts, math.nan, *flags)
    p_value = float(special.fdtrc(redundancy, within.dof, (between / within.row) ** 2))
    if p_value < significance:
        excess = math.sqrt(max(between**2 - within.row**2, 0.0))
        return ChannelNoise(between, 'between', *parts, p_value, *flags, within.row, excess)
    pooled = (redundancy * between**2 + within.dof * within.row**2) / (redundancy + within.dof)
    return ChannelNoise(math.sqrt(pooled), 'pooled', *parts, p_value, *flags)


def estimate_row_noise(result, row_sigmas, within):
    """``{channel: ChannelNoise}`` of a fit ``result`` made with ``row_sigmas`` (SensorNoise of the
    rows) and the within-posture ``{channel: WithinNoise}``; channels with neither left out."""
    components = result.variance_components()
    channels = [name for name in NOISE_FIELDS if name in components or name in within]
    significance = goodness.DEFAULT_SIGNIFICANCE / max(len(channels), 1)
    estimates = {}
    for channel in channels:
        q, r = components.get(channel, (0.0, 0.0))
        used = getattr(row_sigmas, channel)
        between = used * math.sqrt(q / r) if r >= MIN_CHANNEL_REDUNDANCY and q > 0 else None
        if between is None and channel not in within:
            continue
        estimates[channel] = _combine(between, r, within.get(channel), significance)
    return estimates


def fit_test(result, row_sigmas, within):
    """The goodness of fit of a fit whose weights were estimated: the lack-of-fit F test against
    the within-posture variance (channels whose estimate is a lower bound left out; degrees of
    freedom combined by Satterthwaite), or ``none`` without a within-posture estimate."""
    excluded = result.goodness_of_fit.excluded_postures if result.goodness_of_fit else ()
    between = redundancy = spread = 0.0
    total_q = total_r = 0.0
    for channel, (q, r) in result.variance_components().items():
        total_q, total_r = total_q + q, total_r + r
        pure = within.get(channel)
        if pure is None or pure.lower_bound or r <= 0:
            continue
        between += q * (getattr(row_sigmas, channel) / pure.row) ** 2
        redundancy += r
        spread += r**2 / pure.dof
    if redundancy <= 0:
        return goodness.GoodnessOfFit(total_q, total_r, math.nan, excluded, 'none')
    return goodness.lack_of_fit(between, redundancy, redundancy**2 / spread, excluded)


def within_sigmas(within, default):
    """The row sigmas (``SensorNoise``) of the within-posture estimates ``within`` that are not
    only a lower bound; ``default``'s for the other channels."""
    return SensorNoise.from_channels(
        {channel: entry.row for channel, entry in within.items() if not entry.lower_bound},
        default=default,
    )


def identify_with_estimated_noise(
    nominal, leg_lengths, readings, start, within, first=None, **options
):
    """Identify with the row noise estimated from the run: ``(result, {channel: ChannelNoise},
    SensorNoise of the rows used)``, refitting until no row sigma changes by more than
    :data:`TOLERANCE` (at most :data:`MAX_ROUNDS` fits). ``start``: the row sigmas to begin with;
    ``options`` go to :func:`identify`; ``first``: the first round's fit when made already. The
    result's goodness of fit is :func:`fit_test`."""
    sigmas = within_sigmas(within, start)
    estimates = {}
    for round_ in range(MAX_ROUNDS):
        if round_ == 0 and first is not None:
            result = dataclasses.replace(first)  # a copy: its goodness of fit is replaced
        else:
            result = identify(nominal, leg_lengths, readings, sigmas, **options)
        if not result.converged:
            return result, {}, sigmas
        estimates = estimate_row_noise(result, sigmas, within)
        updated = SensorNoise.from_channels(
            {channel: entry.row for channel, entry in estimates.items()}, default=sigmas
        )
        change = max(
            abs(getattr(updated, name) / getattr(sigmas, name) - 1.0) for name in NOISE_FIELDS
        )
        if change < TOLERANCE:
            break
        sigmas = updated
        options['pose_guesses'] = result.poses  # the next fit starts where this one ended
    result.goodness_of_fit = fit_test(result, sigmas, within)
    return result, estimates, sigmas


def identify_with_noise(
    source, nominal, leg_lengths, readings, row_sigmas, within, first=None, **options
):
    """``(result, {channel: ChannelNoise}, SensorNoise of the rows used)`` with the weights of
    ``source``: ``estimated`` (:func:`identify_with_estimated_noise` from ``row_sigmas``, its
    ``first`` fit when given) or ``configured`` (``row_sigmas``; the estimate only reported).
    A rejected model keeps only :func:`goodness.outliers_beside_model_error`."""
    validate_noise_source(source)
    if source == 'estimated':
        result, estimates, used = identify_with_estimated_noise(
            nominal, leg_lengths, readings, row_sigmas, within, first, **options
        )
    else:
        result = identify(nominal, leg_lengths, readings, row_sigmas, **options)
        estimates = estimate_row_noise(result, row_sigmas, within) if result.converged else {}
        used = row_sigmas
    fit = result.goodness_of_fit
    if fit is not None and fit.test != 'none' and not fit.accepted and result.outliers:
        threshold = options.get('options')
        threshold = None if threshold is None else threshold.outlier_threshold
        count = int(np.count_nonzero(np.isfinite(result.residuals)))
        result.outliers = goodness.outliers_beside_model_error(result.outliers, count, threshold)
    return result, estimates, used


def unmodelled_error(estimates):
    """What the model leaves unexplained, per row (a ``SensorNoise`` of standard deviations, m
    and rad: legs, inclinations, phi, d_m; 0 where a channel shows none) from
    ``{channel: ChannelNoise}``; None when no channel shows any (the model explains the data)."""
    excess = {channel: entry.unmodelled for channel, entry in estimates.items()}
    if not any(value > 0.0 for value in excess.values()):
        return None
    return SensorNoise.from_channels(excess, default=SensorNoise(0.0, 0.0, 0.0, 0.0))


def noise_record(estimates, configured, n_samples):
    """``{channel: {...}}`` for result.json: the noise estimate as per-sample equivalents (SI)
    with its within- and between-posture parts, the row std used, the ``unmodelled`` part, the
    source, redundancy, degrees of freedom, the F test's p-value and the ratio to the configured
    sigma with its warning (fields: docs/data.md)."""
    n_samples = np.asarray(n_samples, dtype=float).reshape(-1)
    root = math.sqrt(float(np.median(n_samples))) if n_samples.size else 1.0
    record = {}
    for channel, entry in estimates.items():
        sigma = float(getattr(configured, channel))
        estimated = entry.noise * root
        ratio, warning = goodness.noise_warning(estimated, sigma)
        record[channel] = {
            'configured': sigma,
            'estimated': estimated,
            'within_posture': None if entry.within is None else entry.within * root,
            'between_postures': None if entry.between is None else entry.between * root,
            'row_std': entry.row,
            'unmodelled': entry.unmodelled,
            'source': entry.source,
            'redundancy': entry.redundancy,
            'within_dof': entry.within_dof,
            'within_n_eff': entry.within_n_eff,
            'within_lower_bound': entry.within_lower_bound,
            'consistency_p_value': entry.p_value,
            'ratio': ratio,
            'warning': warning,
        }
    return record
