"""The ``run_to_requirement_levers`` section of ``make bench`` (docs/upkeep.md, "Why 0.5x is not
reached"): two levers of a run that stops when it is good enough, on the realistic platform (all
four effects) at realistic leg speeds, against the default plan (60 postures in route order,
``extended``) of the ``run_to_requirement`` section.

- **Workspace postures as the yardstick** (``workspace``): the default plan with ``WORKSPACE``
  workspace postures gives the workspace held-out accuracy (the verdict's headline with them),
  the selected postures' beside it and the true error. A run measures the plan's postures in
  information-per-second order (``stopping_run.informative_order``) with the workspace postures
  interleaved (:func:`interleaved`), judged as the calibrator judges (``judge_rows``' pipeline)
  every ``EVERY`` postures from ``MINIMUM`` within ``BUDGET`` times the default plan's platform
  time; per judgement the workspace figure and its 95 % bound over the workspace rows, the
  selected postures' figure, the predicted and the true error.
- **The model chosen from the data** (``auto``, the payload given): the default plan augmented
  for all four groups (reference revisits), and its prefixes in route order judged every
  ``EVERY`` commanded postures from ``MINIMUM`` within ``BUDGET`` (and the plan in informative
  order, augmented, within 0.5x, judged once), each identified by ``choose_model`` as the
  ``effects`` section does: cross-validated mean, its 95 % bound, predicted and true error.
"""

import dataclasses
import math

import numpy as np
from scipy import stats

import gsp_bench.effects
import gsp_bench.verdict
from gsp_bench.run_to_requirement import Plan, SimulatedRun, _median, default_plan, informative_plan
from gsp_calibrator.run import postures, run_to_requirement
from gsp_calibrator.run.identify import identify_with_settings, workspace_rows
from gsp_kinematics.estimation.prediction import accuracy_summary
from gsp_kinematics.estimation.verdict.model_choice import choose_model
from gsp_kinematics.model.effect_groups import design_rows
from gsp_kinematics.model.effects import EFFECT_GROUPS, REALISTIC
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.motion import move_time, posture_leg_lengths
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.planning.effect_plan import augment_route
from gsp_kinematics.upkeep import stopping

SEEDS = 20
QUICK_SEEDS = 1
WORKSPACE = 20  #: workspace postures (the verdict section's variant)
MINIMUM = 16  #: postures of the first judgement
EVERY = 2  #: postures between judgements
BUDGET = 0.56  #: judged within this times the default plan's platform time (0.5x and a step)
#: pairs per posture of ``auto`` judged as the calibrator judges, and its judgements
CALIBRATOR_SAMPLES = 160
CALIBRATOR_COUNTS = (18, 20, 22, 24)


def interleaved(plan_order, workspace_indices):
    """``plan_order`` with ``workspace_indices`` spread evenly through it (one after every
    ``len(plan_order) / len(workspace_indices)`` plan postures)."""
    plan_order, queue = list(plan_order), list(workspace_indices)
    if not queue:
        return plan_order
    step = len(plan_order) / len(queue)
    merged, next_at = [], step
    for count, index in enumerate(plan_order, start=1):
        merged.append(index)
        while queue and count >= next_at - 1e-9:
            merged.append(queue.pop(0))
            next_at += step
    return merged + queue


def _plan_time_s(plan):
    """The default plan's platform time (s): 60 postures in route order at the leg limits."""
    settings = plan.settings
    dwell_s = run_to_requirement.rule_for(settings).dwell_s
    poses = plan.pool[plan.planned]
    return stopping.plan_time_s(
        settings.nominal, home_pose(), poses, settings.motion_limits, dwell_s
    )


def _workspace_bound(accuracy, confidence=0.95):
    """The workspace figure's 95 % bound: its mean plus z standard errors over the workspace rows
    (scaled by the noise factor, as the mean is)."""
    position = accuracy['calibrated']['position_mm']
    rows = accuracy.get('workspace_rows') or []
    magnitudes = np.asarray(accuracy['per_posture']['position_mm'], dtype=float)[rows]
    magnitudes = magnitudes[np.isfinite(magnitudes)]
    if magnitudes.size < 2:
        return math.inf
    spread = position['noise_factor'] * np.std(magnitudes, ddof=1) / math.sqrt(magnitudes.size)
    return float(position['mean'] + stats.norm.ppf(confidence) * spread)


