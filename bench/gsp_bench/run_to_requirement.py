"""The ``run_to_requirement`` section of ``make bench`` (docs/upkeep.md): a calibration that stops
when it is good enough, against the default plan, on the realistic platform of
docs/platform_effects.md (all four effects) at realistic leg speeds (50 mm/s, 0.2 m/s^2).

Per seed: the default plan (``bench_verdict``: 60 postures in route order over 15 min of
warming, identified as the calibrator does) gives its verified accuracy, the cross-validated
mean position error. The requirement is the median of it over the seeds. Then a run measures the
same plan's postures in route order and is judged as the calibrator judges it
(``upkeep.run_to_requirement.judge_rows``: the calibrator's identification, cross-validation and
predicted accuracy) every ``EVERY`` postures from ``MINIMUM``; it stops when the 95 % bound meets
the requirement, else adds pool postures by information per second (at most ``MAX_ADDED``, a cap
of the bench: the calibrator's default is 60). Each posture is simulated on the real platform at
its platform time (scaled so the plan spans the default run's 15 min of warming), after the
previous one (backlash), with the default noise. Also given, from the same judgements: where the
run would stop with the default plan's own 95 % bound as the requirement; at half the plan's
platform time (the target's budget), the run's last judgement (its cross-validated mean, bound and
true error); and what more pairs per posture buy (``DWELL_SAMPLES``): the plan, and its first
half, measured with them.
"""

import dataclasses
import math
import statistics

import numpy as np

import gsp_bench.verdict
from gsp_bench import stopping_run
from gsp_calibrator.files.run_directory import Rows
from gsp_calibrator.run import postures, run_to_requirement
from gsp_calibrator.run.identify import identify_with_settings
from gsp_kinematics.estimation.identifiability import posture_information
from gsp_kinematics.estimation.identification import resolve_free
from gsp_kinematics.estimation.noise_from_data import posture_lag_sums
from gsp_kinematics.estimation.prediction import accuracy_summary
from gsp_kinematics.model.effects import REALISTIC
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.motion import move_time, posture_leg_lengths
from gsp_kinematics.model.validation import simulate_commands
from gsp_kinematics.upkeep import stopping

SEEDS = 20
QUICK_SEEDS = 1
MINIMUM = 30  #: postures of the first judgement (the calibrator's default)
EVERY = 4  #: postures between judgements
MAX_ADDED = 24  #: pool postures added at most (the bench's cap)
#: Pairs per posture of the dwell comparison (4x the default: half the noise's std)
DWELL_SAMPLES = 40


@dataclasses.dataclass(frozen=True)
class Plan:
    """The calibrator's pool, the default plan's pool indices in route order, the settings."""

    settings: object
    pool: np.ndarray
    legs: np.ndarray  #: (N, 6) of the pool under the nominal geometry
    planned: list
    start_legs: np.ndarray

    @classmethod
    def default(cls):
        settings = gsp_bench.verdict.default_design().settings
        nominal = settings.nominal
        selection = postures.choose_postures(
            nominal, settings.posture_count, settings.pool_size, seed=settings.seed
        )
        route = postures.posture_route(settings, selection.poses, home_pose())
        pool = postures.posture_pool(nominal, settings.pool_size, settings.seed)
        return cls(
            settings,
            pool,
            posture_leg_lengths(nominal, pool),
            [int(i) for i in np.asarray(selection.pool_indices)[route.order]],
            posture_leg_lengths(nominal, home_pose()[None])[0],
        )


