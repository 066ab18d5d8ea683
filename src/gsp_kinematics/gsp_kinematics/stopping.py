"""A calibration that stops when it is good enough (pure numpy/scipy; docs/upkeep.md).

With a required accuracy, the postures are measured in route order and identified as they come
(an identification costs milliseconds). Every ``every`` postures from ``minimum_postures`` on,
the run is cross-validated (:func:`gsp_kinematics.cross_validation.cross_validate`, the verdict's
measured accuracy); it stops as soon as the upper ``confidence`` bound of the cross-validated
mean position error (noise removed; mean plus ``z`` standard errors over the postures) meets
the requirement. If the planned postures are not enough, postures are added from the pool, each
the one with the largest gain in ``log det`` of the information on the free parameters per second
of platform time (its move from the previous posture and its dwell). The result gives the
platform time spent, and what the fixed plan would have spent.
"""

import dataclasses
import math

import numpy as np
from scipy import stats

from .cross_validation import cross_validate
from .identification import IdentificationError, identify, resolve_free
from .selection import posture_information
from .travel.motion import move_time, posture_leg_lengths


@dataclasses.dataclass(frozen=True)
class StoppingRule:
    """When a run is good enough."""

    required_position_mm: float  #: the cross-validated mean position error to reach
    confidence: float = 0.95  #: one-sided, of the bound that must meet it
    minimum_postures: int = 20  #: the first identification (51 parameters need ~13 postures)
    every: int = 2  #: postures between two cross-validations
    max_added: int = 60  #: postures added from the pool at most
    dwell_s: float = 0.55  #: per posture: the settle allowance and the samples (s)


def accuracy_bound(validation, confidence):
    """``(mean, bound)`` in mm: the cross-validated mean position error (noise removed) and its
    upper one-sided ``confidence`` bound (``z`` standard errors of the mean over the postures)."""
    summary = validation.summary()['calibrated']['position_mm']
    magnitudes = 1e3 * np.linalg.norm(validation.position_error, axis=1)
    magnitudes = magnitudes[np.isfinite(magnitudes)]
    if magnitudes.size < 2 or not math.isfinite(summary['mean']):
        return math.nan, math.inf
    spread = summary['noise_factor'] * np.std(magnitudes, ddof=1) / math.sqrt(magnitudes.size)
    return summary['mean'], summary['mean'] + float(stats.norm.ppf(confidence)) * spread


class _Measurements:
    """The postures measured so far, their pool indices, the platform time and where it is."""

    def __init__(self, controller, pool, start_pose, limits, dwell_s):
        self.legs_at = posture_leg_lengths(controller, pool)
        self.position = posture_leg_lengths(controller, np.asarray(start_pose)[None])[0]
        self.limits, self.dwell_s = limits, dwell_s
        self.indices, self.legs, self.readings = [], [], []
        self.platform_time_s = 0.0

    def moves(self):
        return np.asarray(move_time(self.position, self.legs_at, self.limits), dtype=float)

    def add(self, index, measure):
        legs, readings = measure(index)
        self.platform_time_s += float(self.moves()[index]) + self.dwell_s
        self.position = self.legs_at[index]
        self.indices.append(int(index))
        self.legs.append(legs)
        self.readings.append(readings)


def _judge(nominal, measured, pool, row_sigmas, free, folds, confidence):
    """Identify the postures so far and cross-validate: ``(result, mean_mm, bound_mm)``."""
    legs, readings = np.array(measured.legs), np.array(measured.readings)
    guesses = pool[measured.indices]
    try:
        result = identify(nominal, legs, readings, row_sigmas, free=free, pose_guesses=guesses)
    except IdentificationError:
        return None, math.nan, math.inf
    if not result.converged:
        return None, math.nan, math.inf
    validation = cross_validate(result, nominal, legs, readings, row_sigmas, folds=folds)
    mean, bound = accuracy_bound(validation, confidence)
    return result, mean, bound


def _best_addition(result, pool, measured, row_sigmas, free):
    """The pool posture of largest log-det gain per second from where the platform is."""
    information = posture_information(result.geometry, pool, row_sigmas, free)
    base = result.information
    gains = np.linalg.slogdet(base[None] + information)[1] - np.linalg.slogdet(base)[1]
    seconds = measured.moves() + measured.dwell_s
    score = gains / seconds
    score[measured.indices] = -np.inf
    return int(np.argmax(score))


def run_to_requirement(
    nominal,
    pool,
    planned,
    measure,
    row_sigmas,
    rule,
    limits,
    start_pose,
    free=None,
    folds=10,
):
    """Measure ``planned`` (indices into ``pool`` (N, 6), in route order) one by one with
    ``measure(index) -> (legs (6,), readings (4,))`` until ``rule`` (:class:`StoppingRule`) is
    met, adding pool postures if needed. A JSON-ready dict: ``met``, ``postures``,
    ``added``, ``platform_time_s``, ``fixed_plan_time_s``, ``cross_validated_mm`` and its
    ``bound_mm``, ``history`` (postures, platform time, mean, bound per cross-validation), and
    the final ``result`` (an IdentificationResult; not JSON)."""
    pool = np.atleast_2d(np.asarray(pool, dtype=float))
    free = resolve_free(free)
    measured = _Measurements(nominal, pool, start_pose, limits, rule.dwell_s)
    route = np.vstack([measured.position, measured.legs_at[list(planned)]])
    fixed_s = float(np.sum(move_time(route[:-1], route[1:], limits))) + rule.dwell_s * len(planned)
    steps, result, mean, bound = [], None, math.nan, math.inf
    queue, added = list(planned), 0
    while bound > rule.required_position_mm:
        if queue:
            measured.add(queue.pop(0), measure)
        elif result is not None and added < rule.max_added:
            measured.add(_best_addition(result, pool, measured, row_sigmas, free), measure)
            added += 1
        else:
            break
        count = len(measured.indices)
        last = not queue and (count == len(planned) or added == rule.max_added)
        if count < rule.minimum_postures:
            continue
        if (count - rule.minimum_postures) % rule.every == 0 or last:
            result, mean, bound = _judge(
                nominal, measured, pool, row_sigmas, free, folds, rule.confidence
            )
            steps.append(
                {
                    'postures': count,
                    'platform_time_s': measured.platform_time_s,
                    'mean_mm': mean,
                    'bound_mm': bound,
                }
            )
    return {
        'met': bool(bound <= rule.required_position_mm),
        'required_position_mm': rule.required_position_mm,
        'confidence': rule.confidence,
        'postures': len(measured.indices),
        'added': added,
        'platform_time_s': measured.platform_time_s,
        'fixed_plan_time_s': fixed_s,
        'fixed_plan_postures': len(planned),
        'cross_validated_mm': mean,
        'bound_mm': bound,
        'history': steps,
        'result': result,
    }
