"""The accuracy a calibration achieved, measured by the device on postures the fit did not use."""

import dataclasses
import math
import time

import numpy as np

from ...model.effect_groups import design_rows, model_poses
from ...model.effects import EFFECT_PARAMETER_NAMES
from ...model.geometry import ALL_PARAMETER_NAMES
from ...model.kinematics import Workspace, forward_kinematics_masked, sample_valid_postures
from ...rotation import wrap_angle
from ..identification import Options
from ..prediction import parameter_pose_covariance, reading_pose_covariance, thermal_pose_covariance
from .comparison import (
    comparison_sensitivities,
    comparison_variances,
    device_pose,
    explained_excess,
    leverage_ratios,
    propagated_variances,
)
from .fold_fits import linearised_refits, refit_fold
from .interval import figure_interval, posture_terms, reach_selected, workspace_truth_draws

#: Folds of a cross-validation (a posture set with fewer postures is left out one at a time).
DEFAULT_FOLDS = 10
#: Random workspace postures (seeded) the truth's predicted variance is averaged over, to carry
#: the measured figure from the run's postures to the workspace.
WORKSPACE_SAMPLE = 200


def prediction_errors(geometry, leg_lengths, readings, guesses):
    """Forward kinematics of the measured ``leg_lengths`` (M, 6) under ``geometry`` minus what
    the device measures (``readings`` (M, 4)) under the same ``geometry``:
    ``(position (M, 3) m, phi (M,) rad, converged (M,))``; NaN where FK failed."""
    return _errors(geometry, geometry, leg_lengths, readings, guesses)


def _errors(legs_geometry, device_geometry, leg_lengths, readings, guesses, design=None):
    if legs_geometry.effects.none:
        articular = legs_geometry.sensors.true_leg_lengths(leg_lengths)
        poses, converged = forward_kinematics_masked(legs_geometry, articular, guesses)
    else:  # the identified effects (docs/platform_effects.md), with the rows' design
        poses, converged = model_poses(legs_geometry, leg_lengths, guesses, design)
    position, phi = device_pose(device_geometry, readings)
    position_error = np.where(converged[:, None], poses[:, :3] - position, np.nan)
    phi_error = np.where(converged, wrap_angle(poses[:, 5] - phi), np.nan)
    return position_error, phi_error, converged


def noise_variances(geometry, poses, readings, row_sigmas):
    """The variance the rows' noise (``row_sigmas``) adds to the prediction errors at ``poses``
    (M, 6) with ``readings`` (M, 4): ``(position (M,) m^2, phi (M,) rad^2)``."""
    position, euler = reading_pose_covariance(geometry, poses, readings, row_sigmas)
    return np.trace(position, axis1=1, axis2=2), euler[:, 2, 2]


def noise_removed(errors, variances, unseen=None, leverage=None, held_out=None, transfer=1.0):
    """``(mean, p95, rms, factor)`` of held-out error magnitudes ``errors`` (K,) with the
    noise's ``variances`` (K,) removed, ``unseen`` (K,) added and each excess scaled by its
    ``leverage`` (K,) up to :func:`.comparison.explained_excess` of ``held_out`` (K,) m^2;
    ``factor = sqrt(signal / sum(draws^2))`` scales the draws (docs/verdict.md)."""
    signal, draws = posture_terms(errors, variances, unseen, leverage, held_out)
    if not draws.size:
        return math.nan, math.nan, math.nan, math.nan
    signal = transfer * max(float(np.sum(signal)), 0.0)
    squared = float(np.sum(draws**2))
    factor = math.sqrt(signal / squared) if squared > 0 else 0.0
    mean, p95 = float(np.mean(draws)), float(np.percentile(draws, 95))
    rms = math.sqrt(squared / draws.size)
    return factor * mean, factor * p95, factor * rms, factor


def without_leverage(errors, noise, ratios, held_out=None):
    """Held-out error magnitudes ``errors`` (M,) with their excess over the ``noise`` variance
    (M,) scaled by the leverage ``ratios`` (M,) up to :func:`.comparison.explained_excess` of
    ``held_out`` (None: no bound), the noise still in: ``sqrt(r x + kept + n)``."""
    explained, kept = explained_excess(errors, noise, held_out)
    ratios = np.asarray(ratios, dtype=float)
    return np.sqrt(np.maximum(ratios * explained + kept + np.asarray(noise, dtype=float), 0.0))