def _judged(settings, samples):
    """The calibrator's identification of ``samples``: ``(outcome, figures)`` or None."""
    outcome = identify_with_settings(settings, samples)
    if not outcome.success or outcome.accuracy is None:
        return None
    accuracy = outcome.accuracy
    selected = (accuracy.get('selected') or {}).get('calibrated') or {}
    predicted = math.inf
    if outcome.prediction is not None:
        predicted = accuracy_summary(outcome.prediction)['position_mm_mean']
    return outcome, {
        'workspace_mm': accuracy['calibrated']['position_mm']['mean'],
        'workspace_bound_mm': _workspace_bound(accuracy),
        'workspace_rows': len(accuracy.get('workspace_rows') or []),
        'selected_mm': selected.get('position_mm', {}).get('mean', math.nan),
        'predicted_mm': predicted,
    }


def workspace_default(seed):
    """The default plan with the workspace postures: its workspace, selected, predicted and true
    errors (mm) and its platform time (s)."""
    design = gsp_bench.verdict.default_design({'workspace_postures': WORKSPACE})
    judged = _judged(design.settings, gsp_bench.verdict.simulated_samples(design, REALISTIC, seed))
    if judged is None:
        return None
    outcome, figures = judged
    true_mm, _ = gsp_bench.verdict.true_accuracy(design, REALISTIC, outcome.geometry)
    dwell_s = run_to_requirement.rule_for(design.settings).dwell_s
    seconds = stopping.plan_time_s(
        design.settings.nominal, home_pose(), design.poses, design.settings.motion_limits, dwell_s
    )
    return {**figures, 'true_mm': true_mm, 'platform_time_s': seconds}


def workspace_trajectory(seed, budget=BUDGET):
    """One seed's run in informative order with the workspace postures interleaved: per
    judgement its postures, platform time / the default plan's, figures and true error."""
    plan = Plan.default()
    design = gsp_bench.verdict.default_design({'workspace_postures': WORKSPACE})
    settings = design.settings
    workspace = postures.workspace_poses(settings)
    pool = np.vstack([plan.pool, workspace])
    extended = dataclasses.replace(
        plan, settings=settings, pool=pool, legs=posture_leg_lengths(settings.nominal, pool)
    )
    order = interleaved(informative_plan(plan), range(len(plan.pool), len(pool)))
    dwell_s, limits = run_to_requirement.rule_for(settings).dwell_s, settings.motion_limits
    fixed_s = _plan_time_s(plan)
    simulated = SimulatedRun(design, extended, 70_000 + seed, gsp_bench.verdict.RUN_S / fixed_s)
    position, elapsed, steps = extended.start_legs, 0.0, []
    for count, index in enumerate(order, start=1):
        step = float(move_time(position, extended.legs[index], limits)) + dwell_s
        if elapsed + step > budget * fixed_s:
            break
        elapsed, position = elapsed + step, extended.legs[index]
        simulated.measure(index, elapsed)
        if count < MINIMUM or (count - MINIMUM) % EVERY:
            continue
        judged = _judged(settings, simulated.samples)
        if judged is not None:
            true_mm, _ = gsp_bench.verdict.true_accuracy(design, REALISTIC, judged[0].geometry)
            steps.append(
                {'postures': count, 'ratio': elapsed / fixed_s, 'true_mm': true_mm, **judged[1]}
            )
    return steps


def _auto_run(design, route, seed):
    """``auto`` (the payload given) on one seeded run of ``route`` (an ``AugmentedRoute`` on the
    simulation's clock), as the ``effects`` section identifies it: the groups chosen, the
    cross-validated mean and its 95 % bound, predicted and true errors (mm)."""
    legs, readings, ok = gsp_bench.effects.noisy_rows(design, route, REALISTIC, seed)
    nominal, poses = design.settings.nominal, route.poses[ok]
    rows = design_rows(route.design(REALISTIC.payload_mass, REALISTIC.centre_of_mass), ok)
    sigmas = DEFAULT_SENSOR_NOISE.averaged([gsp_bench.verdict.SAMPLES])
    try:
        choice = choose_model(
            nominal, legs, readings, sigmas, rows, pose_guesses=poses, folds=gsp_bench.effects.FOLDS,
            thermal_time_constants=gsp_bench.effects.THERMAL_TIME_CONSTANTS,
        )  # fmt: skip
    except (ValueError, np.linalg.LinAlgError, ArithmeticError) as error:
        return {'failure': str(error)}
    timed = dataclasses.replace(rows, thermal_time_constant_s=choice.thermal_time_constant_s)
    workspace = workspace_rows(poses, postures.workspace_poses(design.settings))
    # Measured as the effects section measures it (the calibrator's folds and corrections).
    summary = gsp_bench.effects.measured(design, choice.result, legs, readings, timed, workspace)
    figures = gsp_bench.effects._figures(design, REALISTIC, choice.result, summary, timed)
    bound = stopping.accuracy_bounds(summary, 0.95, figures['predicted_mm']).position_bound_mm
    return {'groups': list(choice.groups), 'auto': {**figures, 'bound_mm': bound}}


