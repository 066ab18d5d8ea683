"""A calibration that stops when it is good enough (``stop_when_accurate``, docs/upkeep.md;
pure): the decisions are :mod:`gsp_kinematics.upkeep.stopping`'s, the loop ``run.flow``'s."""

import concurrent.futures
import dataclasses
import math
import time

import numpy as np

from gsp_calibrator.run import reused_rows
from gsp_calibrator.run.identify import identify_with_settings, workspace_rows
from gsp_calibrator.run.postures import posture_pool, route_start, selection_formulation
from gsp_kinematics.estimation.identifiability import posture_information
from gsp_kinematics.estimation.identification import resolve_free
from gsp_kinematics.estimation.prediction import accuracy_summary
from gsp_kinematics.model.motion import DEFAULT_SENSOR_RATE_HZ, posture_leg_lengths
from gsp_kinematics.upkeep import stopping


def rule_for(settings):
    """The ``StoppingRule`` of a run's settings; the dwell: ``pairs_per_posture`` at the default
    sensor rate and a 0.5 s settle allowance."""
    return stopping.StoppingRule(
        required_position_mm=settings.required_position_accuracy_mm,
        required_orientation_deg=settings.required_orientation_accuracy_deg,
        confidence=settings.stop_confidence,
        minimum_postures=settings.stop_minimum_postures,
        every=settings.stop_every,
        max_added=settings.stop_max_added,
        dwell_s=0.5 + settings.pairs_per_posture / DEFAULT_SENSOR_RATE_HZ,
    )


@dataclasses.dataclass(frozen=True)
class Judgement:
    """The rows of ``postures`` postures, identified and cross-validated."""

    postures: int
    bounds: stopping.Bounds
    result: object  #: the core's IdentificationResult, None when it failed
    duration_s: float  #: wall time of the judgement

    def record(self):
        return {
            'postures': self.postures,
            **self.bounds.record(),
            'duration_s': self.duration_s,
        }


def judge_rows(settings, samples, rule):
    """Identify the rows so far as the calibrator does and bound its cross-validated accuracy
    (:class:`Judgement`; a worker thread)."""
    started = time.perf_counter()
    outcome = identify_with_settings(settings, samples)
    if not outcome.success or outcome.accuracy is None:
        return Judgement(len(samples), stopping.UNKNOWN, None, time.perf_counter() - started)
    predicted = None
    if outcome.prediction is not None:
        predicted = accuracy_summary(outcome.prediction)['position_mm_mean']
    bounds = stopping.accuracy_bounds(outcome.accuracy, rule.confidence, predicted)
    return Judgement(len(samples), bounds, outcome.result, time.perf_counter() - started)


class PoolAdditions:
    """The calibrator's posture pool, for the postures a run adds when its plan is not enough
    (the largest information gain per second: ``stopping.best_addition``)."""

    def __init__(self, settings):
        self.settings = settings
        self.pool = posture_pool(settings.nominal, settings.pool_size, settings.seed)
        self.legs = posture_leg_lengths(settings.nominal, self.pool)

    def next_pose(self, judgement, poses, latest_legs, rule):
        """The pose (6,) to add after ``judgement``, the run's ``poses`` so far and the
        platform's ``latest_legs`` (6,); None when the pool has none left or nothing was fit."""
        if judgement.result is None:
            return None
        settings = self.settings
        information = posture_information(
            judgement.result.geometry,
            self.pool,
            settings.sigmas.averaged([settings.pairs_per_posture]),
            resolve_free(list(settings.free_parameters)),
            selection_formulation(settings.formulation),
        )
        used = np.flatnonzero(workspace_rows(self.pool, poses))  # the pool postures commanded
        try:
            index = stopping.best_addition(
                judgement.result.information,
                information,
                self.legs,
                latest_legs,
                used,
                self.settings.motion_limits,
                rule.dwell_s,
            )
        except ValueError:
            return None
        return self.pool[index].copy()


