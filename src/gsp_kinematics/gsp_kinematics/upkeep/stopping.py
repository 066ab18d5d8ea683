"""A calibration that stops when it is good enough: the decisions (pure numpy/scipy;
docs/upkeep.md)."""

import dataclasses
import math

import numpy as np
from scipy import stats

from ..estimation.identification import IdentificationError, identify, resolve_free
from ..estimation.verdict.cross_validation import cross_validate
from ..model.motion import move_time, posture_leg_lengths

#: Per posture besides its move (s): the settle allowance and 10 samples at 200 Hz.
DWELL_S = 0.55


@dataclasses.dataclass(frozen=True)
class StoppingRule:
    """When a run is good enough."""

    required_position_mm: float  #: the cross-validated mean position error to reach
    required_orientation_deg: float = math.inf  #: the cross-validated mean phi error to reach
    confidence: float = 0.95  #: one-sided, of the position bound that must meet it
    minimum_postures: int = 20  #: the first identification (51 parameters need ~13 postures)
    every: int = 2  #: postures between two cross-validations
    max_added: int = 60  #: postures added from the pool at most
    dwell_s: float = DWELL_S  #: per posture: the settle allowance and the samples (s)

    def due(self, count, last=False):
        """Whether the rows of ``count`` postures are judged (``last``: no posture follows)."""
        if count < self.minimum_postures:
            return False
        return last or (count - self.minimum_postures) % self.every == 0


@dataclasses.dataclass(frozen=True)
class Bounds:
    """The cross-validated accuracy of a run so far: means and the position's upper bound."""

    position_mm: float  #: mean position error (noise removed), mm
    position_bound_mm: float  #: its upper one-sided ``confidence`` bound, mm
    orientation_deg: float  #: mean phi error (noise removed), deg
    #: the predicted mean position error over the workspace (covariance and unmodelled error),
    #: mm: the postures so far must identify the model where the run did not go (the verdict's
    #: condition); 0 when not predicted
    predicted_mm: float = 0.0

    def meets(self, rule):
        """The position bound, the predicted position error over the workspace and the phi
        mean meet ``rule``'s requirement."""
        return bool(
            self.position_bound_mm <= rule.required_position_mm
            and self.predicted_mm <= rule.required_position_mm
            and self.orientation_deg <= rule.required_orientation_deg
        )

    def record(self):
        return dataclasses.asdict(self)


#: Bounds of a run that could not be identified or cross-validated yet.
UNKNOWN = Bounds(math.nan, math.inf, math.nan, math.inf)


def _mean_and_bound(figures, magnitudes, z):
    """``(mean, mean + z standard errors)`` (mm) of one set of held-out postures: ``figures``
    (``calibrated`` of a ``CrossValidation.summary``), ``magnitudes`` their per-posture position
    errors (mm); the spread is scaled by the noise factor, as the mean is."""
    position = figures['position_mm']
    magnitudes = magnitudes[np.isfinite(magnitudes)]
    if magnitudes.size < 2 or not math.isfinite(position['mean']):
        return math.nan, math.inf
    spread = position['noise_factor'] * np.std(magnitudes, ddof=1) / math.sqrt(magnitudes.size)
    return float(position['mean']), float(position['mean'] + z * spread)


def accuracy_bounds(summary, confidence, predicted_mm):
    """:class:`Bounds` from a cross-validation's ``summary()`` (``CrossValidation.summary``) and
    the ``predicted_mm`` mean position error over the workspace (None: inf): the position bound
    is the mean plus ``z(confidence)`` standard errors of the mean over the predicted postures.

    With workspace postures (``workspace_rows``) the figures are the verdict's judged accuracy
    (``acceptance.judged_accuracy``): the larger of the workspace and the selected postures'
    means and bounds, each over its own rows, so a run never stops on a figure the verdict then
    rejects (the workspace postures miss the error the device shares with the legs)."""
    z = float(stats.norm.ppf(confidence))
    magnitudes = np.asarray(summary['per_posture']['position_mm'], dtype=float)
    workspace = np.zeros(magnitudes.size, bool)
    workspace[list(summary.get('workspace_rows') or [])] = True
    headline = workspace if workspace.any() else np.ones(magnitudes.size, bool)
    position, bound = _mean_and_bound(summary['calibrated'], magnitudes[headline], z)
    phi = summary['calibrated']['phi_deg']['mean']
    selected = (summary.get('selected') or {}).get('calibrated')
    if workspace.any() and selected:
        others = _mean_and_bound(selected, magnitudes[~workspace], z)
        position, bound = max(position, others[0]), max(bound, others[1])
        phi = max(phi, selected['phi_deg']['mean'])
    if not math.isfinite(position):
        return UNKNOWN
    predicted = math.inf if predicted_mm is None else float(predicted_mm)
    return Bounds(position, bound, float(phi), predicted)


def plan_time_s(geometry, start_pose, poses, limits, dwell_s=DWELL_S):
    """Platform time (s) of commanding ``poses`` (N, 6) in order from ``start_pose``: each move
    at the leg ``limits`` and a dwell per posture."""
    legs = posture_leg_lengths(geometry, np.vstack([np.asarray(start_pose, float)[None], poses]))
    return float(np.sum(move_time(legs[:-1], legs[1:], limits))) + dwell_s * len(poses)


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


def best_addition(information, pool_information, pool_legs, position_legs, used, limits, dwell_s):
    """The pool posture (index) of largest gain in ``log det`` of ``information`` (n, n: the run's
    so far) per second of platform time from ``position_legs`` (6,); ``pool_information``
    (N, n, n) and ``pool_legs`` (N, 6) of the pool, ``used``: indices already measured.
    ValueError when none is left."""
    seconds = np.asarray(move_time(position_legs, pool_legs, limits), dtype=float) + dwell_s
    available = np.isfinite(seconds)
    available[list(used)] = False
    if not available.any():
        raise ValueError('no posture left in the pool to add')
    base = np.asarray(information, dtype=float)
    base = base + 1e-12 * max(np.trace(base), 1e-300) * np.eye(len(base))
    gains = np.linalg.slogdet(base[None] + pool_information)[1] - np.linalg.slogdet(base)[1]
    score = np.where(available, gains / np.where(available, seconds, 1.0), -np.inf)
    return int(np.argmax(score))


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