def _cut(route, count, scale):
    """The first ``count`` postures of ``route``, its times scaled to the simulation's clock."""
    return dataclasses.replace(
        route, poses=route.poses[:count], source=route.source[:count], kind=route.kind[:count],
        times_s=route.times_s[:count] * scale, directions=route.directions[:count],
    )  # fmt: skip


def auto_runs(seed, budget=BUDGET):
    """``auto`` on the default plan augmented for all four groups (``plan``), on its prefixes in
    route order (``route``: every ``EVERY`` commanded postures from ``MINIMUM`` within
    ``budget``) and on the plan in informative order within 0.5x (``informative_half``), each
    with its platform time / the plain default plan's (``ratio``)."""
    plan = Plan.default()
    design = gsp_bench.verdict.default_design({})
    settings = design.settings
    dwell_s, limits = run_to_requirement.rule_for(settings).dwell_s, settings.motion_limits
    fixed_s = _plan_time_s(plan)
    scale = gsp_bench.verdict.RUN_S / fixed_s

    def augmented(poses):
        return augment_route(
            settings.nominal, poses, EFFECT_GROUPS, start_pose=home_pose(), dwell_s=dwell_s,
            limits=limits,
        )  # fmt: skip

    def judged(route, count):
        found = _auto_run(design, _cut(route, count, scale), seed)
        return {**found, 'ratio': float(route.times_s[count - 1] / fixed_s), 'commanded': count}

    route = augmented(design.poses)
    informative = augmented(plan.pool[informative_plan(plan)])
    half = int(np.count_nonzero(informative.times_s <= 0.5 * fixed_s))
    within = int(np.count_nonzero(route.times_s <= budget * fixed_s))
    return {
        'plan': judged(route, len(route.poses)),
        'route': [judged(route, count) for count in range(MINIMUM, within + 1, EVERY)],
        'informative_half': judged(informative, half),
    }


def _first(steps, meets):
    """The first judgement of ``steps`` that ``meets`` (a predicate), or None."""
    return next((step for step in steps if meets(step)), None)


def _stops(trajectories, meets, required_mm, true_of):
    """Where the rule ``meets`` stops each seed's trajectory: the fraction of seeds stopped within
    0.5x, the time ratios, and the true error at the stop / ``required_mm``."""
    stops = [_first(steps, meets) for steps in trajectories]
    within = [stop for stop in stops if stop is not None and stop['ratio'] <= 0.5]
    return {
        'stopped_within_half_fraction': len(within) / max(len(stops), 1),
        'ratio_median': _median([stop['ratio'] for stop in within]),
        'true_over_required_at_stop': [round(true_of(stop) / required_mm, 3) for stop in within],
        'true_within_required_at_stop_fraction': sum(
            true_of(stop) <= required_mm for stop in within
        )
        / max(len(stops), 1),
    }


def _per_judgement(trajectories, figures, required):
    """Per judgement (postures): medians of the steps' ``figures`` (keys) and counts of seeds
    meeting each of ``required`` (name -> (mm, function of a step))."""
    table = []
    for count in sorted({step['postures'] for steps in trajectories for step in steps}):
        steps = [step for steps in trajectories for step in steps if step['postures'] == count]
        row = {'postures': count, 'seeds': len(steps)}
        row.update({key: _median([step[key] for step in steps]) for key in figures})
        for name, (limit, of) in required.items():
            row[f'{name}_meets'] = sum(of(step) <= limit for step in steps)
        table.append(row)
    return table