def platform_time_s(settings, start_pose, poses, rule):
    """Platform time (s) of ``poses`` in order from ``start_pose``, with the rule's dwell."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 6)
    if not len(poses):
        return 0.0
    return stopping.plan_time_s(
        settings.nominal, start_pose, poses, settings.motion_limits, rule.dwell_s
    )


def judgement_line(judgement, rule):
    """One log line of a judgement of the rows so far."""
    bounds = judgement.bounds
    verdict = 'meets' if bounds.meets(rule) else 'does not meet'
    return (
        f'{judgement.postures} postures judged in {judgement.duration_s:.2f} s: cross-validated '
        f'position {bounds.position_mm:.4g} mm ({rule.confidence:.0%} bound '
        f'{bounds.position_bound_mm:.4g} mm), predicted {bounds.predicted_mm:.4g} mm, phi '
        f'{bounds.orientation_deg:.4g} deg: {verdict} the required {rule.required_position_mm:g} '
        f'mm, {rule.required_orientation_deg:g} deg'
    )


def summary_line(record):
    """One line of the run's summary and response: stopped or not, time spent and the plan's."""
    spent, fixed = record['platform_time_s'], record['fixed_plan_time_s']
    ratio = spent / fixed if fixed > 0 else math.nan
    bounds = record['bounds']
    head = (
        f'stopped when accurate: {record["postures"]} postures'
        if record['met']
        else f'could not meet the required accuracy in {record["postures"]} postures '
        f'({record["added"]} added from the pool)'
    )
    return (
        f'{head}; platform time {spent:.1f} s, the fixed plan {fixed:.1f} s '
        f'({record["fixed_plan_postures"]} postures; {ratio:.2f}x); cross-validated position '
        f'{bounds["position_mm"]:.4g} mm, {record["confidence"]:.0%} bound '
        f'{bounds["position_bound_mm"]:.4g} mm, predicted {bounds["predicted_mm"]:.4g} mm '
        f'(required {record["required_position_mm"]:g} mm)'
    )


@dataclasses.dataclass
class StoppingState:
    """Where a run that stops when it is good enough stands (held by the run loop)."""

    settings: object  #: the run's ``CalibratorSettings``
    run_record: object  #: the run's ``record.RunRecord``
    rule: stopping.StoppingRule
    start_pose: np.ndarray  #: (6,) where the platform stood before the first posture
    plan: list  #: the fixed plan's poses (M, 6), in order
    worker: concurrent.futures.ThreadPoolExecutor  #: the judgements' thread, one at a time
    in_flight: concurrent.futures.Future | None = None  #: the judgement under way
    latest: Judgement | None = None  #: the newest finished judgement
    history: list = dataclasses.field(default_factory=list)  #: ``Judgement.record`` of each
    additions: PoolAdditions | None = None  #: the pool, once the plan was not enough
    added: int = 0  #: postures added from the pool
    reused: object = None  #: another run's rows judged with its own (``reused_rows.ReusedRows``)

    @classmethod
    def start(cls, settings, run_record, latest_legs, reused=None):
        """Before the first posture of a run; None unless ``settings.stop_when_accurate``."""
        if not settings.stop_when_accurate:
            return None
        plan = [run_record.state.poses[k - 1] for k in run_record.remaining]
        start, unknown = route_start(settings.nominal, latest_legs)
        if unknown and plan:  # the times are then counted from the first posture
            start = np.asarray(plan[0], dtype=float)
        worker = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix='stop_judge')
        return cls(settings, run_record, rule_for(settings), start, plan, worker, reused=reused)

    def judge_if_due(self, last=False):
        """Start judging the rows so far and the reused ones (numbered after the run's postures)
        in the worker thread when due: none under way, rows not yet judged, and due by the rule
        (``last``: the plan has ended); whether it started."""
        run_record, rows = self.run_record, len(self.run_record.samples)
        judged = self.latest.postures if self.latest is not None else 0
        if self.in_flight is not None or rows <= judged or not self.rule.due(rows, last):
            return False
        first = len(run_record.state.poses) + 1
        together = reused_rows.joined(run_record.rows_so_far(), self.reused, first)
        self.in_flight = self.worker.submit(judge_rows, self.settings, together, self.rule)
        return True

    def finished(self):
        """The in-flight judgement if it has finished (then noted), else None."""
        if self.in_flight is None or not self.in_flight.done():
            return None
        return self.note(self.in_flight.result())

    def note(self, judgement):
        """Keep ``judgement`` (the in-flight one's result) as the latest."""
        self.in_flight, self.latest = None, judgement
        self.history.append(judgement.record())
        return judgement

    def may_add(self):
        """Whether a pool posture may be added: not met, under ``max_added``, and judged."""
        return not self.met and self.added < self.rule.max_added and self.latest is not None

    def next_pose(self, latest_legs):
        """The pool pose to add, counted as added (worker thread); None when none is left."""
        if self.additions is None:
            self.additions = PoolAdditions(self.settings)
        poses = self.run_record.state.poses
        pose = self.additions.next_pose(self.latest, poses, latest_legs, self.rule)
        self.added += pose is not None
        return pose

    @property
    def met(self):
        return self.latest is not None and self.latest.bounds.meets(self.rule)

    def close(self):
        self.worker.shutdown(wait=False, cancel_futures=True)

    def record(self):
        """``result.json`` ``collection.run_to_requirement``: met or not, the platform time
        spent and the fixed plan's, the latest bounds and the judgements."""
        rule, poses = self.rule, self.run_record.state.poses
        commanded_poses = poses[: len(poses) - len(self.run_record.remaining)]
        spent = platform_time_s(self.settings, self.start_pose, commanded_poses, rule)
        fixed = platform_time_s(self.settings, self.start_pose, self.plan, rule)
        bounds = (self.latest.bounds if self.latest is not None else stopping.UNKNOWN).record()
        return {
            'met': self.met,
            'required_position_mm': rule.required_position_mm,
            'required_orientation_deg': rule.required_orientation_deg,
            'confidence': rule.confidence,
            'postures': len(commanded_poses),
            'added': self.added,
            'platform_time_s': spent,
            'fixed_plan_time_s': fixed,
            'fixed_plan_postures': len(self.plan),
            'bounds': bounds,
            'judgements': self.history,
        }
