"""The ``effects`` section of ``make bench`` (docs/platform_effects.md#the-bench-effects-section): the plan
augmented for the effect groups (:func:`gsp_kinematics.planning.effect_plan.augment_route`: reference
revisits, both approach directions) and the model chosen from the data (``auto``,
:func:`gsp_kinematics.estimation.verdict.model_choice.choose_model`) on the realistic platform (all four effects),
each effect alone and the ideal platform, 20 seeds each.

A run is the verdict section's (:mod:`.verdict`): the calibrator's 60 postures in route
order, 10 pairs per posture at the default noise, ``POSTURE_S`` per posture; here the route is
augmented for all four groups (the user does not know which the platform has) and the user gives
the payload (the realistic 40 kg and its centre of mass). ``auto`` chooses among the groups with
``FOLDS``-fold cross-validation (configured noise); the plain model (``extended``) is fitted on
the same rows. The truth is the verdict's: the calibrated, compensating controller commanding 50
random postures on the simulated platform, spread over the run's span. Beside them, issue 23's
figures with ``auto`` and with the plain model: cross-validated / true, predicted / true,
calibrated / best 42-parameter geometry, applied fraction.
"""

import dataclasses
import math
import statistics

import numpy as np

from gsp_bench.verdict import (
    RUN_S,
    SAMPLES,
    SEEDS,
    best_geometry,
    default_design,
    effect_cases,
    route_run,
)
from gsp_calibrator.run.identify import uncompensated_thermal_strain, workspace_rows
from gsp_calibrator.run.postures import workspace_poses
from gsp_kinematics.estimation.goodness import NOISE_CHANNELS
from gsp_kinematics.estimation.identification import IdentificationError, identify
from gsp_kinematics.estimation.noise_from_data import (
    WithinNoise,
    estimate_row_noise,
    unmodelled_error,
)
from gsp_kinematics.estimation.prediction import accuracy_summary, predict_accuracy
from gsp_kinematics.estimation.verdict import acceptance
from gsp_kinematics.estimation.verdict.cross_validation import DEFAULT_FOLDS, cross_validate
from gsp_kinematics.estimation.verdict.model_choice import (
    DEFAULT_THERMAL_TIME_CONSTANTS,
    choose_model,
)
from gsp_kinematics.model.effect_groups import design_rows
from gsp_kinematics.model.effects import EFFECT_GROUPS, REALISTIC
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.motion import MotionLimits
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.model.validation import pose_errors, simulate_commands
from gsp_kinematics.planning.effect_plan import augment_route, effect_identifiability

#: Seconds per posture of the verdict's run (60 postures over RUN_S).
POSTURE_S = RUN_S / 60
#: Postures between the route's reference revisits here: the plan this section's figures were
#: measured with (docs/platform_effects.md#the-bench-effects-section); the calibrator's route
#: revisits at the end only (``effects.plan.DEFAULT_REVISIT_EVERY``: more do not pay).
REVISIT_EVERY = 10
#: Cross-validation folds of ``auto`` here (the calibrator's default is 10; 5 halves the cost).
FOLDS = 5
#: Thermal time constants (s; 0: linear) ``auto`` chooses among by the fit's cost: the
#: calibrator's.
THERMAL_TIME_CONSTANTS = DEFAULT_THERMAL_TIME_CONSTANTS
#: ``gsp_plan``'s timing of a posture on the motion model: settle, then the samples at 200 Hz.
PLAN_DWELL_S = 0.02 + SAMPLES / 200.0


def augmented_plan(design, groups=tuple(EFFECT_GROUPS)):
    """The verdict's route augmented for ``groups``, ``POSTURE_S`` per posture, the reference
    revisited every :data:`REVISIT_EVERY` postures."""
    return augment_route(
        design.settings.nominal,
        design.poses,
        groups,
        start_pose=home_pose(),
        revisit_every=REVISIT_EVERY,
        dwell_s=POSTURE_S,
    )


def plan_costs(design):
    """The platform time the additions cost, per group and for all four: on the bench's clock
    (``POSTURE_S`` a posture) and on ``gsp_plan``'s motion model (default leg limits)."""
    nominal, costs = design.settings.nominal, {}
    for name, groups in [*((g, [g]) for g in ('thermal', 'backlash')), ('all', EFFECT_GROUPS)]:
        bench = augmented_plan(design, groups)
        motion = augment_route(
            nominal,
            design.poses,
            groups,
            home_pose(),
            revisit_every=REVISIT_EVERY,
            dwell_s=PLAN_DWELL_S,
            limits=MotionLimits(),
        )
        costs[name] = {
            'added_postures': bench.added_postures,
            'added_s_at_15_s_a_posture': bench.added_s,
            'motion_model_plain_s': motion.plain_s,
            'motion_model_added_s': motion.added_s,
            'one_way_legs': list(bench.one_way_legs),
        }
    return costs


