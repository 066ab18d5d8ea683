"""The model choice's held-out errors from linearised fold fits
(``gsp_kinematics.estimation.verdict.fold_fits.linearised_refits``) on seeded runs of the realistic platform
(``tools.bench.verdict``'s, the bench's rows): the same groups as with refits of every fold, each
candidate's held-out error and chi-square as the refits give them, and per fold a linearised
refit predicts the held-out postures as the real refit does; the thermal time constant chosen
from one fit as from a fit of each; the calibrator's verdict with linearised folds as with
refits."""

import dataclasses

import numpy as np
import pytest

import gsp_bench.verdict
from gsp_calibrator.collection.approach import effect_design
from gsp_calibrator.run import identify as run_identify
from gsp_calibrator.run.identify import identify_with_settings
from gsp_kinematics.estimation import noise_from_data
from gsp_kinematics.estimation.identification import Options
from gsp_kinematics.estimation.verdict.comparison import comparison_variances
from gsp_kinematics.estimation.verdict.cross_validation import (
    _errors,
    cross_validate,
    fold_assignment,
)
from gsp_kinematics.estimation.verdict.fold_fits import linearised_refits, refit_fold
from gsp_kinematics.estimation.verdict.model_choice import (
    DEFAULT_THERMAL_TIME_CONSTANTS,
    _fit,
    available_groups,
    choose_model,
    thermal_time_constant,
)
from gsp_kinematics.model.effect_groups import design_rows

#: Held-out errors of the linearised and the refitted folds agree within the larger of these.
RELATIVE = 0.05
ABSOLUTE_MM = 0.5e-3
#: A thermal time constant's least cost from one Gauss-Newton step agrees with its fit's within
#: this (half a chi-square of hundreds to thousands; the candidates differ by tens).
COST_TOLERANCE = 0.5


@pytest.fixture(scope='module')
def designs():
    """The bench's real-platform design (``auto`` with the payload) and ``auto`` alone."""
    return {
        'payload': gsp_bench.verdict.default_design(gsp_bench.verdict.REAL_PLATFORM),
        'no_payload': gsp_bench.verdict.default_design({'free_parameters': ['auto']}),
    }


def choice_rows(design, case, seed):
    """``(nominal, legs, readings, the rows' noise, EffectDesign, commanded poses)`` of a run
    of the bench's platform ``case``, weighted as ``run.identify`` weighs the choice's rows."""
    samples = gsp_bench.verdict.simulated_samples(
        design, gsp_bench.verdict.effect_cases()[case], seed
    )
    settings = design.settings
    row_sigmas = settings.sigmas.averaged(samples.n_samples)
    within = noise_from_data.within_row_noise(samples.lag_sums, samples.n_samples)
    known = noise_from_data.within_sigmas(within, row_sigmas)
    effects = effect_design(samples, settings.payload_mass, settings.payload_centre_of_mass)
    return (
        settings.nominal,
        samples.leg_lengths,
        samples.readings,
        known,
        effects,
        samples.commanded_poses,
    )


def _choose(rows, linearised):
    nominal, legs, readings, sigmas, effects, poses = rows
    return choose_model(
        nominal,
        legs,
        readings,
        sigmas,
        effects,
        pose_guesses=poses,
        thermal_time_constants=DEFAULT_THERMAL_TIME_CONSTANTS,
        linearised=linearised,
    )


@pytest.mark.parametrize(
    'variant, case, seed',
    [
        ('payload', 'all_four', 0),
        ('payload', 'all_four', 1),
        ('payload', 'ideal', 2),
        ('no_payload', 'all_four', 3),
    ],
)
def test_the_linearised_choice_is_the_refits_choice(designs, variant, case, seed):
    rows = choice_rows(designs[variant], case, seed)
    refitted, linearised = _choose(rows, False), _choose(rows, True)
    assert linearised.groups == refitted.groups, (linearised.reason, refitted.reason)
    assert linearised.thermal_time_constant_s == refitted.thermal_time_constant_s
    assert len(linearised.candidates) == len(refitted.candidates)
    for fast, slow in zip(linearised.candidates, refitted.candidates, strict=True):
        assert fast.groups == slow.groups and fast.chosen == slow.chosen
        assert fast.not_judged == slow.not_judged and fast.not_measured == slow.not_measured
        tolerance = max(RELATIVE * slow.position_mm, ABSOLUTE_MM)
        assert fast.position_mm == pytest.approx(slow.position_mm, abs=tolerance, nan_ok=True), (
            fast.groups
        )
        # The same fit, started elsewhere: the same minimum (a chi-square of hundreds).
        assert fast.chi2 == pytest.approx(slow.chi2, abs=1e-3), fast.groups


