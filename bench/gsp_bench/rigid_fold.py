"""The ``rigid_fold`` section of ``make bench`` (docs/platform_effects.md, the rigid fold): what
a controller that cannot compensate the identified effects gets, at the calibrator's defaults
(no parameter given). On :mod:`.verdict`'s runs of the realistic platform (each effect alone,
all four: the default plan and route, the calibrator's pipeline), the geometry a rigid
controller gets (``result_rigid.yaml``, the effects folded; ``result.yaml`` when the plain model
was kept) is validated run rigidly, beside the best rigid 42-parameter geometry fitted to the
truth (:func:`.verdict.best_geometry`), with its held-out accuracy and 95 % interval
(:func:`.verdict.rigid_run`).
"""

import math

from gsp_bench import verdict
from gsp_bench.verdict import RUN_S, best_geometry, true_accuracy

FIELDS = (
    'best_mm',
    'true_mm',
    'applied_fraction',
    'per_seed_groups',
)


def rigid_figures(design, effects, runs, best_mm, floor_mm=math.nan):
    """Issue 33's figures of a rigid controller over ``runs`` (:func:`.verdict.rigid_run`'s,
    medians over seeds): its truth over the best rigid geometry's (``best_mm``; at the run's end
    against the best there), and over ``hypot(best_mm, floor_mm)`` (``floor_mm``: the ideal
    platform's calibrated truth with the same plan, the fit's error at this noise, which adds to
    the best rigid geometry's as an independent error); its held-out accuracy over its truth and
    the interval's coverage."""
    runs = [run for run in runs if 'rigid_true_mm' in run]
    if not runs or not best_mm > 1e-9:
        return {}
    best_end = best_geometry(design, effects, at_s=RUN_S)
    best_end_mm = true_accuracy(design, effects, best_end, RUN_S)[0]
    true = [run['rigid_true_mm'] for run in runs]
    at_end = [run['rigid_true_at_end_mm'] for run in runs]
    return {
        'rigid_true_mm': verdict._median(true),
        'rigid_true_at_end_mm': verdict._median(at_end),
        'best_at_end_mm': best_end_mm,
        'rigid_over_best': verdict._median([t / best_mm for t in true]),
        'rigid_within_1.3x_of_best': sum(t / best_mm <= 1.3 for t in true) / len(runs),
        'rigid_over_best_and_ideal': verdict._median(
            [t / math.hypot(best_mm, floor_mm) for t in true]
        ),
        # NaN where a rigid geometry describes the platform at the run's end (thermal alone)
        'rigid_at_end_over_best_at_end': verdict._median([t / best_end_mm for t in at_end])
        if best_end_mm > 1e-9
        else math.nan,
        'rigid_cv_over_true': verdict._median(
            [r['rigid_cv_mm'] / r['rigid_true_mm'] for r in runs]
        ),
        'rigid_interval_coverage': verdict.interval_coverage(
            [r['rigid_cv_interval_mm'] for r in runs], true
        ),
    }


def rigid_cases(design, verdict_cases):
    """The rigid controller's figures of :func:`.verdict.variant_cases`'s realistic cases."""
    effects = verdict.effect_cases()
    floor = verdict_cases.get('ideal', {}).get('true_mm', math.nan)
    return {
        name: {
            **{key: figures[key] for key in FIELDS if key in figures},
            **rigid_figures(
                design, effects[name], figures['per_seed_rigid'], figures['best_mm'], floor
            ),
        }
        for name, figures in verdict_cases.items()
        if name != 'ideal'
    }


def run(quick=False, verdict_cases=None):
    """The ``rigid_fold`` section (``quick``: 3 seeds); ``verdict_cases``: the verdict section's
    ``cases`` when already computed (the same runs)."""
    seeds = 3 if quick else verdict.SEEDS
    if verdict_cases is None:
        verdict_cases = verdict.variant_cases({}, seeds)
    cases = rigid_cases(verdict.default_design(), verdict_cases)
    return {
        'description': (
            'verdict runs at the defaults (auto, no payload mass, default route), realistic '
            'platform: the rigid controller runs result_rigid.yaml (result.yaml when the plain '
            'model was kept) on 50 random postures over the run (rigid_true_mm) and at its end; '
            'best: the best rigid 42-parameter geometry fitted to the truth; held out as the '
            'calibrator gives it; medians over seeds'
        ),
        'targets': {
            'rigid_over_best': '<= 1.3 (issue 33: a rigid controller, median)',
            'rigid_over_best_and_ideal': (
                'over hypot(best, the ideal platform calibrated truth): near 1 when the fold '
                'is as good as the best rigid geometry and only the fit noise is added'
            ),
            'rigid_cv_over_true': 'within 25 % (median); rigid_interval_coverage >= 0.9',
        },
        'seeds': seeds,
        'cases': cases,
    }
