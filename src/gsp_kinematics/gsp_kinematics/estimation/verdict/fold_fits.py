"""The fits of a cross-validation's folds: a fit's refit without some postures
(:func:`refit_fold`), or that refit to first order, one Gauss-Newton step from the full fit
(:func:`linearised_refits`; docs/platform_effects.md#choosing-the-model-auto)."""

import dataclasses

import numpy as np

from ...model.device import DeviceModelError
from ...model.effect_groups import EffectDesign, EffectTerms, geometry_with_effects
from ...model.geometry import Geometry
from .._solver.formulations import _ImplicitModel
from .._solver.lm import block_normal_equations, eliminate_poses
from ..identifiability import analyse_result, identifies_all
from ..identification import SENSOR_NAMES, IdentificationError, identify


def _linearised_model(result, leg_lengths, readings, row_sigmas, effects, nominal=None):
    """``(model, values, augmented [J_X | J_u | r] (M, k, 6 + n + 1))`` of ``result``'s
    implicit model on its rows at its estimate (the geometry the refits start from; the effects'
    joint axes those of ``nominal``, default that geometry, as a refit's)."""
    terms = None
    if np.any(result.effect_free):
        design = effects or EffectDesign()
        axes = result.geometry if nominal is None else nominal
        terms = EffectTerms(axes, design, result.effect_free, len(leg_lengths))
    poses = np.asarray(result.poses, dtype=float)
    model = _ImplicitModel(
        result.geometry, leg_lengths, readings, row_sigmas, result.free, poses, SENSOR_NAMES, terms
    )
    values = np.concatenate(
        [result.parameters[result.free], result.effect_values[result.effect_free]]
    )
    _, jacobian = model._evaluate(values, poses)
    return model, values, jacobian()


def _stepped(result, model, values, system):
    """``result`` moved by the Gauss-Newton step of the reduced ``system`` ``[S | g]``, with
    ``S`` as its information; None when ``S`` does not identify every parameter."""
    size = system.shape[0]
    information = system[:, :size]
    stepped = dataclasses.replace(result, information=information)
    if not identifies_all(analyse_result(stepped)):
        return None
    try:
        covariance = np.linalg.inv(information)
        values = values + np.linalg.solve(information, -system[:, size])
    except np.linalg.LinAlgError:
        return None
    first = int(np.sum(result.free))
    vector = result.parameters.copy()
    vector[result.free] = values[:first]
    effect_values = result.effect_values.copy()
    effect_values[result.effect_free] = values[first:]
    geometry = Geometry.from_full_vector(vector, result.geometry.limits)
    deviations = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    standard_deviations = np.full(vector.shape, np.nan)
    standard_deviations[result.free] = deviations[:first]
    effect_deviations = result.effect_standard_deviations.copy()
    effect_deviations[result.effect_free] = deviations[first:]
    return dataclasses.replace(
        stepped,
        geometry=geometry_with_effects(geometry, model, effect_values),
        parameters=vector,
        effect_values=effect_values,
        covariance=covariance,
        standard_deviations=standard_deviations,
        effect_standard_deviations=effect_deviations,
    )


def linearised_refits(result, leg_lengths, readings, row_sigmas, effects, kept):
    """``result``'s refit of each posture subset ``kept`` ((M,) bool masks of its rows
    ``leg_lengths``, ``readings``, ``row_sigmas``, ``effects``) as one Gauss-Newton step: a
    result per subset (None where it does not identify every parameter), or None unless ``result``
    is a converged implicit least-squares fit."""
    if result.formulation != 'implicit' or not result.converged or result.loss != 'linear':
        return None
    leg_lengths, readings = np.asarray(leg_lengths, float), np.asarray(readings, float)
    model, values, augmented = _linearised_model(result, leg_lengths, readings, row_sigmas, effects)
    pose_rows, total = block_normal_equations(augmented)
    full, _ = eliminate_poses(pose_rows, total)
    refits = []
    for rows in kept:
        held = ~np.asarray(rows, dtype=bool)
        flat = augmented[held][:, :, 6:].reshape(-1, augmented.shape[2] - 6)
        share, _ = eliminate_poses(pose_rows[held], flat.T @ flat)
        refits.append(_stepped(result, model, values, full - share))
    return refits


def refit_fold(result, free, rows, options, effects):
    """``result``'s identification (same formulation and ``free``, from its estimate) of ``rows``
    = ``(leg_lengths, readings, row_sigmas, pose guesses)`` of a fold with its ``EffectDesign``;
    None when it fails or does not identify every parameter."""
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
    return fitted if fitted.converged and identifies_all(analyse_result(fitted)) else None


def linearised_cost(result, nominal, leg_lengths, readings, row_sigmas, effects):
    """The least cost (half the chi-square) of ``result``'s model on its rows with the effect
    design ``effects`` instead of its own, to second order (one Gauss-Newton step from
    ``result``'s estimate)."""
    _, _, augmented = _linearised_model(result, leg_lengths, readings, row_sigmas, effects, nominal)
    pose_rows, total = block_normal_equations(augmented)
    reduced, solved = eliminate_poses(pose_rows, total)
    size = reduced.shape[0]
    gradient = reduced[:, size]
    decrease = float(np.sum(pose_rows[:, :, -1] * solved[:, :, -1]))
    decrease += float(gradient @ np.linalg.solve(reduced[:, :size], gradient))
    return 0.5 * float(np.sum(augmented[:, :, -1] ** 2)) - 0.5 * decrease
