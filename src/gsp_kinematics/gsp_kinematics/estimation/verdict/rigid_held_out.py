"""The held-out accuracy of the rigid geometry a controller without ``geometry.effects.*`` runs
(:mod:`gsp_kinematics.estimation.rigid_fold`), from the compensating geometry's, without a refit or
a fold (docs/verdict.md)."""

import math

import numpy as np


def mean_sum_length(fixed, random):
    """(K,) the mean length of a vector of length ``fixed`` (K,) plus one of length ``random``
    in a uniformly random direction (3-D): the larger plus the smaller squared over three
    times the larger (the mean distance from a point to a sphere's surface)."""
    fixed = np.asarray(fixed, dtype=float)
    larger, smaller = np.maximum(fixed, random), np.minimum(fixed, random)
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.where(larger > 0, larger + smaller**2 / (3.0 * larger), 0.0)


#: Standard errors of a mean over the workspace postures each end of the interval is widened by.
INTERVAL_STANDARD_ERRORS = 1.96


def _lengths(systematic, value, axes):
    """(K,) the error at each workspace posture of ``systematic`` (K,) and a random one of size
    ``value`` (``axes`` 3: :func:`mean_sum_length`; 1: the larger); None without a value."""
    if value is None or not math.isfinite(value):
        return None
    if axes == 1:
        return np.maximum(systematic, value)
    return mean_sum_length(systematic, value)


def _combined(systematic, value, axes, spread=0.0):
    """Mean over the workspace postures of :func:`_lengths`, plus ``spread`` standard errors
    of that mean (the errors at both approach directions of a posture counted as one); NaN
    without a value."""
    lengths = _lengths(systematic, value, axes)
    if lengths is None:
        return math.nan
    error = float(np.std(lengths)) / math.sqrt(max(lengths.size / 2.0, 1.0))
    return max(float(np.mean(lengths)) + spread * error, 0.0)


def _rigid_figure(figure, systematic, axes):
    """A held-out figure (``{mean, p95, rms, mean_interval_95, ...}``) of the compensating
    geometry as the rigid geometry's, with its ``systematic`` errors (K,) over the workspace
    (``axes``: 3 for the position, 1 for phi). The p95 and rms combine in quadrature."""
    interval = figure.get('mean_interval_95') or [math.nan, math.nan]
    mean = figure['mean']
    return {
        'mean': _combined(systematic, mean, axes),
        'p95': float(np.percentile(np.hypot(systematic, figure['p95']), 95))
        if math.isfinite(figure['p95'])
        else math.nan,
        'rms': math.sqrt(float(np.mean(systematic**2)) + figure.get('rms', math.nan) ** 2),
        'mean_interval_95': [
            _combined(systematic, value, axes, spread)
            for value, spread in zip(
                interval, (-INTERVAL_STANDARD_ERRORS, INTERVAL_STANDARD_ERRORS), strict=True
            )
        ],
        'measured_mean': _combined(systematic, figure.get('measured_mean'), axes),
        'compensating_mean': mean,
        'systematic_mean': float(np.mean(systematic)),
    }


def _calibrated(calibrated, position, phi):
    return {
        'position_mm': _rigid_figure(calibrated['position_mm'], position, 3),
        'phi_deg': _rigid_figure(calibrated['phi_deg'], phi, 1),
    }


def rigid_held_out(accuracy, systematic_position_mm, systematic_phi_deg):
    """The rigid geometry's held-out accuracy, shaped as ``accuracy`` (the compensating
    geometry's ``CrossValidation.summary``), from the rigid controller's systematic position (mm)
    and phi (deg) errors (K,) over workspace postures, each figure with ``compensating_mean`` and
    ``systematic_mean`` beside it."""
    position = np.asarray(systematic_position_mm, dtype=float)
    phi = np.asarray(systematic_phi_deg, dtype=float)
    summary = {k: v for k, v in accuracy.items() if k not in ('per_posture', 'selected')}
    summary['calibrated'] = _calibrated(accuracy['calibrated'], position, phi)
    if accuracy.get('selected'):
        selected = accuracy['selected']
        summary['selected'] = {
            **selected,
            'calibrated': _calibrated(selected['calibrated'], position, phi),
        }
    summary['systematic_postures'] = int(position.size)
    return summary