class SimulatedRun:
    """One seed's measurements, posture by posture, on the realistic platform."""

    def __init__(self, design, plan, seed, time_scale, samples=gsp_bench.verdict.SAMPLES):
        self.design, self.plan, self.time_scale = design, plan, time_scale
        self.pairs_per_posture = samples
        self.rng = np.random.default_rng(seed)
        self.samples = Rows.empty()
        self.previous = None
        self.geometries = {}  #: postures -> the judged geometry (for the truth)

    def measure(self, index, elapsed_s):
        settings, nominal = self.plan.settings, self.plan.settings.nominal
        pose = self.plan.pool[index]
        run = simulate_commands(
            self.design.true,
            nominal,
            pose[None],
            REALISTIC,
            [elapsed_s * self.time_scale],
            previous_readings=self.previous,
        )
        self.previous = run.leg_readings[0]
        if not run.reachable[0]:
            return
        noise = settings.sigmas
        scale = np.concatenate([np.full(6, noise.leg_lengths), noise.readings()])
        exact = np.concatenate([run.leg_readings[0], run.device_readings[0]])
        count = self.pairs_per_posture
        window = exact + self.rng.normal(size=(count, 10)) * scale
        mean = window.mean(axis=0)
        k = len(self.samples) + 1
        self.samples.append(k, pose, mean[:6], mean[6:], count, 1.7e9 + k, posture_lag_sums(window))

    def judge(self, settings, rule):
        def judged(indices):
            judgement = run_to_requirement.judge_rows(settings, self.samples, rule)
            if judgement.result is not None:
                self.geometries[len(indices)] = judgement.result.geometry
            return judgement.result, judgement.bounds

        return judged


def default_plan(design, seed):
    """The default plan's verified (cross-validated), bound and true accuracy (mm)."""
    outcome = identify_with_settings(
        design.settings, gsp_bench.verdict.simulated_samples(design, REALISTIC, seed)
    )
    if not outcome.success:
        return None
    predicted = accuracy_summary(outcome.prediction)['position_mm_mean']
    bounds = stopping.accuracy_bounds(outcome.accuracy, 0.95, predicted)
    true_mm, _ = gsp_bench.verdict.true_accuracy(design, REALISTIC, outcome.geometry)
    return {'cv_mm': bounds.position_mm, 'bound_mm': bounds.position_bound_mm, 'true_mm': true_mm}


def _first_meeting(history, required_mm, required_deg):
    for step in history:
        bounds = stopping.Bounds(
            step['position_mm'],
            step['position_bound_mm'],
            step['orientation_deg'],
            step['predicted_mm'],
        )
        rule = stopping.StoppingRule(required_mm, required_deg)
        if bounds.meets(rule):
            return step
    return None


def _seed(design, plan, seed, required_mm, looser_mm):
    settings = dataclasses.replace(plan.settings, required_position_accuracy_mm=required_mm)
    rule = dataclasses.replace(
        run_to_requirement.rule_for(settings),
        minimum_postures=MINIMUM,
        every=EVERY,
        max_added=MAX_ADDED,
    )
    fixed_s = stopping.plan_time_s(
        settings.nominal, home_pose(), plan.pool[plan.planned], settings.motion_limits, rule.dwell_s
    )
    simulated = SimulatedRun(design, plan, 70_000 + seed, gsp_bench.verdict.RUN_S / fixed_s)
    rows = settings.sigmas.averaged([gsp_bench.verdict.SAMPLES])
    free = resolve_free(list(settings.free_parameters))
    found = stopping_run.run_to_requirement(
        plan.legs,
        plan.planned,
        simulated.measure,
        simulated.judge(settings, rule),
        lambda result: posture_information(result.geometry, plan.pool, rows, free),
        rule,
        settings.motion_limits,
        plan.start_legs,
    )
    final = simulated.geometries.get(found['postures'])
    true_mm = math.nan
    if final is not None:
        true_mm, _ = gsp_bench.verdict.true_accuracy(design, REALISTIC, final)
    looser = _first_meeting(found['history'], looser_mm, rule.required_orientation_deg)
    looser_true = math.nan
    if looser is not None and looser['postures'] in simulated.geometries:
        geometry = simulated.geometries[looser['postures']]
        looser_true, _ = gsp_bench.verdict.true_accuracy(design, REALISTIC, geometry)
    half = _at_half_time(design, found['history'], simulated.geometries, fixed_s, required_mm)
    return {
        'half': half,
        'met': found['met'],
        'cv_meets': found['bounds']['position_mm'] <= required_mm,
        'ratio': found['platform_time_s'] / found['fixed_plan_time_s'],
        'postures': found['postures'],
        'added': found['added'],
        'true_mm': true_mm,
        'fixed_plan_time_s': found['fixed_plan_time_s'],
        'looser_met': looser is not None,
        'looser_ratio': (looser['platform_time_s'] / found['fixed_plan_time_s'])
        if looser is not None
        else math.nan,
        'looser_postures': looser['postures'] if looser is not None else math.nan,
        'looser_true_mm': looser_true,
        'history': [(step['postures'], step['position_bound_mm']) for step in found['history']],
    }