def _statistics(errors, variances, scale, *correction):
    mean, p95, rms, factor = noise_removed(errors, variances, *correction)
    finite = np.isfinite(errors)
    raw = np.asarray(errors, dtype=float)[finite]
    return {
        'mean': scale * mean,
        'p95': scale * p95,
        'rms': scale * rms,
        'measured_mean': scale * float(np.mean(raw)) if raw.size else math.nan,
        'measured_p95': scale * float(np.percentile(raw, 95)) if raw.size else math.nan,
        'noise_rms': scale * math.sqrt(float(np.mean(np.asarray(variances)[finite])))
        if raw.size
        else math.nan,
        'noise_factor': factor,
    }


def _rms(variances, errors, scale):
    """``scale`` x the rms of ``variances`` over the finite ``errors`` (0 without them), signed:
    negative when their mean is (an unseen part the comparison holds beyond the truth)."""
    finite = np.isfinite(errors)
    if variances is None or not finite.any():
        return 0.0
    mean = float(np.mean(np.asarray(variances)[finite]))
    return math.copysign(scale * math.sqrt(abs(mean)), mean)


def _rows(values, rows):
    """``values[rows]``, or None without values."""
    return None if values is None else np.asarray(values)[rows]


def _signed_sqrt(values, count, scale):
    values = np.zeros(count) if values is None else np.asarray(values, dtype=float)
    return (scale * np.sign(values) * np.sqrt(np.abs(values))).tolist()


