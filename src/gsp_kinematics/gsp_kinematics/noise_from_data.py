"""The noise of the averaged posture rows, estimated from the run itself (docs/sensor_errors.md).

Two independent estimates of each channel's row noise (legs, inclinometer, encoder, LVDT):

* **within** a posture: the pooled per-sample scatter over the window
  (:func:`gsp_kinematics.goodness.within_posture_noise`) divided by ``sqrt(n)``; many degrees of
  freedom, but blind to noise correlated over longer than the window (``n_eff`` < ``n``);
* **between** postures: the fit's residuals, ``sigma_g^2 = sigma_used^2 q_g / r_g`` with ``q_g``
  the channel's sum of squared normalised residuals and ``r_g`` the sum of its redundancy numbers
  (Förstner's variance-component estimate, iterated with the weights it gives). It measures the
  noise of the averaged row itself, correlated or not, but has only the fit's redundancy.

Where both exist and agree (the between/within F test of the channel accepts at 1 %, Bonferroni
over the channels), the pooled variance ``(r_g v_between + d_g v_within) / (r_g + d_g)`` is used;
where the between-posture residuals are significantly larger, the between estimate (the within
scatter misses part of the noise); where only one exists, that one. The goodness of fit is then
the lack-of-fit F test (:func:`fit_test`).
"""

import dataclasses
import math

import numpy as np
from scipy import special

from . import goodness
from .identification import identify
from .sensors.noise import NOISE_FIELDS, SensorNoise

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


def check_noise_source(source):
    if source not in NOISE_SOURCES:
        raise NoiseSourceError(f'noise_source must be one of {NOISE_SOURCES}, got {source!r}')
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
    p_value: float  #: F test of between against within (NaN unless both exist)


def within_row_noise(sample_std, n_samples):
    """``{channel: (row std, dof)}``: the within-posture per-sample noise over ``sqrt(n)``, with
    ``n`` the median samples a row (the convention of ``SensorNoise.averaged``). A channel that
    does not scatter within a posture (noise-free data, a quantised encoder at rest) has no
    within-posture estimate: it is left out."""
    n_samples = np.asarray(n_samples, dtype=float).reshape(-1)
    if n_samples.size == 0:
        return {}
    root = math.sqrt(float(np.median(n_samples)))
    return {
        channel: (sigma / root, dof)
        for channel, (sigma, dof) in goodness.within_posture_noise(sample_std, n_samples).items()
        if sigma > 0.0
    }


def _combine(between, redundancy, within, significance):
    """A :class:`ChannelNoise` from a between-posture row std (or None) and ``within`` (row std,
    dof) or None."""
    if within is None:
        return ChannelNoise(between, 'between', None, 0.0, between, redundancy, math.nan)
    within_row, dof = within
    if between is None:
        return ChannelNoise(within_row, 'within', within_row, dof, None, redundancy, math.nan)
    p_value = float(special.fdtrc(redundancy, dof, (between / within_row) ** 2))
    if p_value < significance:
        return ChannelNoise(between, 'between', within_row, dof, between, redundancy, p_value)
    pooled = (redundancy * between**2 + dof * within_row**2) / (redundancy + dof)
    return ChannelNoise(math.sqrt(pooled), 'pooled', within_row, dof, between, redundancy, p_value)


def estimate_row_noise(result, row_sigmas, within):
    """``{channel: ChannelNoise}`` of a fit ``result`` made with ``row_sigmas`` (SensorNoise of the
    rows) and the within-posture ``{channel: (row std, dof)}``; channels with neither left out."""
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
    """The goodness of fit of a fit whose weights were estimated: the lack-of-fit F test of the
    between-posture residuals, in within-posture noise units, against the within-posture
    (pure error) variance; ``none`` when no channel has a within-posture estimate.

    The pure-error degrees of freedom of several channels are combined by Satterthwaite's
    ``(sum r_g)^2 / sum (r_g^2 / d_g)``."""
    excluded = result.goodness_of_fit.excluded_postures if result.goodness_of_fit else ()
    between = redundancy = spread = 0.0
    total_q = total_r = 0.0
    for channel, (q, r) in result.variance_components().items():
        total_q, total_r = total_q + q, total_r + r
        if channel not in within or r <= 0:
            continue
        within_row, dof = within[channel]
        between += q * (getattr(row_sigmas, channel) / within_row) ** 2
        redundancy += r
        spread += r**2 / dof
    if redundancy <= 0:
        return goodness.GoodnessOfFit(total_q, total_r, math.nan, excluded, 'none')
    return goodness.lack_of_fit(between, redundancy, redundancy**2 / spread, excluded)


def identify_with_estimated_noise(nominal, leg_lengths, readings, start, within, **options):
    """Identify with the row noise estimated from the run: ``(result, {channel: ChannelNoise},
    SensorNoise of the rows used)``.

    ``start``: the row sigmas to begin with (the configured ones, averaged); a channel with a
    within-posture estimate starts from it. Each round fits, estimates (:func:`estimate_row_noise`)
    and refits with the estimate, until no row sigma changes by more than :data:`TOLERANCE`
    (at most :data:`MAX_ROUNDS` fits). ``options`` go to :func:`identify`. The result's goodness
    of fit is :func:`fit_test`.
    """
    sigmas = SensorNoise.from_channels(
        {channel: row for channel, (row, _) in within.items()}, default=start
    )
    estimates = {}
    for _ in range(MAX_ROUNDS):
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


def identify_with_noise(source, nominal, leg_lengths, readings, row_sigmas, within, **options):
    """``(result, {channel: ChannelNoise}, SensorNoise of the rows used)`` with the weights of
    ``source``: ``estimated`` (:func:`identify_with_estimated_noise` from ``row_sigmas``) or
    ``configured`` (``row_sigmas``; the estimate is made from the fit and only reported)."""
    check_noise_source(source)
    if source == 'estimated':
        return identify_with_estimated_noise(
            nominal, leg_lengths, readings, row_sigmas, within, **options
        )
    result = identify(nominal, leg_lengths, readings, row_sigmas, **options)
    estimates = estimate_row_noise(result, row_sigmas, within) if result.converged else {}
    return result, estimates, row_sigmas


def noise_record(estimates, configured, n_samples):
    """``{channel: {...}}`` for result.json: per-sample equivalents (SI: the row std times
    ``sqrt(n)``, comparable with the configured ``sigma_<field>``) of the estimate, its
    within-posture and between-posture parts, the row std, the source, the redundancy and the
    within-posture degrees of freedom, the F test's p-value, and the ratio to the configured
    sigma with its warning (beyond 2x either way)."""
    n_samples = np.asarray(n_samples, dtype=float).reshape(-1)
    root = math.sqrt(float(np.median(n_samples))) if n_samples.size else 1.0
    record = {}
    for channel, entry in estimates.items():
        sigma = float(getattr(configured, channel))
        estimated = entry.row * root
        ratio, warning = goodness.noise_warning(estimated, sigma)
        record[channel] = {
            'configured': sigma,
            'estimated': estimated,
            'within_posture': None if entry.within is None else entry.within * root,
            'between_postures': None if entry.between is None else entry.between * root,
            'row_std': entry.row,
            'source': entry.source,
            'redundancy': entry.redundancy,
            'within_dof': entry.within_dof,
            'consistency_p_value': entry.p_value,
            'ratio': ratio,
            'warning': warning,
        }
    return record