def workspace_errors(design, effects, geometry, at_s=None):
    """Position errors (mm) over the validation postures on the real platform, spread over the
    run (the verdict's truth) or all at the instant ``at_s`` (s)."""
    times = np.linspace(0.0, RUN_S, len(design.validation))
    if at_s is not None:
        times = np.full(len(design.validation), float(at_s))
    run = simulate_commands(design.true, geometry, design.validation, effects, times)
    position, _ = pose_errors(design.validation[run.reachable], run.real_poses[run.reachable])
    return position


def noisy_rows(design, route, effects, seed):
    """The averaged rows the calibrator collects along ``route`` (reachable postures)."""
    run = route_run(design, route, effects)
    sigmas = DEFAULT_SENSOR_NOISE
    scale = np.concatenate([np.full(6, sigmas.leg_lengths), sigmas.readings()])
    noise = np.random.default_rng(seed).normal(size=(len(route.poses), 10)) * scale
    noise /= math.sqrt(SAMPLES)
    ok = run.reachable
    return run.leg_readings[ok] + noise[ok, :6], run.device_readings[ok] + noise[ok, 6:], ok


def known_noise_unmodelled(result, sigmas, rows):
    """What ``result`` leaves unexplained (``noise_from_data.unmodelled_error``) with the
    within-posture noise known (the configured ``sigmas`` of the ``rows`` averaged rows): as
    the calibrator estimates it from the windows' scatter."""
    within = {
        channel: WithinNoise(getattr(sigmas, channel), rows * (SAMPLES - 1) * len(range(10)[c]))
        for channel, c in NOISE_CHANNELS.items()
    }
    return unmodelled_error(estimate_row_noise(result, sigmas, within))


def measured(design, result, legs, readings, rows, workspace):
    """The accuracy the calibrator measures (``CrossValidation.summary``): ``result`` (of the
    averaged rows ``legs``, ``readings`` with the ``EffectDesign`` ``rows``, None without
    effects) cross-validated over the calibrator's folds, with the unmodelled error and the
    uncompensated thermal growth as it gives them; the headline over the ``workspace`` rows
    when the run has them."""
    sigmas = DEFAULT_SENSOR_NOISE.averaged([SAMPLES])
    validation = cross_validate(
        result,
        design.settings.nominal,
        legs,
        readings,
        sigmas,
        folds=DEFAULT_FOLDS,
        noise=sigmas,
        effects=rows,
        uncompensated_strain=uncompensated_thermal_strain(result, rows),
        unmodelled=known_noise_unmodelled(result, sigmas, len(result.poses)),
    )
    return validation.summary(workspace)


def _figures(design, effects, result, cv_summary, rows):
    """True (mean, p90; over the run and at the geometry's reference instant), cross-validated
    (held out on the workspace postures) and predicted mean position errors (mm, the unmodelled
    error and the uncompensated thermal growth included as in the calibrator), applied."""
    errors = workspace_errors(design, effects, result.geometry)
    at_reference = workspace_errors(design, effects, result.geometry, rows.reference_time_s)
    sigmas = DEFAULT_SENSOR_NOISE.averaged([SAMPLES])
    prediction = predict_accuracy(
        result.geometry,
        result.covariance,
        result.free,
        unmodelled=known_noise_unmodelled(result, sigmas, len(result.poses)),
        thermal_strain=uncompensated_thermal_strain(result, rows),
        effect_free=result.effect_free,
    )
    headline = accuracy_summary(prediction)
    verdict = acceptance.judge(cv_summary, design.settings.requirement, None, headline)
    return {
        'cv_raw_mm': cv_summary['calibrated']['position_mm']['measured_mean'],
        'true_mm': float(np.mean(errors)),
        'true_p90_mm': float(np.percentile(errors, 90)),
        'true_at_reference_mm': float(np.mean(at_reference)),
        'true_at_reference_p90_mm': float(np.percentile(at_reference, 90)),
        'cv_mm': cv_summary['calibrated']['position_mm']['mean'],
        'predicted_mm': headline['position_mm_mean'],
        'applied': bool(verdict.accepted),
    }


