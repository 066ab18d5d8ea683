"""The ``upkeep_realistic`` section of ``make bench`` (docs/upkeep.md): the check on the realistic
platform of docs/platform_effects.md (compliance, backlash, thermal growth, offset joint axes).

Each seed calibrates that platform as the calibrator does (``bench_verdict``'s simulated run over
15 min of warming, the calibrator's identification with the noise and unmodelled error estimated
from the run), then checks it, unchanged and after +20 um on one leg offset, twice: at the
calibration's mid-run thermal state (a check in the same conditions), and at its start (a check
of a platform started cold, whose legs are shorter than during most of the calibration).
"""

import numpy as np

import gsp_bench.verdict
from gsp_bench.upkeep import CHANGE_M, calibration_of, changed_truth
from gsp_calibrator.run.identify import identify_with_settings
from gsp_calibrator.upkeep import check_run
from gsp_kinematics.model.effects import REALISTIC
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.sensor_noise import NOISE_FIELDS, SensorNoise
from gsp_kinematics.model.validation import simulate_commands

SEEDS = 20
QUICK_SEEDS = 2
#: When the check starts (s since the calibration's start): mid-run, and cold.
CHECK_STARTS_S = {'same_thermal_state': 0.5 * gsp_bench.verdict.RUN_S, 'cold_start': 0.0}


def _reference(design, seed):
    settings = design.settings
    outcome = identify_with_settings(
        settings, gsp_bench.verdict.simulated_samples(design, REALISTIC, seed)
    )
    if not outcome.success:
        return None
    estimates = outcome.noise_estimates
    noise = SensorNoise(**{name: estimates[name]['estimated'] for name in NOISE_FIELDS})
    calibrated = calibration_of(outcome.result)
    return check_run.CheckReference(
        outcome.geometry, f'seed {seed}', calibrated, noise, outcome.unmodelled
    )


def _check(design, reference, plan, true, start_s, seed):
    settings = design.settings
    times = start_s + np.linspace(0.0, plan.platform_time_s, len(plan.poses))
    run = simulate_commands(true, reference.geometry, plan.poses, REALISTIC, times)
    samples = gsp_bench.verdict.rows_of_run(
        run, plan.poses, settings.pairs_per_posture, settings.sigmas, np.random.default_rng(seed)
    )
    return check_run.evaluate_check(
        reference, samples, settings.sigmas, settings.requirement, 'bench'
    )


def run(quick=False):
    """Per check start: the fractions of seeds that say recalibrate (unchanged, changed) and that
    name the changed leg first."""
    design = gsp_bench.verdict.default_design()
    settings = design.settings
    keys = ('unchanged', 'changed', 'named', 'unchanged_alike', 'unchanged_named_a_leg')
    counts = {name: dict.fromkeys(keys, 0) for name in CHECK_STARTS_S}
    used = 0
    for seed in range(QUICK_SEEDS if quick else SEEDS):
        reference = _reference(design, seed)
        if reference is None:
            continue
        used += 1
        plan = check_run.check_plan(
            reference,
            home_pose(),
            settings.pool_size,
            settings.seed,
            settings.sigmas,
            settings.pairs_per_posture,
            settings.motion_limits,
        )
        leg = 1 + seed % 6
        moved = changed_truth(design.true, f'Loff{leg}', CHANGE_M)
        for name, start_s in CHECK_STARTS_S.items():
            same = _check(design, reference, plan, design.true, start_s, 50_000 + seed)
            changed = _check(design, reference, plan, moved, start_s, 60_000 + seed)
            counts[name]['unchanged'] += same['verdict'] == 'recalibrate'
            counts[name]['changed'] += changed['verdict'] == 'recalibrate'
            counts[name]['named'] += changed['moved_legs'][:1] == [leg]
            counts[name]['unchanged_alike'] += same.get('common_change', {}).get('alike', False)
            counts[name]['unchanged_named_a_leg'] += bool(same['moved_legs'])
    return {
        'description': (
            'realistic platform (all four effects), calibrated over 15 min of warming by the '
            'calibrator defaults; a check unchanged and after +20 um on leg (seed mod 6) + 1, at '
            'the calibration mid-run thermal state and cold (its start)'
        ),
        'seeds': used,
        **{
            name: {
                'unchanged_recalibrate_fraction': entry['unchanged'] / max(used, 1),
                'changed_recalibrate_fraction': entry['changed'] / max(used, 1),
                'changed_names_leg_fraction': entry['named'] / max(used, 1),
                # the six leg offsets changed alike (thermal growth), and no leg named
                'unchanged_alike_fraction': entry['unchanged_alike'] / max(used, 1),
                'unchanged_names_a_leg_fraction': entry['unchanged_named_a_leg'] / max(used, 1),
            }
            for name, entry in counts.items()
        },
    }
