"""The accuracy a calibration achieved, measured by the device on postures the fit did not use.

The device measures the platform's position exactly (``alpha``, ``beta`` and ``D = D0 + Dm``,
eq 7 and 9) and its rotation ``phi``. So a geometry's error in predicting where the platform
is, from its measured leg lengths through forward kinematics, is a real accuracy (mm, deg),
available on any platform, ideal or not. :func:`cross_validate` splits the postures into folds,
fits the geometry without each fold and predicts the fold's postures from their leg lengths;
the nominal geometry predicts the same postures (the no-calibration baseline).

The measured error holds the measurement noise of the held-out posture too (the legs' noise
through FK, the device's through eq 9): independent of the fit, it adds in quadrature. Its
propagated variance is subtracted from the mean squared error (:func:`noise_removed`), and
the mean and p95 are scaled by the same factor. To first order, the error of FK(calibrated, q)
against the true pose at the real leg lengths q is the error of the pose the platform reaches
when the calibrated controller commands a pose (``validation.pose_errors``), with the sign
reversed: the same accuracy.

A held-out posture is predicted by a fit that did not see it: at a posture that alone determines
a parameter (an extreme of the workspace, which the selection prefers) that fit knows far less
than the full one. Each held-out error's excess over the noise is scaled by the full fit's over
the held-out fit's predicted variance there (:func:`leverage_ratios`), and the device's own
uncertainty, which no held-out posture sees, is added (:func:`device_variances`).
"""

import dataclasses
import math
import time

import numpy as np

from ..device import DeviceModelError, device_position
from ..effects.groups import EFFECT_PARAMETER_NAMES, design_rows, model_poses
from ..geometry import ALL_PARAMETER_NAMES, Geometry
from ..identification import IdentificationError, Options, identify
from ..kinematics import forward_kinematics_masked
from ..prediction import (
    parameter_pose_covariance,
    reading_pose_covariance,
    thermal_pose_covariance,
)
from ..rotation import wrap_angle

#: Folds of a cross-validation (a posture set with fewer postures is left out one at a time).
DEFAULT_FOLDS = 10


def device_pose(geometry, readings):
    """What the device measures under ``geometry``'s device parameters and sensor errors:
    ``(position (M, 3) m, phi (M,) rad)`` from readings ``[alpha, beta, phi, d_m]`` (M, 4)."""
    ideal = geometry.sensors.ideal_device_readings(np.atleast_2d(readings))
    position = device_position(
        ideal[:, 0],
        ideal[:, 1],
        geometry.device_length + ideal[:, 3],
        geometry.inclinometer_axes_angle,
    )
    return position, ideal[:, 2]


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
    """The variance the rows' noise (``row_sigmas``, a SensorNoise of the averaged rows) adds to
    the prediction errors at ``poses`` (M, 6) with ``readings`` (M, 4): ``(position (M,) m^2,
    the trace of its 3x3 covariance; phi (M,) rad^2)``
    (:func:`~gsp_kinematics.prediction.reading_pose_covariance`)."""
    position, euler = reading_pose_covariance(geometry, poses, readings, row_sigmas)
    return np.trace(position, axis1=1, axis2=2), euler[:, 2, 2]


#: The device's own parameters: its errors move where the device says the platform is.
DEVICE_PARAMETERS = ('D0', 'gamma', 'alpha0', 'beta0', 'phi0', 'kDm')