def one_run(design, route, effects, seed):
    """``auto`` and the plain model on one seeded run of the augmented ``route``."""
    legs, readings, ok = noisy_rows(design, route, effects, seed)
    nominal, poses = design.settings.nominal, route.poses[ok]
    rows = design_rows(route.design(REALISTIC.payload_mass, REALISTIC.centre_of_mass), ok)
    sigmas = DEFAULT_SENSOR_NOISE.averaged([SAMPLES])
    try:
        choice = choose_model(
            nominal,
            legs,
            readings,
            sigmas,
            rows,
            pose_guesses=poses,
            folds=FOLDS,
            thermal_time_constants=THERMAL_TIME_CONSTANTS,
        )
        plain = identify(nominal, legs, readings, sigmas, free=['extended'], pose_guesses=poses)
    except IdentificationError as error:
        return {'failure': str(error)}
    if plain.status <= 0:
        return {'failure': 'the plain model did not converge'}
    workspace = workspace_rows(poses, workspace_poses(design.settings))
    timed = dataclasses.replace(rows, thermal_time_constant_s=choice.thermal_time_constant_s)
    return {
        'groups': list(choice.groups),
        'thermal_time_constant_s': choice.thermal_time_constant_s,
        'auto': _figures(
            design,
            effects,
            choice.result,
            measured(design, choice.result, legs, readings, timed, workspace),
            timed,
        ),
        'plain': _figures(
            design, effects, plain, measured(design, plain, legs, readings, None, workspace), rows
        ),
    }


def _median(values):
    values = [v for v in values if math.isfinite(v)]
    return statistics.median(values) if values else math.nan


def _model_figures(runs, model, best_mm):
    done = [run[model] for run in runs if model in run]
    ratio = [run['true_mm'] / best_mm for run in done] if best_mm > 1e-9 else []
    cv = [run['cv_mm'] / run['true_mm'] for run in done]
    predicted = [run['predicted_mm'] / run['true_mm'] for run in done]
    return {
        'true_mm_median': _median([run['true_mm'] for run in done]),
        'true_p90_mm_median': _median([run['true_p90_mm'] for run in done]),
        'true_at_reference_mm_median': _median([run['true_at_reference_mm'] for run in done]),
        'true_at_reference_p90_mm_median': _median(
            [run['true_at_reference_p90_mm'] for run in done]
        ),
        'cv_over_true_at_reference': _median(
            [run['cv_mm'] / run['true_at_reference_mm'] for run in done]
        ),
        'cv_over_true': _median(cv),
        'per_seed_cv_over_true': cv,
        'cv_raw_over_true': _median([run['cv_raw_mm'] / run['true_mm'] for run in done]),
        'cv_within_25_percent': sum(abs(r - 1.0) <= 0.25 for r in cv) / max(len(done), 1),
        'predicted_over_true': _median(predicted),
        'predicted_within_1.3x': sum(1 / 1.3 <= r <= 1.3 for r in predicted) / max(len(done), 1),
        'calibrated_over_best': _median(ratio),
        'calibrated_within_1.3x_of_best': sum(r <= 1.3 for r in ratio) / max(len(done), 1)
        if ratio
        else math.nan,
        'applied_fraction': sum(run['applied'] for run in done) / max(len(runs), 1),
        'per_seed_true_mm': [run['true_mm'] for run in done],
        'per_seed_true_at_reference_mm': [run['true_at_reference_mm'] for run in done],
    }


def _against_ideal_floor(cases):
    """Per case and model: calibrated / max(best, the ideal platform's median true accuracy of
    the same model and plan), median and fraction of seeds within 1.3x: below the ideal's, the
    best geometry is under the plan's noise floor (docs/verdict.md). The same at the reference
    instant (``..._at_reference``): the calibrated geometry and the best one of the platform
    at the instant the geometry refers to, both validated there."""
    for model in ('auto', 'plain'):
        for suffix, best_key in (('', 'best_mm'), ('_at_reference', 'best_at_reference_mm')):
            floor = cases['ideal'][model][f'true{suffix}_mm_median']
            for case in cases.values():
                if not case['best_mm'] > 1e-9:
                    continue  # the ideal platform: its best geometry is the truth
                level = max(case[best_key], floor)
                ratios = [t / level for t in case[model][f'per_seed_true{suffix}_mm']]
                figures = case[model]
                figures[f'calibrated_over_best_or_ideal{suffix}'] = _median(ratios)
                figures[f'calibrated_within_1.3x_of_best_or_ideal{suffix}'] = sum(
                    r <= 1.3 for r in ratios
                ) / max(len(ratios), 1)


