"""The one-minute check (gsp_kinematics.upkeep.check) on the benches' simulation path: a calibrated
controller, the shipped real platform (unchanged, or with one leg offset moved), noisy rows."""

import numpy as np
import pytest

from gsp_bench.sensor_errors import SAMPLES, SIGMAS, collect
from gsp_bench.upkeep import UpkeepDesign, calibration_of, changed_truth
from gsp_kinematics.estimation.verdict import acceptance
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.motion import MotionLimits, move_time, posture_leg_lengths
from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_kinematics.upkeep import check, drift

ROWS = SIGMAS.averaged([SAMPLES])
REQUIRED = acceptance.Requirement(position_mm=0.05, orientation_deg=0.01)
NO_NOISE = SensorNoise(leg_lengths=0.0, inclinometer=0.0, encoder=0.0, lvdt=0.0)


@pytest.fixture(scope='module')
def calibrated():
    design = UpkeepDesign.default()
    result = design.identify(design.true, seed=31)
    calibration = calibration_of(result)
    plan = check.choose_check_postures(result.geometry, design.pool, home_pose(), ROWS)
    return design, result.geometry, calibration, plan


def run_check(calibrated, true, seed, required=REQUIRED):
    design, controller, calibration, plan = calibrated
    legs, readings, _, commanded = collect(true, controller, plan.poses, seed)
    return check.check_platform(controller, legs, readings, commanded, ROWS, required, calibration)


def test_the_plan_fits_in_a_minute_at_realistic_leg_speeds(calibrated):
    _, controller, _, plan = calibrated
    assert 4 <= len(plan.poses) <= check.CHECK_POSTURES
    legs = posture_leg_lengths(controller, np.vstack([home_pose(), plan.poses]))
    travel = float(np.sum(move_time(legs[:-1], legs[1:], MotionLimits())))
    assert np.isclose(travel, plan.travel_s, rtol=1e-9)
    assert plan.platform_time_s <= check.CHECK_BUDGET_S


def test_an_unchanged_platform_is_within_tolerance(calibrated):
    data = run_check(calibrated, calibrated[0].true, seed=41)
    assert data['verdict'] == 'within tolerance', data['reasons']
    assert data['moved'] == [] and data['moved_legs'] == []
    accuracy = data['accuracy']
    assert accuracy['position_mm_mean'] < 0.01 and accuracy['position_mm_sigma'] > 0


def test_a_20_um_leg_offset_change_says_recalibrate_and_names_the_leg(calibrated):
    data = run_check(calibrated, changed_truth(calibrated[0].true, 'Loff3', 20e-6), seed=41)
    assert data['verdict'] == 'recalibrate'
    assert data['moved_legs'] == [3], data['moved']
    (moved,) = data['moved']
    assert abs(moved['change_report'] - 0.020) < 4 * moved['sigma_report']
    assert 'changed since its calibration (Loff3)' in data['reasons'][0]


def test_an_accuracy_that_misses_the_requirement_says_recalibrate(calibrated):
    # Unchanged platform, a phi requirement no calibration meets: the likeliest leg is named.
    tight = acceptance.Requirement(position_mm=0.05, orientation_deg=1e-9)
    data = run_check(calibrated, calibrated[0].true, seed=41, required=tight)
    assert data['verdict'] == 'recalibrate'
    assert [reason.split()[0] for reason in data['reasons']] == ['phi']
    assert len(data['moved']) == 1 and data['moved'][0]['likely']
    # The changed platform against 0.01 mm: both the accuracy and the change say so.
    tight = acceptance.Requirement(position_mm=0.01, orientation_deg=0.01)
    changed = changed_truth(calibrated[0].true, 'Loff3', 20e-6)
    data = run_check(calibrated, changed, seed=41, required=tight)
    assert [reason.split()[0] for reason in data['reasons']] == ['position', 'the']


