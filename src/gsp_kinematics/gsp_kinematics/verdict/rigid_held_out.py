"""The held-out accuracy of the rigid geometry a controller without ``geometry.effects.*`` runs
(:mod:`gsp_kinematics.effects.rigid_fold`), from the compensating geometry's, without a refit
or a fold (docs/verdict.md).

A rigid controller's error at a posture has two parts: the error of the fit's parameters, which
the fold inherits (what the compensating geometry's held-out figure measures, noise removed and
carried to the workspace), and the fold's deterministic difference from the identified model
there (:func:`~gsp_kinematics.effects.rigid_fold.rigid_model_errors`: the effects' variation
with the posture and the backlash's direction, which no rigid geometry follows). The second is
known at any posture once the model is: it is taken over random workspace postures, where the
truth averages, not at the run's postures (the selection's extremes, where it is several times
larger). The two add in quadrature at each workspace posture (independent: one is the fit's
error, the other fixed by its estimate); the figure is their mean. The map is increasing in
the compensating figure, so the ends of its 95 % interval map to the rigid figure's.
"""

import math

import numpy as np


def _mean_hypot(systematic, value):
    """Mean over the workspace postures of ``hypot(systematic, value)``; NaN without a value."""
    if value is None or not math.isfinite(value):
        return math.nan
    return float(np.mean(np.hypot(systematic, value)))


def _rigid_figure(figure, systematic):
    """A held-out figure (``{mean, p95, rms, mean_interval_95, ...}``) of the compensating
    geometry as the rigid geometry's, with its ``systematic`` errors (K,) over the workspace."""
    interval = figure.get('mean_interval_95') or [math.nan, math.nan]
    mean = figure['mean']
    return {
        'mean': _mean_hypot(systematic, mean),
        'p95': float(np.percentile(np.hypot(systematic, mean), 95))
        if math.isfinite(mean)
        else math.nan,
        'rms': _mean_hypot(systematic, figure.get('rms')),
        'mean_interval_95': [_mean_hypot(systematic, value) for value in interval],
        'measured_mean': _mean_hypot(systematic, figure.get('measured_mean')),
        'compensating_mean': mean,
        'systematic_mean': float(np.mean(systematic)),
    }


def _calibrated(calibrated, position, phi):
    return {
        'position_mm': _rigid_figure(calibrated['position_mm'], position),
        'phi_deg': _rigid_figure(calibrated['phi_deg'], phi),
    }


def rigid_held_out(accuracy, systematic_position_mm, systematic_phi_deg):
    """The rigid geometry's held-out accuracy, shaped as ``accuracy`` (the compensating
    geometry's ``CrossValidation.summary``, without its per-posture lists), from the rigid
    controller's ``systematic_position_mm`` and ``systematic_phi_deg`` (K,) errors over
    workspace postures; each figure keeps the compensating one (``compensating_mean``) and
    the systematic mean (``systematic_mean``) beside it. ``nominal`` is unchanged."""
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
