"""Posture selection by the condition number of the identification Jacobian (paper section 4.2)."""

import numpy as np

from ..estimation.identifiability import posture_factors, scaled_condition_number
from ..estimation.identification import DEFAULT_FORMULATION
from ..model.sensor_noise import DEFAULT_SENSOR_NOISE

#: Candidates whose condition number is scored exactly at each step of :func:`select_postures`.
SHORTLIST = 12
#: Power of 1/lambda_k weighting the gains that rank the shortlist (see select_postures).
FOCUS = 6.0


def select_postures(
    geometry,
    pool,
    count=60,
    sigmas=DEFAULT_SENSOR_NOISE,
    free=None,
    formulation=DEFAULT_FORMULATION,
    exchange_passes=1,
    shortlist=SHORTLIST,
):
    """Indices of ``count`` postures from ``pool`` (N, 6) minimising the condition number:
    ``(indices, condition_number)``. Greedy on log det, then on the condition number scored
    exactly on a ``shortlist`` of candidates (``None``: all), then ``exchange_passes`` sweeps of
    swaps (docs/core_api.md)."""
    pool = np.asarray(pool, dtype=float)
    if pool.shape[0] < count:
        raise ValueError(f'the pool has {pool.shape[0]} postures, fewer than the {count} requested')
    factors = posture_factors(geometry, pool, sigmas, free, formulation)
    # One scale for every candidate set, so conditions compare like with like.
    column_information = np.einsum('mri,mri->i', factors, factors)
    scale = np.sqrt(count) / np.sqrt(np.maximum(column_information, 1e-300))
    factors = factors * scale[None, None, :]
    chosen, available, total = _greedy(factors, count, shortlist)
    chosen, total = _exchange(factors, chosen, available, total, exchange_passes, shortlist)
    return np.array(chosen), float(scaled_condition_number(total))


def _information(factors, indices):
    """(c, n, n) information of the candidates ``indices`` (their factors' ``G^T G``)."""
    selected = factors[indices]
    return np.einsum('cri,crj->cij', selected, selected)


def _shortlisted(factors, candidates, base, shortlist):
    """The ``shortlist`` candidates of largest gain in the weak directions of ``base``."""
    if shortlist is None or candidates.size <= shortlist:
        return candidates
    pool_size, rows, size = factors.shape
    # Gain of each candidate in the weak directions of base: sum_k |G v_k|^2 / lambda_k^p,
    # p = FOCUS (p = 1 is the first-order gain tr(base^-1 I_c); a larger p aims at lambda_min).
    eigenvalues, vectors = np.linalg.eigh(base)
    weights = np.maximum(eigenvalues, 1e-12 * max(eigenvalues[-1], 1e-300)) ** (-FOCUS / 2)
    projected = (factors.reshape(-1, size) @ (vectors * weights[None, :])).reshape(
        pool_size, rows, size
    )
    gain = np.einsum('mri,mri->m', projected, projected)[candidates]
    return candidates[np.argpartition(-gain, shortlist - 1)[:shortlist]]


def _log_det_gain(factors, candidates, base):
    """log det(base + G^T G) - log det(base) of each candidate, exact (determinant lemma)."""
    rows = factors.shape[1]
    inverse = np.linalg.inv(base)
    selected = factors[candidates]
    inner = np.eye(rows)[None] + selected @ inverse @ np.swapaxes(selected, 1, 2)
    return np.linalg.slogdet(inner)[1]


def _greedy(factors, count, shortlist, ridge=1e-6):
    """The greedy start of :func:`select_postures`: ``(chosen, available mask, information)``."""
    pool_size, rows, size = factors.shape
    total = np.zeros((size, size))
    chosen = []
    available = np.ones(pool_size, dtype=bool)
    for _ in range(count):
        available_indices = np.flatnonzero(available)
        full_rank = np.linalg.eigvalsh(total)
        if full_rank[0] > 1e-9 * full_rank[-1] or len(chosen) * rows >= size * 2:
            candidates = _shortlisted(factors, available_indices, total, shortlist)
            eigenvalues = np.linalg.eigvalsh(total[None] + _information(factors, candidates))
            best = candidates[
                int(np.argmin(eigenvalues[:, -1] / np.maximum(eigenvalues[:, 0], 1e-300)))
            ]
        else:
            gain = _log_det_gain(factors, available_indices, total + ridge * np.eye(size))
            best = available_indices[int(np.argmax(gain))]
        chosen.append(best)
        available[best] = False
        total += _information(factors, [best])[0]
    return chosen, available, total


def _exchange(factors, chosen, available, total, passes, shortlist):
    """``passes`` sweeps of swaps that lower the condition number: ``(chosen, information)``."""
    eigenvalues = np.linalg.eigvalsh(total)
    current = np.sqrt(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0 else np.inf
    for _ in range(passes):
        improved = False
        for position in range(len(chosen)):
            outgoing = chosen[position]
            base = total - _information(factors, [outgoing])[0]
            candidates = _shortlisted(factors, np.flatnonzero(available), base, shortlist)
            eigenvalues = np.linalg.eigvalsh(base[None] + _information(factors, candidates))
            conditions = np.sqrt(eigenvalues[:, -1] / np.maximum(eigenvalues[:, 0], 1e-300))
            best = int(np.argmin(conditions))
            if conditions[best] < current * (1.0 - 1e-9):
                incoming = candidates[best]
                available[incoming], available[outgoing] = False, True
                chosen[position] = incoming
                total = base + _information(factors, [incoming])[0]
                current = conditions[best]
                improved = True
        if not improved:
            break
    return chosen, total


def best_addition(information, chosen, excluded=()):
    """Index of the posture (not in ``chosen`` nor ``excluded``) that adds most to the design of
    ``chosen`` (the criterion of :func:`select_postures`) from the pool's per-posture
    ``information`` (N, n, n). ValueError if none is left."""
    available = np.ones(len(information), dtype=bool)
    available[list(chosen)] = False
    available[list(excluded)] = False
    candidates = np.flatnonzero(available)
    if not candidates.size:
        raise ValueError('no posture left in the pool to add')
    total = information[list(chosen)].sum(axis=0)
    conditions = scaled_condition_number(total[None] + information[candidates])
    if np.isfinite(conditions).any():
        return int(candidates[int(np.argmin(conditions))])
    ridge = 1e-9 * max(np.trace(total), 1e-300) * np.eye(total.shape[0])
    gain = np.linalg.slogdet(total[None] + ridge + information[candidates])[1]
    return int(candidates[int(np.argmax(gain))])
