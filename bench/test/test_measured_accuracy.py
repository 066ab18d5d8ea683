"""Issue 23's bench figures against the simulation's truth (``tools.bench.effects``): the
accuracy measured on held-out postures under leg compliance, and what the calibrated geometry
is compared with on a platform that warms during the run (docs/verdict.md)."""

import numpy as np
import pytest

import gsp_bench.effects
import gsp_bench.verdict


@pytest.fixture(scope='module')
def design():
    """The calibrator's default plan (60 postures in route order) on the shipped pair."""
    return gsp_bench.verdict.default_design()


def test_the_held_out_accuracy_under_compliance_takes_the_leverage_of_the_extremes_out(design):
    """Seed 1 of the bench: one selected posture loads a leg with 1.9 kN, the only posture
    that determines its compliance; the fold without it misplaces it by about 0.26 mm, and the
    raw held-out mean is about 4x the true accuracy. Scaled by the full fit's over the held-out
    fit's predicted variance, with the part no held-out posture sees added, it is within 50 %."""
    route = gsp_bench.effects.augmented_plan(design)
    run = gsp_bench.effects.one_run(
        design, route, gsp_bench.verdict.effect_cases()['compliance'], 1
    )
    assert run['groups'] == ['compliance']
    auto = run['auto']
    assert auto['cv_raw_mm'] > 3.0 * auto['true_mm']
    assert auto['cv_mm'] == pytest.approx(auto['true_mm'], rel=0.5)


def test_at_one_instant_the_warmed_platform_has_an_exact_42_parameter_geometry(design):
    """Thermal growth at one instant is a leg gain and offset: the best geometry fitted there
    is exact there (under 0.1 um), while over the run's warming no single geometry is (about
    5 um): calibrated / best compares like with like only at the same instant."""
    effects = gsp_bench.verdict.effect_cases()['thermal']
    reference_s = 975.0
    at_reference = gsp_bench.verdict.best_geometry(design, effects, at_s=reference_s)
    exact = gsp_bench.effects.workspace_errors(design, effects, at_reference, reference_s)
    assert np.mean(exact) < 1e-4  # mm
    over_run = gsp_bench.verdict.best_geometry(design, effects)
    assert np.mean(gsp_bench.effects.workspace_errors(design, effects, over_run)) > 3e-3  # mm