def device_variances(result, readings, step=1e-7):
    """The variance (position (M,) m^2, the trace; phi (M,) rad^2) of what the device measures
    at ``readings`` (M, 4) under ``result``'s geometry from the uncertainty of its own free
    parameters (:data:`DEVICE_PARAMETERS`, ``result.covariance``): an error the legs share (the
    fit makes them agree with the device), which no held-out posture can see."""
    readings = np.atleast_2d(np.asarray(readings, dtype=float))
    free = [n for n, on in zip(ALL_PARAMETER_NAMES, result.free, strict=True) if on]
    columns = [free.index(name) for name in DEVICE_PARAMETERS if name in free]
    covariance = np.asarray(result.covariance, dtype=float)
    if not columns or not np.all(np.isfinite(covariance[np.ix_(columns, columns)])):
        return np.zeros(len(readings)), np.zeros(len(readings))
    vector = result.geometry.to_full_vector()
    limits = result.geometry.limits
    base_position, base_phi = device_pose(result.geometry, readings)
    position, phi = [], []
    for column in columns:
        moved = vector.copy()
        moved[ALL_PARAMETER_NAMES.index(free[column])] += step
        shifted, shifted_phi = device_pose(Geometry.from_full_vector(moved, limits), readings)
        position.append((shifted - base_position) / step)
        phi.append(wrap_angle(shifted_phi - base_phi) / step)
    position, phi = np.stack(position, axis=2), np.stack(phi, axis=1)  # (M, 3, p), (M, p)
    block = covariance[np.ix_(columns, columns)]
    return (
        np.einsum('mip,pq,miq->m', position, block, position),
        np.einsum('mp,pq,mq->m', phi, block, phi),
    )


