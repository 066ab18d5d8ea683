"""Identifiability: rank, condition number (of the column-scaled Jacobian) and the parameter
combinations that cannot be identified, from the information ``J^T J`` of the free parameters."""

import math

import numpy as np

from ..channels import READING_NAMES
from ..model.geometry import ALL_PARAMETER_NAMES
from ..model.sensor_noise import DEFAULT_SENSOR_NOISE
from ._solver.readings import readings_jacobians
from .identification import DEFAULT_FORMULATION, SENSOR_NAMES, resolve_free

#: A scaled singular value below this fraction of the largest counts as zero.
DEFAULT_RELATIVE_TOLERANCE = 1e-6


def analyse_identifiability(
    information, free=None, relative_tolerance=DEFAULT_RELATIVE_TOLERANCE, names=None
):
    """``{rank, parameters, condition_number, singular_values, unidentifiable}``; ``names``: of
    the information's rows (default those of ``free``); ``unidentifiable``: per null direction
    ``{"combination": "0.71*B1x - 0.71*B2y", "parameters", "coefficients"}`` (scaled units)."""
    if names is None:
        free = resolve_free(free)
        names = [name for name, is_free in zip(ALL_PARAMETER_NAMES, free, strict=True) if is_free]
    information = np.asarray(information, dtype=float)
    if information.shape != (len(names), len(names)):
        raise ValueError(f'information must be {len(names)}x{len(names)}, got {information.shape}')
    diagonal = np.diag(information).copy()
    largest = max(float(diagonal.max(initial=0.0)), 1e-300)
    # A column with (almost) no information at all cannot be scaled; it is unidentifiable by itself.
    dead = diagonal <= (relative_tolerance**2) * largest * 1e-6
    scale = 1.0 / np.sqrt(np.where(dead, largest, diagonal))
    scaled = information * scale[:, None] * scale[None, :]
    eigenvalues, eigenvectors = np.linalg.eigh(scaled)
    singular_values = np.sqrt(np.clip(eigenvalues, 0.0, None))[::-1]
    eigenvectors = eigenvectors[:, ::-1]
    threshold = relative_tolerance * singular_values[0]
    null = singular_values <= threshold
    rank = int(np.count_nonzero(~null))
    condition = (
        float(singular_values[0] / singular_values[-1]) if singular_values[-1] > 0 else float('inf')
    )
    unidentifiable = []
    for column in np.flatnonzero(null):
        vector = eigenvectors[:, column]
        order = np.argsort(-np.abs(vector))
        keep = [index for index in order if abs(vector[index]) >= 0.1 * abs(vector[order[0]])]
        sign = np.sign(vector[order[0]])
        coefficients = [float(sign * vector[index]) for index in keep]
        members = [names[index] for index in keep]
        text = ' '.join(
            f'{"-" if value < 0 else "+"} {abs(value):.2f}*{name}'
            for value, name in zip(coefficients, members, strict=True)
        ).lstrip('+ ')
        unidentifiable.append(
            {'combination': text, 'parameters': members, 'coefficients': coefficients}
        )
    return {
        'rank': rank,
        'parameters': len(names),
        'condition_number': condition,
        'singular_values': singular_values.tolist(),
        'unidentifiable': unidentifiable,
    }


def unidentifiable_parameters(analysis):
    """Sorted names of every parameter involved in a null direction."""
    return sorted({name for entry in analysis['unidentifiable'] for name in entry['parameters']})


def analyse_result(result):
    """:func:`analyse_identifiability` of an ``IdentificationResult``'s information, plus
    ``names`` (:func:`unidentifiable_parameters`); a failed fit: rank 0, every parameter named."""
    information = np.asarray(result.information, dtype=float)
    if not np.all(np.isfinite(information)):
        names = list(result.free_names)
        return {
            'rank': 0,
            'parameters': len(names),
            'condition_number': math.inf,
            'unidentifiable': [],
            'names': names,
        }
    analysis = analyse_identifiability(information, names=list(result.free_names))
    analysis['names'] = unidentifiable_parameters(analysis)
    return analysis


def identifies_all(analysis):
    """Whether the :func:`analyse_result` ``analysis`` identifies every free parameter: full
    rank, no parameter in a null direction (a fit that does not is one of many, and its
    covariance, a pseudo-inverse, is not a covariance)."""
    return not analysis['names'] and analysis['rank'] >= analysis['parameters']


