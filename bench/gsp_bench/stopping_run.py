"""The run that stops when it is good enough, on measurements given by functions (the benches'
path; the decisions are :mod:`gsp_kinematics.upkeep.stopping`, docs/upkeep.md)."""

import numpy as np

from gsp_kinematics.estimation.identification import IdentificationError, identify, resolve_free
from gsp_kinematics.estimation.verdict.cross_validation import cross_validate
from gsp_kinematics.model.motion import move_time
from gsp_kinematics.upkeep.stopping import DWELL_S, UNKNOWN, accuracy_bounds, best_addition


def _scaled(information):
    """Per-posture information (N, n, n) scaled to unit mean diagonal per parameter (log det
    gains then weigh every parameter alike, whatever its unit)."""
    scale = 1.0 / np.sqrt(np.maximum(np.einsum('mii->i', information) / len(information), 1e-300))
    return information * np.outer(scale, scale)[None], scale


def informative_order(information, legs, start_legs, limits, dwell_s=DWELL_S, ridge=1e-3):
    """An order of the postures whose every prefix is informative: greedily, the next posture is
    the one of largest gain in ``log det`` of the (scaled, ``ridge``-regularised) information per
    second of platform time (its move from the previous posture and ``dwell_s``).

    ``information`` (N, n, n): per-posture information (``selection.posture_information``);
    ``legs`` (N, 6): their leg lengths, ``start_legs`` (6,) where the platform starts."""
    scaled, _ = _scaled(np.asarray(information, dtype=float))
    total = ridge * np.eye(scaled.shape[1])
    left, order, position = list(range(len(scaled))), [], np.asarray(start_legs, dtype=float)
    while left:
        seconds = np.asarray(move_time(position, legs[left], limits), dtype=float) + dwell_s
        gains = np.linalg.slogdet(total[None] + scaled[left])[1] - np.linalg.slogdet(total)[1]
        best = left.pop(int(np.argmax(gains / seconds)))
        order.append(best)
        total = total + scaled[best]
        position = legs[best]
    return np.array(order, dtype=int)


def core_judge(nominal, pool, measured, row_sigmas, free=None, folds=10, confidence=0.95):
    """A judge for :func:`run_to_requirement` by the core alone: ``judge(indices)`` identifies the
    rows ``measured(indices) -> (legs, readings)`` and cross-validates them: ``(result or None,
    Bounds)`` (no predicted accuracy over the workspace: ``predicted_mm`` stays 0)."""
    free = resolve_free(free)

    def judge(indices):
        legs, readings = measured(indices)
        try:
            result = identify(
                nominal, legs, readings, row_sigmas, free=free, pose_guesses=pool[indices]
            )
        except IdentificationError:
            return None, UNKNOWN
        if not result.converged:
            return None, UNKNOWN
        validation = cross_validate(result, nominal, legs, readings, row_sigmas, folds=folds)
        return result, accuracy_bounds(validation.summary(), confidence, 0.0)

    return judge


def run_to_requirement(pool_legs, planned, measure, judge, information, rule, limits, start_legs):
    """The run that stops when it is good enough, on measurements given by functions (the
    benches; the calibrator's loop is ``gsp_calibrator.run.flow``). ``planned``: indices into
    the pool (``pool_legs`` (N, 6), its postures' leg lengths), in the order measured;
    ``measure(index, platform_time_s)`` measures one; ``judge(indices)`` identifies and
    cross-validates those measured so far: ``(result or None, Bounds)``; ``information(result)``
    is the pool's per-posture information (N, n, n) at ``result``'s geometry, for the additions.
    A JSON-ready dict: ``met``, ``postures``, ``added``, ``platform_time_s``,
    ``fixed_plan_time_s``, the last ``bounds``, ``history`` (postures, platform time and bounds
    per judgement), the ``indices`` measured, and the final ``result`` (not JSON)."""
    legs_path = np.vstack([np.asarray(start_legs, float)[None], pool_legs[list(planned)]])
    fixed_s = float(np.sum(move_time(legs_path[:-1], legs_path[1:], limits)))
    fixed_s += rule.dwell_s * len(planned)
    position = np.asarray(start_legs, dtype=float)
    queue, indices, steps = list(planned), [], []
    result, bounds, added, elapsed = None, UNKNOWN, 0, 0.0
    while not bounds.meets(rule):
        if queue:
            index = queue.pop(0)
        elif result is not None and added < rule.max_added:
            index = best_addition(
                result.information, information(result), pool_legs, position, indices, limits,
                rule.dwell_s,
            )  # fmt: skip
            added += 1
        else:
            break
        elapsed += float(move_time(position, pool_legs[index], limits)) + rule.dwell_s
        position = pool_legs[index]
        measure(index, elapsed)
        indices.append(int(index))
        last = not queue and (len(indices) == len(planned) or added == rule.max_added)
        if rule.due(len(indices), last):
            result, bounds = judge(list(indices))
            steps.append({'postures': len(indices), 'platform_time_s': elapsed, **bounds.record()})
    return {
        'met': bounds.meets(rule),
        'required_position_mm': rule.required_position_mm,
        'confidence': rule.confidence,
        'postures': len(indices),
        'added': added,
        'platform_time_s': elapsed,
        'fixed_plan_time_s': fixed_s,
        'fixed_plan_postures': len(planned),
        'bounds': bounds.record(),
        'history': steps,
        'indices': indices,
        'result': result,
    }