@dataclasses.dataclass(frozen=True)
class CrossValidation:
    """Held-out prediction errors of a calibrated and of the nominal geometry (SI units): per
    posture (M; NaN: not predicted) FK against the device, position (M, 3) m and phi (M,) rad, and
    the variance its own noise adds (m^2, rad^2)."""

    folds: int
    fold_of_posture: np.ndarray  #: (M,) the fold that held each posture out
    position_error: np.ndarray  #: (M, 3) m, calibrated without the posture's fold
    phi_error: np.ndarray  #: (M,) rad
    position_noise: np.ndarray  #: (M,) m^2
    phi_noise: np.ndarray  #: (M,) rad^2
    nominal_position_error: np.ndarray  #: (M, 3) m
    nominal_phi_error: np.ndarray  #: (M,) rad
    failed_folds: tuple  #: folds whose fit did not converge (their postures are NaN)
    duration_s: float
    #: (M,) m^2 and rad^2: the truth's predicted variance there less the comparison's
    #: (:func:`.comparison.comparison_variances`), added to the calibrated figures (negative:
    #: subtracted); None: nothing
    position_unseen: np.ndarray | None = None
    phi_unseen: np.ndarray | None = None
    #: (M,) m^2: the pose error a controller leaves uncompensated there (the identified thermal
    #: growth over the run), added to every calibrated position figure; None: none
    position_uncompensated: np.ndarray | None = None
    #: (M,) the leverage ratios (:func:`.comparison.leverage_ratios`) that scale each held-out
    #: error's excess over the noise to the full fit's; None: the raw held-out errors
    position_leverage: np.ndarray | None = None
    phi_leverage: np.ndarray | None = None
    #: (M,) m^2 and rad^2: the held-out fit's predicted variance of the comparison at each
    #: posture, the unmodelled part included (:func:`noise_removed`); None: unknown
    position_held_out_variance: np.ndarray | None = None
    phi_held_out_variance: np.ndarray | None = None
    #: (M,) m^2: the truth's predicted position variance at each posture that the model
    #: describes (the parameters' and the uncompensated growth's), and its mean over random
    #: workspace postures: their ratio carries that share of the figure from the run's postures
    #: to the workspace (:meth:`_transfer`); None: no transfer
    position_truth_variance: np.ndarray | None = None
    workspace_truth_variance: float | None = None
    #: (M,) m^2: the unmodelled part's predicted position variance there (its share stays)
    position_unmodelled_variance: np.ndarray | None = None
    #: (R,): the truth's draws about its expectation under the fit's covariance, for the
    #: intervals (:func:`.interval.truth_draw_ratios`); None: the truth at its expectation
    position_truth_draws: np.ndarray | None = None
    phi_truth_draws: np.ndarray | None = None

    @property
    def predicted(self):
        """Postures predicted by the calibrated geometry of their fold."""
        return int(np.count_nonzero(np.isfinite(self.phi_error)))

    def summary(self, workspace=None):
        """JSON-ready: the calibrated and nominal accuracy, position (mm) and phi (deg), each
        ``{mean, p95, rms}`` with the noise removed, beside ``measured_mean``, ``measured_p95``,
        ``noise_rms`` and ``noise_factor``; ``per_posture``: measured position errors (mm) and noise
        stds (mm). ``workspace`` (M,) bool: the rows of workspace postures, then the headline and
        ``selected`` (the others) and ``workspace_rows`` (docs/data.md); None: every posture."""
        position = np.linalg.norm(self.position_error, axis=1)
        nominal = np.linalg.norm(self.nominal_position_error, axis=1)
        count = position.shape[0]
        rows = np.zeros(count, bool) if workspace is None else np.asarray(workspace, bool)
        headline = rows if rows.any() else np.ones(count, bool)
        summary = {
            'folds': self.folds,
            'postures': int(np.count_nonzero(np.isfinite(self.phi_error[headline]))),
            'measured_on': 'workspace' if rows.any() else 'selected',
            'workspace_rows': np.flatnonzero(rows).tolist(),
            'failed_folds': list(self.failed_folds),
            'duration_s': self.duration_s,
            **self._figures(position, nominal, headline),
            'per_posture': {
                'position_mm': (1e3 * position).tolist(),
                'nominal_position_mm': (1e3 * nominal).tolist(),
                'noise_position_mm': (1e3 * np.sqrt(self.position_noise)).tolist(),
                'uncompensated_position_mm': _signed_sqrt(self.position_uncompensated, count, 1e3),
                'leverage': (
                    np.ones(count) if self.position_leverage is None else self.position_leverage
                ).tolist(),
                'unseen_position_mm': _signed_sqrt(self.position_unseen, count, 1e3),
            },
        }
        if rows.any() and not rows.all():
            summary['selected'] = {
                'postures': int(np.count_nonzero(np.isfinite(self.phi_error[~rows]))),
                **self._figures(position, nominal, ~rows),
            }
            reach_selected(summary['calibrated'], summary['selected']['calibrated'])
        return summary

    def _figures(self, position, nominal, rows):
        """``{calibrated, nominal}`` accuracy over ``rows`` (bool mask): the calibrated figures
        with the leverage taken out and the unseen part (and the uncompensated growth) added
        (:func:`noise_removed`, docs/verdict.md); the raw held-out figure kept beside them."""
        degrees = math.degrees(1.0)
        position_noise, phi_noise = self.position_noise[rows], self.phi_noise[rows]
        unseen = [v for v in (self.position_unseen, self.position_uncompensated) if v is not None]
        unseen = _rows(sum(unseen), rows) if unseen else None
        transfer = self._transfer(rows & np.isfinite(position))
        correction = (
            unseen,
            _rows(self.position_leverage, rows),
            _rows(self.position_held_out_variance, rows),
            transfer,
        )
        calibrated = _statistics(position[rows], position_noise, 1e3, *correction)
        calibrated['mean_interval_95'] = figure_interval(
            position[rows], position_noise, 1e3, correction, self.position_truth_draws
        )
        calibrated['leverage_removed'] = self.position_leverage is not None
        calibrated['workspace_transfer'] = transfer
        calibrated['unseen_rms'] = _rms(_rows(self.position_unseen, rows), position[rows], 1e3)
        calibrated['uncompensated_rms'] = _rms(
            _rows(self.position_uncompensated, rows), position[rows], 1e3
        )
        phi = np.abs(self.phi_error[rows])
        correction = (
            _rows(self.phi_unseen, rows),
            _rows(self.phi_leverage, rows),
            _rows(self.phi_held_out_variance, rows),
        )
        calibrated_phi = _statistics(phi, phi_noise, degrees, *correction)
        calibrated_phi['mean_interval_95'] = figure_interval(
            phi, phi_noise, degrees, correction, self.phi_truth_draws
        )
        calibrated_phi['leverage_removed'] = self.phi_leverage is not None
        calibrated_phi['unseen_rms'] = _rms(_rows(self.phi_unseen, rows), phi, degrees)
        return {
            'calibrated': {'position_mm': calibrated, 'phi_deg': calibrated_phi},
            'nominal': {
                'position_mm': _statistics(nominal[rows], position_noise, 1e3),
                'phi_deg': _statistics(np.abs(self.nominal_phi_error[rows]), phi_noise, degrees),
            },
        }

    def _transfer(self, rows):
        """The scale that carries the signal at the postures ``rows`` (bool mask) to the
        workspace: ``f ratio + 1 - f``, ``f`` the modelled share of the truth's predicted variance,
        ``ratio`` its workspace mean over that at the rows (1: unknown; docs/verdict.md)."""
        truth, workspace = self.position_truth_variance, self.workspace_truth_variance
        if truth is None or workspace is None or not rows.any():
            return 1.0
        modelled = float(np.mean(np.asarray(truth)[rows]))
        unmodelled = self.position_unmodelled_variance
        unmodelled = 0.0 if unmodelled is None else float(np.mean(np.asarray(unmodelled)[rows]))
        if not (modelled > 0 and math.isfinite(modelled + unmodelled + workspace)):
            return 1.0
        share = modelled / (modelled + unmodelled)
        return share * workspace / modelled + 1.0 - share