def _at_half_time(design, history, geometries, fixed_s, required_mm):
    """The run's last judgement within half the plan's platform time: its cross-validated mean,
    95 % bound and predicted error, whether each meets ``required_mm``, and the true error."""
    within = [step for step in history if step['platform_time_s'] <= 0.5 * fixed_s]
    if not within:
        return None
    step = within[-1]
    true_mm = math.nan
    if step['postures'] in geometries:
        true_mm, _ = gsp_bench.verdict.true_accuracy(
            design, REALISTIC, geometries[step['postures']]
        )
    return {
        'postures': step['postures'],
        'cv_mm': step['position_mm'],
        'bound_mm': step['position_bound_mm'],
        'predicted_mm': step['predicted_mm'],
        'true_mm': true_mm,
        'cv_meets': step['position_mm'] <= required_mm,
        'bound_meets': step['position_bound_mm'] <= required_mm,
    }


def _prefix(design, plan, seed, order, samples, budget=math.inf):
    """The postures ``order`` (pool indices) measured in that order with ``samples`` per
    posture, as many as fit in ``budget`` times the plan's platform time (10 samples), judged
    once: its postures, cross-validated mean, bound and true error (mm) and its platform time /
    the plan's."""
    settings = plan.settings
    rule = run_to_requirement.rule_for(settings)
    limits, home = settings.motion_limits, home_pose()
    fixed_s = stopping.plan_time_s(
        settings.nominal, home, plan.pool[plan.planned], limits, rule.dwell_s
    )
    dwell_s = 0.5 + samples / 200.0
    simulated = SimulatedRun(
        design, plan, 70_000 + seed, gsp_bench.verdict.RUN_S / fixed_s, samples
    )
    position, elapsed = plan.start_legs, 0.0
    for index in order:
        step = float(move_time(position, plan.legs[index], limits)) + dwell_s
        if elapsed + step > budget * fixed_s:
            break
        elapsed += step
        position = plan.legs[index]
        simulated.measure(index, elapsed)
    judgement = run_to_requirement.judge_rows(settings, simulated.samples, rule)
    true_mm = math.nan
    if judgement.result is not None:
        true_mm, _ = gsp_bench.verdict.true_accuracy(design, REALISTIC, judgement.result.geometry)
    return {
        'postures': len(simulated.samples),
        'cv_mm': judgement.bounds.position_mm,
        'bound_mm': judgement.bounds.position_bound_mm,
        'true_mm': true_mm,
        'ratio': elapsed / fixed_s,
    }


def informative_plan(plan):
    """The plan's postures in :func:`gsp_bench.stopping_run.informative_order` (information
    per second at the nominal geometry, from the start pose)."""
    settings = plan.settings
    rows = settings.sigmas.averaged([gsp_bench.verdict.SAMPLES])
    free = resolve_free(list(settings.free_parameters))
    information = posture_information(settings.nominal, plan.pool[plan.planned], rows, free)
    order = stopping_run.informative_order(
        information,
        plan.legs[plan.planned],
        plan.start_legs,
        settings.motion_limits,
        run_to_requirement.rule_for(settings).dwell_s,
    )
    return [plan.planned[i] for i in order]


def _prefix_figures(design, plan, seeds):
    """Medians over ``seeds`` of :func:`_prefix`: the route's first half and whole with 10 and
    ``DWELL_SAMPLES`` pairs per posture, and the plan in informative order within 0.5x and
    1x the plan's platform time."""
    half = len(plan.planned) // 2
    cases = {
        f'route_{count}_postures_{samples}_samples': (plan.planned[:count], samples, math.inf)
        for count in (half, len(plan.planned))
        for samples in (gsp_bench.verdict.SAMPLES, DWELL_SAMPLES)
    }
    informative = informative_plan(plan)
    for budget in (0.5, 1.0):
        cases[f'informative_order_within_{budget}x'] = (
            informative,
            gsp_bench.verdict.SAMPLES,
            budget,
        )
    figures = {}
    for name, (order, samples, budget) in cases.items():
        runs = [_prefix(design, plan, seed, order, samples, budget) for seed in seeds]
        figures[name] = {f'{key}_median': _median([run[key] for run in runs]) for key in runs[0]}
    return figures