def workspace_figures(defaults, trajectories, plain_mm):
    """The workspace lever's figures: the default plan with the workspace postures, per
    judgement, and where stopping rules stop (the workspace bound against the plan's workspace
    figure; the verdict's judged figure against the plain plan's verified ``plain_mm``)."""
    required = _median([found['workspace_mm'] for found in defaults])
    ratios = [found['workspace_mm'] / found['true_mm'] for found in defaults]
    judged = lambda step: max(step['workspace_mm'], step['selected_mm'])  # noqa: E731
    return {
        'default_plan': {
            'workspace_mm_median': required,
            'workspace_bound_mm_median': _median([f['workspace_bound_mm'] for f in defaults]),
            'selected_mm_median': _median([found['selected_mm'] for found in defaults]),
            'true_mm_median': _median([found['true_mm'] for found in defaults]),
            'workspace_over_true': [
                min(ratios),
                _median(ratios),
                max(ratios),
            ],
            'platform_time_s': defaults[0]['platform_time_s'],
        },
        'per_judgement': _per_judgement(
            trajectories,
            ('ratio', 'workspace_mm', 'workspace_bound_mm', 'selected_mm', 'true_mm'),
            {
                'workspace_bound_vs_workspace_requirement': (
                    required,
                    lambda s: s['workspace_bound_mm'],
                ),
                'judged_vs_plain_requirement': (plain_mm, judged),
                'true_vs_plain_requirement': (plain_mm, lambda s: s['true_mm']),
            },
        ),  # fmt: skip
        'stop_on_workspace_bound': _stops(
            trajectories,
            lambda s: s['workspace_bound_mm'] <= required and s['predicted_mm'] <= required,
            required,
            lambda s: s['true_mm'],
        ),
        'stop_on_judged_vs_plain': _stops(
            trajectories,
            lambda s: judged(s) <= plain_mm and s['predicted_mm'] <= plain_mm,
            plain_mm,
            lambda s: s['true_mm'],
        ),
    }


def auto_figures(runs, plain_mm):
    """The ``auto`` lever's figures: its own default plan, per judgement along the route, and
    where the 95 % bound (and the prediction) meets ``plain_mm`` and the auto plan's verified
    accuracy."""
    plans = [run['plan']['auto'] for run in runs if 'auto' in run['plan']]
    own_mm = _median([plan['cv_mm'] for plan in plans])
    trajectories = [
        [{'postures': s['commanded'], 'ratio': s['ratio'], **s['auto']} for s in run['route']
         if 'auto' in s]
        for run in runs
    ]  # fmt: skip
    meets = lambda limit: lambda s: s['bound_mm'] <= limit and s['predicted_mm'] <= limit  # noqa: E731
    halves = [run['informative_half'] for run in runs if 'auto' in run['informative_half']]
    return {
        'default_plan': {
            'cv_mm_median': own_mm,
            'bound_mm_median': _median([plan['bound_mm'] for plan in plans]),
            'true_mm_median': _median([plan['true_mm'] for plan in plans]),
            'true_at_reference_mm_median': _median([p['true_at_reference_mm'] for p in plans]),
            'platform_time_over_plain': runs[0]['plan']['ratio'],
        },
        'per_judgement': _per_judgement(
            trajectories,
            ('ratio', 'cv_mm', 'bound_mm', 'predicted_mm', 'true_mm'),
            {
                'bound_vs_plain_requirement': (plain_mm, lambda s: s['bound_mm']),
                'bound_vs_auto_requirement': (own_mm, lambda s: s['bound_mm']),
                'true_vs_plain_requirement': (plain_mm, lambda s: s['true_mm']),
            },
        ),  # fmt: skip
        'stop_at_plain_requirement': _stops(
            trajectories, meets(plain_mm), plain_mm, lambda s: s['true_mm']
        ),  # fmt: skip
        'stop_at_auto_requirement': _stops(
            trajectories, meets(own_mm), own_mm, lambda s: s['true_mm']
        ),  # fmt: skip
        'informative_half': {
            'ratio': halves[0]['ratio'] if halves else math.nan,
            'postures': halves[0]['commanded'] if halves else 0,
            **{
                f'{key}_median': _median([h['auto'][key] for h in halves])
                for key in ('cv_mm', 'bound_mm', 'predicted_mm', 'true_mm')
            },
            'bound_meets_plain_fraction': sum(h['auto']['bound_mm'] <= plain_mm for h in halves)
            / max(len(halves), 1),
        },  # fmt: skip
        'failures': sum('failure' in s for run in runs for s in [run['plan'], *run['route']]),
    }