def case_figures(design, route, name, effects, seeds, runs=None):
    """The figures of one platform over ``seeds`` runs (``runs``: the :func:`one_run` results
    if already made)."""
    if runs is None:
        runs = [one_run(design, route, effects, seed) for seed in range(seeds)]
    best_mm = float(np.mean(workspace_errors(design, effects, best_geometry(design, effects))))
    # The controllers hold the geometry of the reference instant (the run's last posture) and
    # do not compensate the thermal growth: the best geometry of the platform at that instant.
    reference_s = float(route.times_s[-1])
    best_at_reference = best_geometry(design, effects, at_s=reference_s)
    best_at_reference_mm = float(
        np.mean(workspace_errors(design, effects, best_at_reference, reference_s))
    )
    expected = [] if name == 'ideal' else list(EFFECT_GROUPS) if name == 'all_four' else [name]
    done = [run for run in runs if 'groups' in run]
    chose = [run['groups'] for run in done]
    return {
        'expected_groups': expected,
        'auto': _model_figures(done, 'auto', best_mm),
        'plain': _model_figures(done, 'plain', best_mm),
        'best_mm': best_mm,
        'best_at_reference_mm': best_at_reference_mm,
        'reference_s': reference_s,
        'expected_chosen_fraction': sum(set(expected) <= set(g) for g in chose) / max(len(runs), 1),
        'exactly_expected_fraction': sum(sorted(g) == sorted(expected) for g in chose)
        / max(len(runs), 1),
        'group_counts': {g: sum(g in c for c in chose) for g in EFFECT_GROUPS},
        'per_seed_true_mm': [run['auto']['true_mm'] for run in done],
        'per_seed_true_at_reference_mm': [run['auto']['true_at_reference_mm'] for run in done],
        'per_seed_groups': chose,
        'per_seed_thermal_time_constant_s': [run['thermal_time_constant_s'] for run in done],
        'failures': sorted({run['failure'] for run in runs if 'failure' in run})[:3],
        'seeds': seeds,
    }


def _against_ideal(cases):
    """Per case: auto's true accuracy over the ideal platform's (medians; and paired by seed),
    over the run and at the reference instant; target 1.5x."""
    for suffix in ('', '_at_reference'):
        ideal = cases['ideal'][f'per_seed_true{suffix}_mm']
        for case in cases.values():
            mine = case[f'per_seed_true{suffix}_mm']
            paired = [a / b for a, b in zip(mine, ideal, strict=False) if b > 0]
            case[f'over_ideal{suffix}_paired_median'] = _median(paired)
            ratio = _median(mine) / _median(ideal)
            case[f'over_ideal{suffix}'] = ratio
            case[f'within_1.5x_of_ideal{suffix}'] = ratio <= 1.5


def run(quick=False):
    """The ``effects`` section (``quick``: 3 seeds)."""
    design = default_design()
    route = augmented_plan(design)
    seeds = 3 if quick else SEEDS
    cases = {
        name: case_figures(design, route, name, effects, seeds)
        for name, effects in effect_cases().items()
    }
    _against_ideal(cases)
    _against_ideal_floor(cases)
    sigmas = DEFAULT_SENSOR_NOISE.averaged([SAMPLES])
    plan_design = route.design(REALISTIC.payload_mass, REALISTIC.centre_of_mass)
    identifiability = effect_identifiability(
        design.settings.nominal, route.poses, plan_design, list(EFFECT_GROUPS), sigmas, 'extended'
    )
    return {
        'description': (
            "the verdict's run (60 of 600 in route order, 15 s a posture, 10 samples at the "
            'default noise) augmented for all four groups (thermal reference revisits every 10 '
            'postures, both approach directions; from the home pose); auto: forward selection '
            'by a likelihood-ratio test at 1 % with a 5-fold held-out guard at 50 % (configured '
            'noise), plain: extended on the same '
            'rows; measured: as the calibrator (10-fold cross-validation, the leverage of '
            'each held-out posture taken out, the part no held-out posture sees added, carried '
            'to the workspace; on the '
            'workspace postures when the plan has them); predicted: with the unmodelled error '
            'and the uncompensated thermal growth; truth: 50 random postures on the simulated '
            'platform over the run (and at the reference instant, best geometry likewise); '
            'medians over seeds'
        ),
        'targets': {
            'over_ideal': '<= 1.5 (auto, each case)',
            'expected_chosen_fraction': '>= 0.9 (each effect alone)',
            'ideal plain kept (exactly_expected_fraction)': '>= 0.95',
            'cv_over_true': 'within 25 %',
            'predicted_over_true': 'within 1.3x',
            'calibrated_over_best': '<= 1.3',
            'calibrated_over_best_or_ideal': '<= 1.3 (max(best, ideal): the noise floor)',
        },
        'plan': {'route': route.to_dict(), 'costs': plan_costs(design)},
        'identifiability': identifiability,
        'cases': cases,
    }
