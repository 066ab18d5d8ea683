"""``model_choice_cpu`` section of ``gsp_bench`` (docs/platform_effects.md#choosing-the-model-auto):
the CPU time of the calibrator's identification with the model chosen from the data (``auto``:
the choice, the fit and the verdict's cross-validation, ``run.identify.identify_from_samples``)
against the plain fit's (``extended``: the fit and the verdict) on the same rows.

The rows are those of :mod:`.verdict`'s runs (the calibrator's default plan on the route ``auto``
augments, 10 samples a posture over ``RUN_S``): per case, at the defaults (``auto`` without the
payload mass), the realistic platform with all four effects and the ideal platform. The time is
the process's CPU time (``time.process_time``) of each identification, the fastest of
``REPEATS`` (the machine is shared: CPU time is the steadier figure, and the least is the cost
without interference); per case the median over the seeds of the per-seed
ratio ``auto / extended`` (the issue-33 target: at most 5). Beside it, ``ratio_to_plain_fit``:
``auto`` over the plain fit alone (``extended``'s estimated-noise fit without its verdict, what
the summary's identification time counts), and ``before``: the same section on the code before
the model choice's linearised folds (commit 5eab6c8) and before it cross-validated only the
candidates that can still be kept (commit e934763).
"""

import math
import statistics
import time

from gsp_bench import verdict
from gsp_calibrator.run.identify import identify_with_settings
from gsp_calibrator.settings import CalibratorSettings
from gsp_kinematics.estimation import noise_from_data
from gsp_kinematics.estimation.identification import resolve_free

SEEDS = 20
QUICK_SEEDS = 2
REPEATS = 2
TARGET_RATIO = 5.0
#: ``{case: (platform in verdict.effect_cases(), calibrator values of the auto run)}``: the
#: defaults (``auto``, no payload mass).
CASES = {
    'realistic_no_payload': ('all_four', {'free_parameters': ['auto']}),
    'ideal_no_payload': ('ideal', {'free_parameters': ['auto']}),
}


#: This section's medians before a change of the model choice: ``{commit: {case: {field: value}}}``.
#: 5eab6c8, before the linearised folds (2026-11-28, 5 seeds, load average about 12 from other
#: jobs); e934763, before only the candidates that can still be kept were cross-validated
#: (2026-11-28, 20 seeds, run just before the same section on the change).
BEFORE = {
    '5eab6c8': {
        'realistic_with_payload': {
            'auto_cpu_s': 2.559,
            'extended_cpu_s': 0.331,
            'plain_fit_cpu_s': 0.046,
            'ratio': 7.63,
            'ratio_to_plain_fit': 55.3,
        },
        'realistic_no_payload': {
            'auto_cpu_s': 1.623,
            'extended_cpu_s': 0.334,
            'plain_fit_cpu_s': 0.048,
            'ratio': 4.78,
            'ratio_to_plain_fit': 34.7,
        },
        'ideal_no_payload': {
            'auto_cpu_s': 1.074,
            'extended_cpu_s': 0.289,
            'plain_fit_cpu_s': 0.018,
            'ratio': 3.73,
            'ratio_to_plain_fit': 58.4,
        },
    },
    'e934763': {
        'realistic_no_payload': {
            'auto_cpu_s': 1.175,
            'extended_cpu_s': 0.243,
            'plain_fit_cpu_s': 0.031,
            'ratio': 4.84,
            'ratio_to_plain_fit': 38.09,
            'ratio_max': 5.03,
        },
        'ideal_no_payload': {
            'auto_cpu_s': 0.539,
            'extended_cpu_s': 0.21,
            'plain_fit_cpu_s': 0.013,
            'ratio': 2.57,
            'ratio_to_plain_fit': 43.22,
            'ratio_max': 2.67,
        },
    },
}


def cpu_s(settings, samples, repeats=REPEATS):
    """``(least CPU seconds of identifying samples with settings over repeats, outcome)``."""
    best, outcome = math.inf, None
    for _ in range(repeats):
        started = time.process_time()
        outcome = identify_with_settings(settings, samples)
        best = min(best, time.process_time() - started)
    return best, outcome


def plain_fit_cpu_s(settings, samples, repeats=REPEATS):
    """Least CPU seconds of the plain fit alone (``run.identify``'s estimated-noise
    identification with ``extended``, no verdict) of ``samples`` with ``settings``."""
    row_sigmas = settings.sigmas.averaged(samples.n_samples)
    within = noise_from_data.within_row_noise(samples.lag_sums, samples.n_samples)
    best = math.inf
    for _ in range(repeats):
        started = time.process_time()
        noise_from_data.identify_with_noise(
            settings.noise_source,
            settings.nominal,
            samples.leg_lengths,
            samples.readings,
            row_sigmas,
            within,
            formulation=settings.formulation,
            free=resolve_free(['extended']),
            pose_guesses=samples.commanded_poses,
            options=settings.identify_options(),
        )
        best = min(best, time.process_time() - started)
    return best


def case_figures(platform, values, seeds):
    """The CPU figures of one case over ``seeds`` seeded runs."""
    design = verdict.default_design(values)
    plain = CalibratorSettings.from_values({**values, 'free_parameters': ['extended']})
    effects = verdict.effect_cases()[platform]
    runs = []
    for seed in range(seeds):
        samples = verdict.simulated_samples(design, effects, seed)
        auto_s, outcome = cpu_s(design.settings, samples)
        plain_s, _ = cpu_s(plain, samples)
        fit_s = plain_fit_cpu_s(plain, samples)
        runs.append(
            {
                'seed': seed,
                'auto_cpu_s': auto_s,
                'extended_cpu_s': plain_s,
                'plain_fit_cpu_s': fit_s,
                'ratio': auto_s / plain_s,
                'ratio_to_plain_fit': auto_s / fit_s,
                'groups': list((outcome.effects or {}).get('groups', [])),
            }
        )
    ratios = [run['ratio'] for run in runs]
    return {
        'platform': platform,
        'settings': values,
        'auto_cpu_s': statistics.median(run['auto_cpu_s'] for run in runs),
        'extended_cpu_s': statistics.median(run['extended_cpu_s'] for run in runs),
        'plain_fit_cpu_s': statistics.median(run['plain_fit_cpu_s'] for run in runs),
        'ratio': statistics.median(ratios),
        'ratio_to_plain_fit': statistics.median(run['ratio_to_plain_fit'] for run in runs),
        'ratio_max': max(ratios),
        'within_target': statistics.median(ratios) <= TARGET_RATIO,
        'per_seed': runs,
    }


def run(quick=False):
    """The ``model_choice_cpu`` section (``quick``: 2 seeds)."""
    seeds = QUICK_SEEDS if quick else SEEDS
    cases = {
        name: case_figures(platform, values, seeds) for name, (platform, values) in CASES.items()
    }
    return {
        'description': (
            'CPU time (time.process_time, least of 2 repeats) of the calibrator identification '
            '(run.identify.identify_from_samples: fit, model choice, verdict cross-validation and '
            'prediction) with free_parameters [auto] against [extended] on the same rows '
            '(tools.bench.verdict runs: default plan on the auto route, 10 samples a posture), '
            'medians over seeds of the per-seed ratio'
        ),
        'target': {'ratio': f'<= {TARGET_RATIO:g}'},
        'seeds': seeds,
        'cases': cases,
        'before': BEFORE,
    }