def calibrator_figures(runs, plain_mm, first_counts=(18, 24)):
    """``auto`` with ``CALIBRATOR_SAMPLES`` per posture judged as the calibrator judges: its own
    default plan (10 samples), per judgement, and where the 95 % bound (and the prediction)
    meets ``plain_mm`` or the auto plan's verified accuracy, judged from each of
    ``first_counts`` (``stop_minimum_postures``) on."""
    plans = [run['plan'][0] for run in runs if math.isfinite(run['plan'][0]['position_mm'])]
    own_mm = _median([plan['position_mm'] for plan in plans])
    trajectories = [
        [{**step, 'postures': step['commanded']} for step in run['run']
         if math.isfinite(step['position_mm'])]
        for run in runs
    ]  # fmt: skip
    meets = lambda limit: lambda s: s['position_bound_mm'] <= limit and s['predicted_mm'] <= limit  # noqa: E731
    stops = {}
    for first in first_counts:
        later = [[s for s in steps if s['postures'] >= first] for steps in trajectories]
        for name, limit in (('plain', plain_mm), ('auto', own_mm)):
            stops[f'from_{first}_at_{name}_requirement'] = _stops(
                later, meets(limit), limit, lambda s: s['true_mm']
            )
    return {
        'pairs_per_posture': CALIBRATOR_SAMPLES,
        'auto_default_plan': {
            'cv_mm_median': own_mm,
            'bound_mm_median': _median([plan['position_bound_mm'] for plan in plans]),
            'true_mm_median': _median([plan['true_mm'] for plan in plans]),
            'platform_time_over_plain': plans[0]['ratio'] if plans else math.nan,
        },
        'per_judgement': _per_judgement(
            trajectories,
            ('ratio', 'position_mm', 'position_bound_mm', 'predicted_mm', 'true_mm'),
            {
                'bound_vs_plain_requirement': (plain_mm, lambda s: s['position_bound_mm']),
                'bound_vs_auto_requirement': (own_mm, lambda s: s['position_bound_mm']),
                'cv_vs_auto_requirement': (own_mm, lambda s: s['position_mm']),
                'true_vs_plain_requirement': (plain_mm, lambda s: s['true_mm']),
                'true_vs_auto_requirement': (own_mm, lambda s: s['true_mm']),
            },
        ),  # fmt: skip
        'stops': stops,
    }


def run(quick=False):
    """The section: the plain default plan's verified accuracy (the requirement), then the
    levers per seed."""
    design = gsp_bench.verdict.default_design()
    seeds = range(QUICK_SEEDS if quick else SEEDS)
    plain = [found for found in (default_plan(design, s) for s in seeds) if found]
    plain_mm = _median([found['cv_mm'] for found in plain])
    defaults = [found for found in (workspace_default(s) for s in seeds) if found]
    trajectories = [workspace_trajectory(seed) for seed in seeds]
    calibrated = [
        {
            'plan': calibrator_auto(seed, gsp_bench.verdict.SAMPLES, None),
            'run': calibrator_auto(seed, CALIBRATOR_SAMPLES, CALIBRATOR_COUNTS),
        }
        for seed in seeds
    ]
    return {
        'description': __doc__.split('\n\n')[0],
        'seeds': len(seeds),
        'plain_default_plan_verified_mm': plain_mm,
        'workspace': workspace_figures(defaults, trajectories, plain_mm),
        'auto': auto_figures([auto_runs(seed) for seed in seeds], plain_mm),
        'auto_calibrator': calibrator_figures(calibrated, plain_mm),
    }


def calibrator_auto(seed, samples, counts):
    """``auto`` (the payload given) with ``samples`` per posture judged as the calibrator's
    stopping run judges (``upkeep.run_to_requirement.judge_rows``: noise from the run, its
    folds, the predicted error) on the default plan augmented by the calibrator's route for
    ``auto``, at ``counts`` commanded postures (None: the whole route): per judgement the bounds,
    the true error and the platform time / the plain default plan's."""
    plan = Plan.default()
    values = {
        'free_parameters': ['auto'],
        'payload_mass': REALISTIC.payload_mass,
        'payload_centre_of_mass': list(REALISTIC.centre_of_mass),
        'pairs_per_posture': samples,
    }
    design = gsp_bench.verdict.default_design(values)
    settings = design.settings
    rule = run_to_requirement.rule_for(settings)
    fixed_s = _plan_time_s(plan)
    route = augment_route(
        settings.nominal, design.poses, EFFECT_GROUPS, start_pose=home_pose(),
        dwell_s=rule.dwell_s, limits=settings.motion_limits,
    )  # fmt: skip
    timed = _cut(route, len(route.poses), gsp_bench.verdict.RUN_S / fixed_s)
    run = gsp_bench.effects.route_run(design, timed, REALISTIC)
    rng = np.random.default_rng(80_000 + seed)
    rows = gsp_bench.verdict.rows_of_run(run, timed.poses, samples, DEFAULT_SENSOR_NOISE, rng, True)
    steps = []
    for count in counts or [len(route.poses)]:
        kept = rows.posture <= count
        judgement = run_to_requirement.judge_rows(settings, rows.rows(kept), rule)
        true_mm = math.nan
        if judgement.result is not None:
            true_mm, _ = gsp_bench.verdict.true_accuracy(
                design, REALISTIC, judgement.result.geometry
            )
        steps.append(
            {
                'commanded': count,
                'ratio': float(route.times_s[count - 1] / fixed_s),
                'plan_s': float(route.total_s),
                'true_mm': true_mm,
                **judgement.bounds.record(),
            }
        )
    return steps