def fold_assignment(count, folds=DEFAULT_FOLDS):
    """The fold (0..k-1) of each of ``count`` postures, interleaved (posture m in fold m mod k,
    so each fold spreads over the run); ``k = min(folds, count)`` (k = count: leave one out)."""
    if folds < 2:
        raise ValueError(f'cross-validation needs at least 2 folds, got {folds}')
    return np.arange(count) % min(int(folds), count)


def _uncompensated(geometry, poses, strain):
    """(M,) m^2: the position error the thermal ``strain`` (6,) leaves at ``poses`` (None:
    none)."""
    if strain is None:
        return None
    position, _ = thermal_pose_covariance(geometry, poses, strain)
    return np.trace(position, axis1=1, axis2=2)


def _corrections(result, readings, held_out, unmodelled, effects, sensitivities):
    """The :class:`CrossValidation` fields that correct ``result``'s held-out errors: the
    leverage ratios against each posture's ``held_out`` variances (position (M,) m^2, phi (M,)
    rad^2), with ``unmodelled`` (SensorNoise or None) added to both, and the unseen part
    (``sensitivities``: :func:`.comparison.comparison_sensitivities` at ``result``'s poses)."""
    poses = np.asarray(result.poses, dtype=float)
    unmodelled_variances = (0.0, 0.0)
    if unmodelled is not None:
        position, euler = reading_pose_covariance(result.geometry, poses, readings, unmodelled)
        unmodelled_variances = (np.trace(position, axis1=1, axis2=2), euler[:, 2, 2])
    controller, comparison = comparison_variances(result, poses, readings, effects, sensitivities)
    fields = {}
    for k, channel in enumerate(('position', 'phi')):
        extra = unmodelled_variances[k]
        fields[f'{channel}_leverage'] = leverage_ratios(comparison[k], held_out[k], extra)
        fields[f'{channel}_held_out_variance'] = held_out[k] + extra
        fields[f'{channel}_unseen'] = controller[k] - comparison[k]
    fields['position_truth_variance'] = controller[0]
    fields['position_unmodelled_variance'] = unmodelled_variances[0] + np.zeros(len(poses))
    return fields


def _workspace_truth_variance(result, poses, strain):
    """m^2: the truth's predicted position variance that the model describes (the parameters',
    the uncompensated thermal ``strain``'s) averaged over the workspace ``poses`` (as the
    predicted accuracy samples it); None without them or a usable covariance."""
    geometry = result.geometry
    covariance = np.asarray(result.covariance, dtype=float)
    if poses is None or not np.all(np.isfinite(covariance)):
        return None
    position, _ = parameter_pose_covariance(
        geometry, covariance, poses, result.free, result.effect_free
    )
    variance = np.trace(position, axis1=1, axis2=2)
    thermal = _uncompensated(geometry, poses, strain)
    return float(np.mean(variance if thermal is None else variance + thermal))