def parameter_variances(result, poses):
    """(M,) m^2: the trace of the position covariance that ``result``'s parameter covariance
    (geometry and effects) gives the reached pose at ``poses`` (M, 6); NaN where unknown."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    effect_free = getattr(result, 'effect_free', None)
    try:
        position, _ = parameter_pose_covariance(
            result.geometry, result.covariance, poses, result.free, effect_free
        )
    except (ValueError, np.linalg.LinAlgError):
        return np.full(poses.shape[0], np.nan)
    return np.trace(position, axis1=1, axis2=2)


def leverage_ratios(full, held_out, unmodelled=0.0):
    """(M,) in [0, 1]: at each posture, the predicted error variance of the full fit
    (``full`` (M,) m^2) over that of the fold's fit that did not see it (``held_out``), each
    with the ``unmodelled`` variance (M,) added, which no fit removes. A posture that alone
    determines a parameter (an extreme the selection chose) is predicted far worse by the fit
    without it than the full fit places it: the ratio takes that leverage out of its held-out
    error (docs/verdict.md). 1 where a variance is unknown (no correction)."""
    full = np.asarray(full, dtype=float) + unmodelled
    held_out = np.asarray(held_out, dtype=float) + unmodelled
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = full / held_out
    return np.where(np.isfinite(ratio) & (held_out > 0), np.clip(ratio, 0.0, 1.0), 1.0)


#: A held-out error's excess over the noise up to this many times the held-out fit's predicted
#: variance there (3 standard deviations) is the fold's ignorance, which the leverage scales;
#: beyond it, it is an error no fit's covariance explains (a model error), kept as measured.
LEVERAGE_EXPLAINS = 9.0


def without_leverage(errors, noise, ratios, held_out=None):
    """Held-out error magnitudes ``errors`` (M,) with the excess of their square over the
    posture's ``noise`` variance (M,) scaled by the leverage ``ratios`` (M,,
    :func:`leverage_ratios`): ``sqrt(r x + n)``, ``x = e^2 - n``, the error the full fit makes
    there plus the posture's own noise (removed later, :func:`noise_removed`). ``held_out``
    (M,) m^2: the held-out fit's predicted variance there (with the unmodelled part); the excess
    beyond :data:`LEVERAGE_EXPLAINS` times it is not scaled (None: all of it is)."""
    errors, noise, ratios = (np.asarray(v, dtype=float) for v in (errors, noise, ratios))
    excess = errors**2 - noise
    kept = np.zeros_like(excess)
    if held_out is not None:
        cap = LEVERAGE_EXPLAINS * np.asarray(held_out, dtype=float)
        beyond = np.isfinite(cap) & (excess > cap)
        kept = np.where(beyond, excess - cap, 0.0)
        excess = np.where(beyond, cap, excess)
    return np.sqrt(np.maximum(ratios * excess + kept + noise, 0.0))


def noise_removed(errors, variances, shared=None):
    """``(mean, p95, rms, factor)`` of error magnitudes ``errors`` (K,) with the noise's
    ``variances`` (K,) removed: ``factor = sqrt(max(1 - sum(variances) / sum(errors^2), 0))``
    scales the mean, the p95 and the rms (the noise's share of the mean squared error is taken
    out in quadrature; the error's distribution is assumed to keep its shape). ``shared`` (K,):
    the variance of an error the held-out errors cannot see (the device's own, which the fit
    gives the legs too: :func:`device_variances`), added in quadrature:
    ``factor = sqrt(max(1 - sum(variances) / sum(errors^2), 0) + sum(shared) / sum(errors^2))``."""
    errors = np.asarray(errors, dtype=float)
    variances = np.asarray(variances, dtype=float)
    shared = np.zeros_like(variances) if shared is None else np.asarray(shared, dtype=float)
    finite = np.isfinite(errors) & np.isfinite(variances) & np.isfinite(shared)
    if not finite.any():
        return math.nan, math.nan, math.nan, math.nan
    errors, variances, shared = errors[finite], variances[finite], shared[finite]
    squared = float(np.sum(errors**2))
    factor = (
        math.sqrt(
            max(1.0 - float(np.sum(variances)) / squared, 0.0) + float(np.sum(shared)) / squared
        )
        if squared > 0
        else 0.0
    )
    mean, p95 = float(np.mean(errors)), float(np.percentile(errors, 95))
    rms = math.sqrt(squared / errors.size)
    return factor * mean, factor * p95, factor * rms, factor


def _statistics(errors, variances, scale, shared=None):
    mean, p95, rms, factor = noise_removed(errors, variances, shared)
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
    """``scale`` x the rms of ``variances`` over the finite ``errors`` (0 without them)."""
    finite = np.isfinite(errors)
    if variances is None or not finite.any():
        return 0.0
    return scale * math.sqrt(float(np.mean(np.asarray(variances)[finite])))


@dataclasses.dataclass(frozen=True)
class CrossValidation:
    """Held-out prediction errors of a calibrated and of the nominal geometry (SI units).

    Per posture (M rows; NaN where it was not predicted): the errors of FK(geometry, legs)
    against the device, position (M, 3) m and phi (M,) rad, and the variance the posture's own
    noise adds to each (m^2, rad^2)."""

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
    #: (M,) m^2 and rad^2: the device's own uncertainty there (:func:`device_variances`), added
    #: to the calibrated figures; None: not added
    position_device: np.ndarray | None = None
    phi_device: np.ndarray | None = None
    #: (M,) m^2: the pose error a controller leaves uncompensated there (the identified thermal
    #: growth over the run), added to every calibrated position figure; None: none
    position_uncompensated: np.ndarray | None = None
    #: (M,) the leverage ratios (:func:`leverage_ratios`) that scale each held-out position
    #: error's excess over the noise to the full fit's; None: the raw held-out errors
    position_leverage: np.ndarray | None = None
    #: (M,) m^2: the held-out fit's predicted variance at each posture, the unmodelled part
    #: included (:func:`without_leverage`); None: unknown
    position_held_out_variance: np.ndarray | None = None

    @property
    def predicted(self):
        """Postures predicted by the calibrated geometry of their fold."""
        return int(np.count_nonzero(np.isfinite(self.phi_error)))

    def summary(self, workspace=None):
        """JSON-ready: the calibrated and nominal accuracy, position (mm) and phi (deg), each
        ``{mean, p95, rms}`` with the noise removed, beside the measured ``measured_mean``,
        ``measured_p95``, the noise's own ``noise_rms`` and the ``noise_factor`` applied;
        ``per_posture``: each posture's measured position errors (mm, NaN: not predicted) and
        its noise's standard deviation (mm), for plots.

        ``workspace`` (M,) bool: the rows of the run's workspace (validation) postures, drawn
        at random from the workspace: the headline (``calibrated``, ``nominal``, ``postures``)
        is then their held-out errors, an estimate of the mean over the workspace, and
        ``selected`` holds the same figures over the other (selected) postures;
        ``workspace_rows`` lists the rows (0-based). None or no row: every posture."""
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
            **self._figures(position, nominal, headline, device=bool(rows.any())),
            'per_posture': {
                'position_mm': (1e3 * position).tolist(),
                'nominal_position_mm': (1e3 * nominal).tolist(),
                'noise_position_mm': (1e3 * np.sqrt(self.position_noise)).tolist(),
                'uncompensated_position_mm': (
                    1e3 * np.sqrt(self.position_uncompensated)
                    if self.position_uncompensated is not None
                    else np.zeros(count)
                ).tolist(),
                'leverage': (
                    np.ones(count) if self.position_leverage is None else self.position_leverage
                ).tolist(),
                'device_position_mm': (
                    1e3
                    * np.sqrt(
                        np.zeros(count) if self.position_device is None else self.position_device
                    )
                ).tolist(),
            },
        }
        if rows.any() and not rows.all():
            summary['selected'] = {
                'postures': int(np.count_nonzero(np.isfinite(self.phi_error[~rows]))),
                **self._figures(position, nominal, ~rows),
            }
        return summary

    def _figures(self, position, nominal, rows, device=False):
        """``{calibrated, nominal}`` accuracy over ``rows`` (bool mask); ``device``: the
        device's own uncertainty added to the calibrated figures (the workspace postures'; with
        the leverage taken out, every posture's: the raw held-out errors of the selected
        postures, the workspace's extremes, already exceed it, docs/verdict.md)."""
        degrees = math.degrees(1.0)
        position_noise, phi_noise = self.position_noise[rows], self.phi_noise[rows]
        calibrated_position = position[rows]
        if self.position_leverage is not None:
            held_out = self.position_held_out_variance
            calibrated_position = without_leverage(
                calibrated_position,
                position_noise,
                self.position_leverage[rows],
                None if held_out is None else held_out[rows],
            )
            device = True
        device = device and self.position_device is not None
        position_device = self.position_device[rows] if device else None
        phi_device = self.phi_device[rows] if device else None
        uncompensated = self.position_uncompensated
        uncompensated = None if uncompensated is None else uncompensated[rows]
        shared = [v for v in (position_device, uncompensated) if v is not None]
        calibrated = _statistics(
            calibrated_position, position_noise, 1e3, sum(shared) if shared else None
        )
        raw = _statistics(position[rows], position_noise, 1e3)  # as measured, for the record
        calibrated['measured_mean'] = raw['measured_mean']
        calibrated['measured_p95'] = raw['measured_p95']
        calibrated['leverage_removed'] = self.position_leverage is not None
        calibrated['device_rms'] = _rms(position_device, position[rows], 1e3)
        calibrated['uncompensated_rms'] = _rms(uncompensated, position[rows], 1e3)
        return {
            'calibrated': {
                'position_mm': calibrated,
                'phi_deg': _statistics(
                    np.abs(self.phi_error[rows]), phi_noise, degrees, phi_device
                ),
            },
            'nominal': {
                'position_mm': _statistics(nominal[rows], position_noise, 1e3),
                'phi_deg': _statistics(np.abs(self.nominal_phi_error[rows]), phi_noise, degrees),
            },
        }


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


def _fold_fit(result, free, rows, options, effects):
    """``result``'s identification (same formulation and ``free`` parameters, from its
    estimate) of ``rows`` = ``(leg_lengths, readings, row_sigmas, pose guesses)`` of a fold's
    kept postures with their ``EffectDesign``; None when it fails or does not converge."""
    legs, readings, row_sigmas, guesses = rows
    try:
        fitted = identify(
            result.geometry,
            legs,
            readings,
            row_sigmas,
            result.formulation,
            free,
            guesses,
            options=options,
            effects=effects,
        )
    except (IdentificationError, DeviceModelError, np.linalg.LinAlgError):
        return None
    return fitted if fitted.converged else None


def _leverage(result, readings, held_out_variance, unmodelled):
    """``(ratios, held-out variances)`` (M,) at ``result``'s poses: :func:`leverage_ratios` of
    its predicted variance over each posture's ``held_out_variance``, and that variance, each
    with the ``unmodelled`` part (SensorNoise or None)."""
    poses = np.asarray(result.poses, dtype=float)
    unmodelled_variance = 0.0
    if unmodelled is not None:
        position, _ = reading_pose_covariance(result.geometry, poses, readings, unmodelled)
        unmodelled_variance = np.trace(position, axis1=1, axis2=2)
    full = parameter_variances(result, poses)
    ratios = leverage_ratios(full, held_out_variance, unmodelled_variance)
    return ratios, held_out_variance + unmodelled_variance


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
):
    """:class:`CrossValidation` of the identification ``result`` (of the rows ``leg_lengths``
    (M, 6), ``readings`` (M, 4), weights ``row_sigmas``): each fold is identified without it
    (same formulation and free parameters, from ``result``'s estimate and poses) and predicts
    its postures; the ``nominal`` geometry predicts every posture.

    A held-out posture's device reference uses the device parameters of the fit without it, the
    nominal baseline the full fit's. ``noise``: the rows' measurement noise removed from the
    errors (a SensorNoise; None: ``row_sigmas``); weights that hold a model error are not the
    noise: pass the within-posture noise. ``effects``: the rows' ``EffectDesign`` when
    ``result`` freed effect groups (each fold fits them and predicts with what it identified).
    ``uncompensated_strain`` (6,): the thermal growth the controllers leave (its error kept).
    ``unmodelled``: what the model leaves unexplained (a SensorNoise of row stds, or None:
    nothing), part of every posture's error that no fit removes: the leverage ratios
    (:func:`leverage_ratios`, ``CrossValidation.position_leverage``) add it to both fits'
    predicted variances, so a held-out error that is model error keeps its size."""
    started = time.perf_counter()
    leg_lengths, readings = np.asarray(leg_lengths, float), np.asarray(readings, float)
    count = leg_lengths.shape[0]
    assignment = fold_assignment(count, folds)
    guesses = np.asarray(result.poses, dtype=float)
    position, phi, failed = np.full((count, 3), np.nan), np.full(count, np.nan), []
    held_out_variance = np.full(count, np.nan)
    free = [name for name, on in zip(ALL_PARAMETER_NAMES, result.free, strict=True) if on]
    free += [n for n, on in zip(EFFECT_PARAMETER_NAMES, result.effect_free, strict=True) if on]
    for fold in range(int(assignment.max()) + 1):
        held, kept = assignment == fold, assignment != fold
        rows = (leg_lengths[kept], readings[kept], row_sigmas, guesses[kept])
        fitted = _fold_fit(result, free, rows, options, design_rows(effects, kept))
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
        held_out_variance[held] = parameter_variances(fitted, guesses[held])
    noise = row_sigmas if noise is None else noise
    position_noise, phi_noise = noise_variances(result.geometry, guesses, readings, noise)
    nominal_position, nominal_phi, _ = _errors(
        nominal, result.geometry, leg_lengths, readings, guesses
    )
    position_device, phi_device = device_variances(result, readings)
    leverage, held_out_variance = _leverage(result, readings, held_out_variance, unmodelled)
    return CrossValidation(
        position_leverage=leverage,
        position_held_out_variance=held_out_variance,
        position_uncompensated=_uncompensated(result.geometry, guesses, uncompensated_strain),
        position_device=position_device,
        phi_device=phi_device,
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