def _half_figures(runs, required_mm):
    halves = [run['half'] for run in runs if run['half'] is not None]
    return {
        'required_position_mm': required_mm,
        'seeds': len(halves),
        'postures_median': _median([half['postures'] for half in halves]),
        'cross_validated_mm_median': _median([half['cv_mm'] for half in halves]),
        'bound_95_mm_median': _median([half['bound_mm'] for half in halves]),
        'predicted_mm_median': _median([half['predicted_mm'] for half in halves]),
        'true_mm_median': _median([half['true_mm'] for half in halves]),
        'cross_validated_meets_fraction': _fraction(halves, 'cv_meets'),
        'bound_meets_fraction': _fraction(halves, 'bound_meets'),
    }


def _median(values):
    values = [v for v in values if math.isfinite(v)]
    return statistics.median(values) if values else math.nan


def _max(values):
    values = [v for v in values if math.isfinite(v)]
    return max(values) if values else math.nan


def _fraction(runs, key):
    return sum(bool(run[key]) for run in runs) / max(len(runs), 1)


def run(quick=False):
    """The section: the requirement, then per seed the run's platform time against the plan's,
    and whether its cross-validated accuracy meets the requirement."""
    design = gsp_bench.verdict.default_design()
    plan = Plan.default()
    seeds = range(QUICK_SEEDS if quick else SEEDS)
    defaults = [found for found in (default_plan(design, s) for s in seeds) if found]
    required = _median([found['cv_mm'] for found in defaults])
    looser = _median([found['bound_mm'] for found in defaults])
    runs = [_seed(design, plan, seed, required, looser) for seed in seeds]
    return {
        'description': (
            'realistic platform (all four effects), realistic leg speed; the default plan (60 '
            'postures in route order) against a run of the same route judged by the calibrator '
            f'every {EVERY} postures from {MINIMUM}, stopping when the 95 % bound of the '
            'cross-validated mean position error and the predicted error meet the requirement, '
            f'else adding at most {MAX_ADDED} pool postures by information per second'
        ),
        'seeds': len(runs),
        'default_plan': {
            'verified_cv_mm_median': required,
            'bound_95_mm_median': looser,
            'true_mm_median': _median([found['true_mm'] for found in defaults]),
        },
        'at_verified_accuracy': {
            'required_position_mm': required,
            'time_ratio_median': _median([r['ratio'] for r in runs]),
            'time_ratio_max': _max([r['ratio'] for r in runs]),
            'bound_met_fraction': _fraction(runs, 'met'),
            'cross_validated_meets_fraction': _fraction(runs, 'cv_meets'),
            'postures_median': _median([r['postures'] for r in runs]),
            'added_median': _median([r['added'] for r in runs]),
            'true_mm_median': _median([r['true_mm'] for r in runs]),
            'fixed_plan_time_s': runs[0]['fixed_plan_time_s'],
        },
        'at_the_plans_95_bound': {
            'required_position_mm': looser,
            'met_fraction': _fraction(runs, 'looser_met'),
            'time_ratio_median': _median([r['looser_ratio'] for r in runs]),
            'time_ratio_max': _max([r['looser_ratio'] for r in runs]),
            'postures_median': _median([r['looser_postures'] for r in runs]),
            'true_mm_median': _median([r['looser_true_mm'] for r in runs]),
        },
        # the run's last judgement within 0.5x the plan's platform time (the target's budget)
        'at_half_the_plan_time': _half_figures(runs, required),
        # what 4x the pairs per posture buy (the route's first half and whole, 10 and 40
        # samples), and the plan in informative order within 0.5x and 1x its platform time
        'prefixes': _prefix_figures(design, plan, seeds),
        'bounds_per_seed': [r['history'] for r in runs],
    }