def analyse_design(
    geometry,
    poses,
    sigmas=DEFAULT_SENSOR_NOISE,
    free=None,
    formulation=DEFAULT_FORMULATION,
    sensors=SENSOR_NAMES,
    relative_tolerance=DEFAULT_RELATIVE_TOLERANCE,
):
    """Identifiability of a measurement design (postures, sensors) before any data is taken."""
    information = posture_information(geometry, poses, sigmas, free, formulation, sensors)
    return analyse_identifiability(information.sum(axis=0), free, relative_tolerance)


def posture_factors(
    geometry,
    poses,
    sigmas=None,
    free=None,
    formulation=DEFAULT_FORMULATION,
    sensors=SENSOR_NAMES,
    leg_columns=None,
):
    """Per-posture information factors ``G`` (N, r, n): posture k's information is ``G_k^T G_k``.

    ``'implicit'``: the weighted residual Jacobian projected on the orthogonal complement of the
    pose's columns (r = k - 6; the Schur complement); ``'fk'``: the FK-based residual Jacobian.
    ``sigmas``: the ``SensorNoise`` weights. ``leg_columns`` (N, 6, e): derivatives of the leg
    readings (m per unit) w.r.t. e more parameters only the legs see (``'implicit'`` only), last."""
    sigmas = DEFAULT_SENSOR_NOISE if sigmas is None else sigmas
    free = resolve_free(free)
    columns = [c for c, name in enumerate(READING_NAMES) if name in sensors]
    # Derivatives of the sensor readings (the sensor errors included) over the extended vector.
    _, d_pose, d_u = readings_jacobians(geometry, poses)
    d_q_d_pose, d_q_d_u, d_h_d_pose, d_h_d_u = d_pose[:, :6], d_u[:, :6], d_pose[:, 6:], d_u[:, 6:]
    reading_weights = 1.0 / sigmas.readings()[columns]
    d_h_d_pose = d_h_d_pose[:, columns] * reading_weights[None, :, None]
    d_h_d_u = d_h_d_u[:, columns][:, :, free] * reading_weights[None, :, None]
    d_q_d_u = d_q_d_u[:, :, free]
    if formulation == 'implicit':
        jac_pose = np.concatenate([d_q_d_pose / sigmas.leg_lengths, d_h_d_pose], axis=1)
        jac_u = np.concatenate([d_q_d_u / sigmas.leg_lengths, d_h_d_u], axis=1)
        if leg_columns is not None:
            leg_columns = np.asarray(leg_columns, dtype=float) / sigmas.leg_lengths
            device_rows = np.zeros((len(jac_u), d_h_d_u.shape[1], leg_columns.shape[2]))
            jac_u = np.concatenate(
                [jac_u, np.concatenate([leg_columns, device_rows], axis=1)], axis=2
            )
        complement = np.linalg.qr(jac_pose, mode='complete')[0][:, :, 6:]
        return np.swapaxes(complement, 1, 2) @ jac_u
    return d_h_d_u - d_h_d_pose @ np.linalg.solve(d_q_d_pose, d_q_d_u)


def posture_information(
    geometry,
    poses,
    sigmas=None,
    free=None,
    formulation='implicit',
    sensors=SENSOR_NAMES,
    leg_columns=None,
):
    """Per-posture information matrices (N, n, n) of the free parameters, weighted (the pose
    eliminated for ``'implicit'``)."""
    factors = posture_factors(geometry, poses, sigmas, free, formulation, sensors, leg_columns)
    return np.einsum('mri,mrj->mij', factors, factors)


def scaled_condition_number(information):
    """Condition number of the column-scaled Jacobian, from its information matrix (inf if singular)."""
    scale = 1.0 / np.sqrt(np.maximum(np.diagonal(information, axis1=-2, axis2=-1), 1e-300))
    scaled = information * scale[..., :, None] * scale[..., None, :]
    eigenvalues = np.linalg.eigvalsh(scaled)
    with np.errstate(divide='ignore', invalid='ignore'):
        condition = np.sqrt(eigenvalues[..., -1] / eigenvalues[..., 0])
    return np.where(eigenvalues[..., 0] > 1e-14 * eigenvalues[..., -1], condition, np.inf)