def _held_out(result, rows, assignment, options, effects, linearised, sensitivity):
    """``(position (M, 3) m, phi (M,) rad, (position, phi) variances, failed folds)``: each
    posture's error predicted by the fit without its fold (``assignment``) and that fit's variance
    of the comparison there. ``rows``: ``(leg_lengths, readings, row_sigmas, guesses)``;
    ``sensitivity``: the comparison's (:func:`.comparison.comparison_sensitivities`) there."""
    leg_lengths, readings, row_sigmas, guesses = rows
    folds = range(int(assignment.max()) + 1)
    steps = linearised and linearised_refits(
        result, leg_lengths, readings, row_sigmas, effects, [assignment != f for f in folds]
    )
    count = leg_lengths.shape[0]
    position, phi, failed = np.full((count, 3), np.nan), np.full(count, np.nan), []
    held_out = (np.full(count, np.nan), np.full(count, np.nan))  # position, phi
    free = [name for name, on in zip(ALL_PARAMETER_NAMES, result.free, strict=True) if on]
    free += [n for n, on in zip(EFFECT_PARAMETER_NAMES, result.effect_free, strict=True) if on]
    for fold in folds:
        held, kept = assignment == fold, assignment != fold
        kept_rows = (leg_lengths[kept], readings[kept], row_sigmas, guesses[kept])
        if steps:
            fitted = steps[fold]
        else:
            fitted = refit_fold(result, free, kept_rows, options, design_rows(effects, kept))
        if fitted is None:
            failed.append(fold)
            continue
        position[held], phi[held], _ = _errors(
            fitted.geometry,
            fitted.geometry,
            leg_lengths[held],
            readings[held],
            guesses[held],
            design_rows(effects, held),
        )
        if steps:  # the full fit's sensitivities: the step moves them to second order
            comparison = propagated_variances(sensitivity[held], fitted.covariance)
        else:
            _, comparison = comparison_variances(
                fitted, guesses[held], readings[held], design_rows(effects, held)
            )
        held_out[0][held], held_out[1][held] = comparison
    return position, phi, held_out, failed


def cross_validate(
    result,
    nominal,
    leg_lengths,
    readings,
    row_sigmas,
    folds=DEFAULT_FOLDS,
    options=Options(),
    noise=None,
    effects=None,
    uncompensated_strain=None,
    unmodelled=None,
    workspace=Workspace(),
    linearised=False,
    truth_draws=True,
):
    """:class:`CrossValidation` of the identification ``result`` (of the rows ``leg_lengths``
    (M, 6), ``readings`` (M, 4), weights ``row_sigmas``): each fold is identified without its
    postures (``linearised``: to first order, :mod:`.fold_fits`) and predicts them; the
    ``nominal`` geometry predicts every posture (docs/verdict.md).

    ``noise``: the rows' measurement noise removed from the errors (a SensorNoise; None:
    ``row_sigmas``). ``effects``: the rows' ``EffectDesign`` when ``result`` freed effect groups.
    ``uncompensated_strain`` (6,): the thermal growth the controllers leave. ``unmodelled``: a
    SensorNoise of row stds no fit removes (None: nothing). ``workspace``: the ``Workspace`` the
    calibrated position figure is carried to (None: the run's postures). ``truth_draws``: False
    leaves out the truth's draws (:func:`.interval.workspace_truth_draws`), which only the
    summary's intervals read (the model choice reads none)."""
    started = time.perf_counter()
    leg_lengths, readings = np.asarray(leg_lengths, float), np.asarray(readings, float)
    count = leg_lengths.shape[0]
    assignment = fold_assignment(count, folds)
    guesses = np.asarray(result.poses, dtype=float)
    rows = (leg_lengths, readings, row_sigmas, guesses)
    sensitivities = comparison_sensitivities(result, guesses, readings, effects)
    position, phi, held_out, failed = _held_out(
        result, rows, assignment, options, effects, linearised, sensitivities[1]
    )
    noise = row_sigmas if noise is None else noise
    position_noise, phi_noise = noise_variances(result.geometry, guesses, readings, noise)
    nominal_position, nominal_phi, _ = _errors(
        nominal, result.geometry, leg_lengths, readings, guesses
    )
    corrections = _corrections(result, readings, held_out, unmodelled, effects, sensitivities)
    sample = None  # WORKSPACE_SAMPLE seeded random postures of the workspace
    if workspace is not None:
        rng = np.random.default_rng(0)
        sample = sample_valid_postures(result.geometry, WORKSPACE_SAMPLE, rng, workspace)
    uncompensated = _uncompensated(result.geometry, guesses, uncompensated_strain)
    if uncompensated is not None:
        corrections['position_truth_variance'] = (
            corrections['position_truth_variance'] + uncompensated
        )
    return CrossValidation(
        **corrections,
        workspace_truth_variance=_workspace_truth_variance(result, sample, uncompensated_strain),
        **(
            workspace_truth_draws(result, guesses if sample is None else sample)
            if truth_draws
            else {}
        ),
        position_uncompensated=uncompensated,
        folds=int(assignment.max()) + 1,
        fold_of_posture=assignment,
        position_error=position,
        phi_error=phi,
        position_noise=position_noise,
        phi_noise=phi_noise,
        nominal_position_error=nominal_position,
        nominal_phi_error=nominal_phi,
        failed_folds=tuple(failed),
        duration_s=time.perf_counter() - started,
    )