def test_the_calibration_share_is_what_a_controller_error_does_to_the_check(calibrated):
    # Against the truth: a controller whose A3x is 10 um off, noise-free rows of the real platform.
    design, controller, _, plan = calibrated
    error = np.zeros(len(check.CHECK_PARAMETERS) + 1)
    names = check.CHECK_PARAMETERS + ('A3x',)
    error[-1] = 10e-6
    shifted = changed_truth(controller, 'A3x', 10e-6)
    truth = controller  # the platform is exactly the unshifted controller
    legs, readings, _, commanded = collect(truth, shifted, plan.poses, seed=0, sigmas=NO_NOISE)
    data = check.check_platform(shifted, legs, readings, commanded, ROWS, REQUIRED)
    seen = np.array(data['identification']['estimates_si']) - shifted.leg_offsets
    single = drift.Calibration(names, np.zeros(len(names)), np.outer(error, error))
    predicted = np.sqrt(np.diag(check.calibration_share(shifted, commanded, ROWS, single)))
    np.testing.assert_allclose(np.abs(seen), predicted, atol=0.05e-6)  # m


def test_a_posture_the_platform_already_holds_is_not_chosen(calibrated):
    # The platform stands at the plan's first posture (as after a calibration ending there).
    design, controller, _, plan = calibrated
    held = plan.pool_indices[0]
    again = check.choose_check_postures(controller, design.pool, design.pool[held], ROWS)
    assert held not in again.pool_indices


def grown_alike(true, change_m):
    for leg in range(1, 7):
        true = changed_truth(true, f'Loff{leg}', change_m)
    return true


def test_legs_grown_alike_within_the_requirement_are_within_tolerance(calibrated):
    # Thermal growth: every leg offset +10 um (the legs of a platform warmer than at its
    # calibration). The check sees the change and names no leg; it moves the platform by about
    # 0.01 mm, within the 0.05 mm required: within tolerance, with a note (before: recalibrate).
    data = run_check(calibrated, grown_alike(calibrated[0].true, 10e-6), seed=41)
    assert data['verdict'] == 'within tolerance', data['reasons']
    assert data['moved_legs'] == [] and data['reasons'] == [], data['moved']
    common = data['common_change']
    assert common['alike'] and abs(common['change_um'] - 10.0) < 4 * common['sigma_um']
    assert common['effect']['position_mm_bound'] < REQUIRED.position_mm
    assert data['notes'][0].startswith('warm up / common growth: all six leg offsets')
    # One leg moved is not a common change.
    moved = run_check(calibrated, changed_truth(calibrated[0].true, 'Loff3', 20e-6), seed=41)
    assert not moved['common_change']['alike'] and moved['moved_legs'] == [3]


def test_legs_grown_alike_beyond_the_requirement_say_warm_up_and_name_no_leg(calibrated):
    # Every leg offset +10 um against a requirement of 0.005 mm, which their common change
    # exceeds: recalibrate, the reason is the common growth, and no leg is named.
    tight = acceptance.Requirement(position_mm=0.005, orientation_deg=0.01)
    data = run_check(calibrated, grown_alike(calibrated[0].true, 10e-6), seed=41, required=tight)
    assert data['verdict'] == 'recalibrate' and data['moved_legs'] == [], data['moved']
    common = data['common_change']
    assert common['alike'] and common['effect']['position_mm_bound'] > tight.position_mm
    assert any(reason.startswith('warm up / common growth') for reason in data['reasons'])
    assert 'beyond the required accuracy' in data['reasons'][-1]


def test_a_leg_moved_on_legs_grown_alike_is_named(calibrated):
    # Every leg +10 um (warmer) and leg 3 another +20 um: the common change is taken out before
    # the legs are named, so leg 3 is named alone (without: legs 2, 4 and 5 were named).
    true = grown_alike(changed_truth(calibrated[0].true, 'Loff3', 20e-6), 10e-6)
    data = run_check(calibrated, true, seed=41)
    common = data['common_change']
    assert common['significant'] and not common['alike']
    assert data['verdict'] == 'recalibrate' and data['moved_legs'] == [3], data['moved']
