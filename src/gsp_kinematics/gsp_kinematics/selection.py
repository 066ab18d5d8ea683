"""Posture selection by the condition number of the identification Jacobian (paper section 4.2)."""

import numpy as np

from ._formulations import leg_readings_jacobians, sensor_readings_jacobians
from ._lm import schur_information
from .identification import SENSOR_NAMES, Sigmas, resolve_free


def posture_information(
    geometry, poses, sigmas=Sigmas(), free=None, formulation='implicit', sensors=SENSOR_NAMES
):
    """Per-posture information matrices (N, n, n) of the free parameters.

    For ``'implicit'`` each posture's pose is eliminated (Schur complement), which is additive over
    postures; for ``'fk'`` it is ``J_k^T J_k`` of the FK-based residuals. Both are weighted.
    """
    free = resolve_free(free)
    columns = [c for c, name in enumerate(('alpha', 'beta', 'phi', 'd_m')) if name in sensors]
    # Derivatives of the sensor readings (the sensor errors included) over the extended vector.
    _, d_q_d_pose, d_q_d_u = leg_readings_jacobians(geometry, poses)
    _, d_h_d_pose, d_h_d_u = sensor_readings_jacobians(geometry, poses)
    reading_weights = 1.0 / sigmas.readings()[columns]
    d_h_d_pose = d_h_d_pose[:, columns] * reading_weights[None, :, None]
    d_h_d_u = d_h_d_u[:, columns][:, :, free] * reading_weights[None, :, None]
    d_q_d_u = d_q_d_u[:, :, free]
    if formulation == 'implicit':
        jac_pose = np.concatenate([d_q_d_pose / sigmas.leg_lengths, d_h_d_pose], axis=1)
        jac_u = np.concatenate([d_q_d_u / sigmas.leg_lengths, d_h_d_u], axis=1)
        return schur_information(jac_pose, jac_u, per_posture=True)
    jacobian = d_h_d_u - d_h_d_pose @ np.linalg.solve(d_q_d_pose, d_q_d_u)
    return np.swapaxes(jacobian, 1, 2) @ jacobian


def scaled_condition_number(information):
    """Condition number of the column-scaled Jacobian, from its information matrix (inf if singular)."""
    scale = 1.0 / np.sqrt(np.maximum(np.diagonal(information, axis1=-2, axis2=-1), 1e-300))
    scaled = information * scale[..., :, None] * scale[..., None, :]
    eigenvalues = np.linalg.eigvalsh(scaled)
    with np.errstate(divide='ignore', invalid='ignore'):
        condition = np.sqrt(eigenvalues[..., -1] / eigenvalues[..., 0])
    return np.where(eigenvalues[..., 0] > 1e-14 * eigenvalues[..., -1], condition, np.inf)


def select_postures(
    geometry,
    pool,
    count=60,
    sigmas=Sigmas(),
    free=None,
    formulation='implicit',
    exchange_passes=1,
    shortlist=96,
):
    """Indices of ``count`` postures from ``pool`` (N, 6) minimising the condition number.

    Greedy: while the accumulated information is rank-deficient, add the posture that most
    increases log det (regularised); afterwards, the one that gives the smallest condition
    number. Then ``exchange_passes`` sweeps of a swap (exchange) algorithm keep any swap that
    lowers it. To keep this fast, each step scores the exact criterion only on a ``shortlist`` of
    candidates ranked by their first-order information gain ``tr(T^-1 I_c)`` (``None``: all).
    Returns ``(indices, condition_number)``.
    """
    pool = np.asarray(pool, dtype=float)
    if pool.shape[0] < count:
        raise ValueError(f'the pool has {pool.shape[0]} postures, fewer than the {count} requested')
    information = posture_information(geometry, pool, sigmas, free, formulation)
    # One scale for every candidate set, so conditions compare like with like.
    scale = 1.0 / np.sqrt(np.maximum(np.diagonal(information.sum(axis=0)), 1e-300)) * np.sqrt(count)
    information = information * scale[None, :, None] * scale[None, None, :]
    size = information.shape[1]
    total = np.zeros((size, size))
    chosen = []
    available = np.ones(pool.shape[0], dtype=bool)
    ridge = 1e-6 * np.eye(size)
    flat_information = information.reshape(information.shape[0], -1)

    def shortlisted(candidates, base):
        if shortlist is None or candidates.size <= shortlist:
            return candidates
        # First-order gain of each candidate (regularised while base is rank-deficient).
        inverse = np.linalg.inv(base + ridge * max(np.trace(base) / size, 1.0))
        gain = flat_information[candidates] @ inverse.ravel()
        return candidates[np.argpartition(-gain, shortlist - 1)[:shortlist]]

    for _ in range(count):
        candidates = shortlisted(np.flatnonzero(available), total)
        trial = total[None] + information[candidates]
        eigenvalues = np.linalg.eigvalsh(trial)
        if eigenvalues[0, 0] > 1e-9 * eigenvalues[0, -1] or len(chosen) * 4 >= size * 2:
            score = eigenvalues[:, -1] / np.maximum(eigenvalues[:, 0], 1e-300)
        else:
            score = -np.sum(np.log(eigenvalues + ridge[0, 0]), axis=1)
        best = candidates[int(np.argmin(score))]
        chosen.append(best)
        available[best] = False
        total += information[best]

    def condition(matrix):
        eigenvalues = np.linalg.eigvalsh(matrix)
        return np.sqrt(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0 else np.inf

    current = condition(total)
    for _ in range(exchange_passes):
        improved = False
        for position in range(count):
            outgoing = chosen[position]
            base = total - information[outgoing]
            candidates = shortlisted(np.flatnonzero(available), base)
            eigenvalues = np.linalg.eigvalsh(base[None] + information[candidates])
            conditions = np.sqrt(eigenvalues[:, -1] / np.maximum(eigenvalues[:, 0], 1e-300))
            best = int(np.argmin(conditions))
            if conditions[best] < current * (1.0 - 1e-9):
                incoming = candidates[best]
                available[incoming], available[outgoing] = False, True
                chosen[position] = incoming
                total = base + information[incoming]
                current = conditions[best]
                improved = True
        if not improved:
            break
    return np.array(chosen), float(scaled_condition_number(total))
