"""A 95 % interval on a held-out accuracy: where the true accuracy over the workspace lies (pure)
(docs/verdict.md)."""

import math

import numpy as np

from ..prediction import pose_sensitivities
from .comparison import explained_excess

#: Coverage of the interval.
LEVEL = 0.95
#: Bootstrap resamples of the postures.
RESAMPLES = 4000
#: Draws of the truth's parameter error (:func:`truth_draw_ratios`).
TRUTH_DRAWS = 1000
#: The truth the interval holds: the mean error over this many random workspace postures, as
#: a validation measures it (the demo's and the benches' 50; over the whole workspace the
#: interval is slightly wider than needed).
VALIDATION_POSTURES = 50
#: Seed of the resamples and draws (a run's interval is repeatable).
SEED = 20261128


def posture_terms(errors, variances, unseen=None, leverage=None, held_out=None):
    """``(signal (K,), draws (K,))`` over the finite postures of held-out error magnitudes
    ``errors`` (M,) with their noise ``variances`` (M,), ``leverage``, ``held_out`` and ``unseen``
    as in :func:`.cross_validation.noise_removed`: the terms :func:`accuracy_statistic` sums."""
    errors = np.asarray(errors, dtype=float)
    variances = np.asarray(variances, dtype=float)
    count = errors.shape
    unseen = np.zeros(count) if unseen is None else np.asarray(unseen, dtype=float)
    leverage = np.ones(count) if leverage is None else np.asarray(leverage, dtype=float)
    finite = np.isfinite(errors) & np.isfinite(variances) & np.isfinite(unseen)
    errors, variances, unseen, leverage = (v[finite] for v in (errors, variances, unseen, leverage))
    held_out = None if held_out is None else np.asarray(held_out, dtype=float)[finite]
    explained, kept = explained_excess(errors, variances, held_out)
    signal = leverage * explained + kept + unseen
    draws = errors
    if held_out is not None:
        with np.errstate(divide='ignore', invalid='ignore'):
            shrink = (leverage * held_out + variances) / (held_out + variances)
        shrink = np.where(np.isfinite(shrink), np.clip(shrink, 0.0, 1.0), 1.0)
        draws = np.sqrt(np.maximum(shrink * (errors**2 - kept) + kept, 0.0))
    return signal, draws


def accuracy_statistic(signal, draws, transfer=1.0):
    """The noise-removed mean of :func:`posture_terms` (``signal``, ``draws``: (..., K), the
    last axis the postures): ``sqrt(transfer max(sum signal, 0) / sum draws^2) mean(draws)``
    (0 where the draws are all 0)."""
    total = transfer * np.maximum(np.sum(signal, axis=-1), 0.0)
    squared = np.sum(np.square(draws), axis=-1)
    with np.errstate(divide='ignore', invalid='ignore'):
        factor = np.where(squared > 0, np.sqrt(total / squared), 0.0)
    return factor * np.mean(draws, axis=-1)


def truth_draw_ratios(sensitivities, covariance, validation=VALIDATION_POSTURES, seed=SEED):
    """(:data:`TRUTH_DRAWS`,): the squared mean error magnitude ``|S delta|`` over postures
    (``sensitivities`` (M, 3, p) or (M, 1, p)) for ``delta`` drawn from ``covariance`` (p, p),
    over its expectation (``validation``: over that many random postures of the M; None: the M).
    None when the covariance is not finite or predicts nothing."""
    covariance = np.asarray(covariance, dtype=float)
    sensitivities = np.asarray(sensitivities, dtype=float)
    if not np.all(np.isfinite(covariance)) or not sensitivities.size:
        return None
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    root = vectors * np.sqrt(np.clip(values, 0.0, None))
    rng = np.random.default_rng(seed + 1)
    deltas = rng.standard_normal((TRUTH_DRAWS, root.shape[0])) @ root.T
    count, axes, size = sensitivities.shape
    moved = (sensitivities.reshape(count * axes, size) @ deltas.T).reshape(count, axes, -1)
    errors = np.linalg.norm(moved, axis=1).T  # (draws, M)
    expected = float(np.mean(errors))
    if not (expected > 0 and math.isfinite(expected)):
        return None
    if validation is not None:
        rows = rng.integers(0, errors.shape[1], (TRUTH_DRAWS, int(validation)))
        errors = np.take_along_axis(errors, rows, axis=1)
    return np.square(np.mean(errors, axis=1) / expected)


def workspace_truth_draws(result, poses):
    """``{position_truth_draws, phi_truth_draws}``: :func:`truth_draw_ratios` of ``result``'s
    covariance over the position and phi of the pose its controller reaches at ``poses`` (M, 6)."""
    geometry = result.geometry
    poses = np.asarray(poses, dtype=float)
    effect_free = getattr(result, 'effect_free', None)
    sensitivities = pose_sensitivities(geometry, poses, result.free, effect_free=effect_free)
    return {
        'position_truth_draws': truth_draw_ratios(sensitivities[:, :3], result.covariance),
        'phi_truth_draws': truth_draw_ratios(sensitivities[:, 5:], result.covariance),
    }


def figure_interval(errors, variances, scale, correction, truth_ratios):
    """``[low, high]`` (x ``scale``): :func:`held_out_interval` of the figure
    ``cross_validation.noise_removed(errors, variances, *correction)`` (``correction``:
    ``(unseen, leverage, held_out[, transfer])``), with the truth's draws ``truth_ratios``."""
    unseen, leverage, held_out, *transfer = correction
    signal, draws = posture_terms(errors, variances, unseen, leverage, held_out)
    low, high = held_out_interval(signal, draws, *(transfer or [1.0]), truth_ratios)
    return [scale * low, scale * high]


def reach_selected(headline, selected):
    """With workspace postures (the ``headline`` figures, ``{position_mm, phi_deg}``) their
    intervals reach up to the ``selected`` postures' (in place; docs/verdict.md)."""
    for key in ('position_mm', 'phi_deg'):
        interval, bound = headline[key]['mean_interval_95'], selected[key]['mean_interval_95']
        if all(math.isfinite(v) for v in interval + bound):
            interval[1] = max(interval[1], bound[1])


def held_out_interval(
    signal, draws, transfer=1.0, truth_ratios=None, level=LEVEL, resamples=RESAMPLES, seed=SEED
):
    """``(low, high)``: the ``level`` interval of the true mean error of which
    :func:`accuracy_statistic` of ``signal``, ``draws`` (K,) is the estimate: ``resamples``
    bootstrap resamples of the postures, each figure scaled by the square root of a draw of
    ``truth_ratios`` (None: the expectation; docs/verdict.md). NaN without a posture."""
    signal, draws = np.asarray(signal, dtype=float), np.asarray(draws, dtype=float)
    if not signal.size:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    rows = rng.integers(0, signal.size, (int(resamples), signal.size))
    figures = accuracy_statistic(signal[rows], draws[rows], transfer)
    if truth_ratios is not None:
        ratios = rng.choice(np.asarray(truth_ratios, dtype=float), figures.size)
        figures = figures * np.sqrt(ratios)
    tail = 50.0 * (1.0 - level)
    low, high = np.percentile(figures, [tail, 100.0 - tail])
    return float(low), float(high)
