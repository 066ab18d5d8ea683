"""A calibration that stops when it is good enough: the decisions (pure numpy/scipy;
docs/upkeep.md)."""

import dataclasses
import math

import numpy as np
from scipy import stats

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
    """:class:`Bounds` from a cross-validation's ``summary()`` and the ``predicted_mm`` mean
    position error over the workspace (None: inf): the position bound is the mean plus
    ``z(confidence)`` standard errors; with workspace postures, the larger of theirs and the
    selected postures' (docs/upkeep.md)."""
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