@pytest.mark.parametrize('groups', [(), ('compliance', 'backlash'), ('compliance', 'thermal')])
def test_a_linearised_refit_predicts_the_held_out_postures_as_the_refit(designs, groups):
    nominal, legs, readings, sigmas, effects, poses = choice_rows(designs['payload'], 'all_four', 4)
    data = (legs, readings, sigmas, poses, effects, None)
    free = ['extended', *groups]
    result = _fit(nominal, data, free, Options(), effects)
    guesses = np.asarray(result.poses)
    assignment = fold_assignment(len(legs), 5)
    kept = [assignment != fold for fold in range(5)]
    steps = linearised_refits(result, legs, readings, sigmas, effects, kept)
    names = result.free_names
    for fold, rows in enumerate(kept):
        held = ~rows
        refit = refit_fold(
            result,
            names,
            (legs[rows], readings[rows], sigmas, guesses[rows]),
            Options(),
            design_rows(effects, rows),
        )
        assert refit is not None and steps[fold] is not None
        predicted = [
            _errors(
                fit.geometry,
                fit.geometry,
                legs[held],
                readings[held],
                guesses[held],
                design_rows(effects, held),
            )[0]
            for fit in (steps[fold], refit)
        ]
        linear, exact = (np.linalg.norm(p, axis=1) for p in predicted)
        tolerance = np.maximum(RELATIVE * exact, ABSOLUTE_MM * 1e-3)
        assert np.all(np.abs(linear - exact) <= tolerance), (fold, 1e6 * (linear - exact))
        variances = [
            comparison_variances(fit, guesses[held], readings[held], design_rows(effects, held))[1][
                0
            ]
            for fit in (steps[fold], refit)
        ]
        np.testing.assert_allclose(variances[0], variances[1], rtol=RELATIVE)


@pytest.mark.parametrize(
    'variant, case, seed', [('payload', 'all_four', 0), ('no_payload', 'all_four', 1)]
)
def test_the_thermal_time_constant_from_one_fit_is_the_fits_choice(designs, variant, case, seed):
    nominal, legs, readings, sigmas, effects, poses = choice_rows(designs[variant], case, seed)
    data = (legs, readings, sigmas, poses, effects, None)
    groups = available_groups(effects, len(legs))
    tau, costs = thermal_time_constant(
        nominal, data, ('extended',), groups, DEFAULT_THERMAL_TIME_CONSTANTS, Options()
    )
    fitted = {}
    for candidate in DEFAULT_THERMAL_TIME_CONSTANTS:
        timed = dataclasses.replace(effects, thermal_time_constant_s=candidate)
        fitted[candidate] = _fit(nominal, data, ['extended', *groups], Options(), timed).cost
    assert tau == min(fitted, key=fitted.get), (costs, fitted)
    for candidate, cost in fitted.items():
        assert costs[candidate] == pytest.approx(cost, abs=COST_TOLERANCE), candidate


@pytest.mark.parametrize(
    'variant, case, seed', [('payload', 'all_four', 0), ('no_payload', 'ideal', 1)]
)
def test_the_verdicts_linearised_folds_give_the_refits_figures(
    designs, variant, case, seed, monkeypatch
):
    """The calibrator's verdict cross-validates with linearised fold fits: its held-out figures
    are those of refitting every fold."""
    design = designs[variant]
    samples = gsp_bench.verdict.simulated_samples(
        design, gsp_bench.verdict.effect_cases()[case], seed
    )
    linearised = identify_with_settings(design.settings, samples)

    def refitting(*args, **kwargs):
        return cross_validate(*args, **{**kwargs, 'linearised': False})

    monkeypatch.setattr(run_identify, 'cross_validate', refitting)
    refitted = identify_with_settings(design.settings, samples)
    assert linearised.accepted == refitted.accepted
    for key in ('mean', 'measured_mean', 'p95'):
        fast, slow = (
            outcome.accuracy['calibrated']['position_mm'][key] for outcome in (linearised, refitted)
        )
        assert fast == pytest.approx(slow, abs=max(RELATIVE * slow, ABSOLUTE_MM)), key
