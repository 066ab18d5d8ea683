"""The pure calibration pipeline on synthetic data from the core (no ROS)."""

import math
import re

import numpy as np
import pytest

from gsp_calibrator.files.run_directory import Rows
from gsp_calibrator.run import postures
from gsp_calibrator.run.identify import identify_from_samples
from gsp_calibrator.run.response import (
    NOT_ACCEPTED_HEAD,
    final_progress_message,
    format_response,
    outcome_summary,
    parse_response,
    posture_residuals,
)
from gsp_kinematics.estimation.identification import Options
from gsp_kinematics.estimation.noise_from_data import posture_lag_sums
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import default_geometry, geometry_from_yaml, parameter_errors
from gsp_kinematics.model.kinematics import (
    check_reachable,
    forward_kinematics_masked,
    inverse_kinematics,
)
from gsp_kinematics.model.sensor_noise import SensorNoise

NOMINAL = default_geometry('nominal')
TRUE = default_geometry('true')
SIGMAS = SensorNoise()  # Table 3, first level


def synthetic_samples(
    poses, n_samples=10, seed=1, true=TRUE, nominal=NOMINAL, sigmas=SIGMAS, windows=False
):
    """Rows as the calibrator would collect them: nominal controller, true platform, noise
    averaged over ``n_samples`` samples; postures FK cannot reach are left out. ``windows``:
    draw each window's samples and keep their lag sums (the within-posture estimate), else
    draw the rows' noise only."""
    rng = np.random.default_rng(seed)
    q = nominal.sensors.leg_readings(inverse_kinematics(nominal, poses))
    real, ok = forward_kinematics_masked(true, true.sensors.true_leg_lengths(q), poses)
    readings = true.sensors.device_readings(device_readings(true, real[ok]))
    scale = 1.0 / math.sqrt(n_samples)
    samples = Rows.empty()
    for k, (pose, legs, reading) in enumerate(zip(poses[ok], q[ok], readings, strict=True), 1):
        lag_sums = None
        if windows:
            window = np.concatenate([legs, reading]) + rng.normal(
                size=(n_samples, 10)
            ) * np.concatenate([np.full(6, sigmas.leg_lengths), sigmas.readings()])
            legs, reading = window[:, :6].mean(axis=0), window[:, 6:].mean(axis=0)
            lag_sums = posture_lag_sums(window)
        else:
            legs = legs + rng.normal(0, sigmas.leg_lengths * scale, 6)
            reading = reading + rng.normal(0, 1, 4) * sigmas.readings() * scale
        samples.append(k, pose, legs, reading, n_samples, 1.7e9 + k, lag_sums)
    return samples


@pytest.fixture(scope='module')
def selection():
    return postures.choose_postures(NOMINAL, 40, 300, seed=3)


def test_choose_postures_is_seeded_and_reachable(selection):
    assert selection.poses.shape == (40, 6) and len(set(selection.pool_indices)) == 40
    assert np.all(check_reachable(NOMINAL, selection.poses)[0])
    assert math.isfinite(selection.condition_number) and selection.condition_number > 1
    again = postures.choose_postures(NOMINAL, 40, 300, seed=3)
    # Bit-equal: the same operations in the same process (the seed decides, not the kernel).
    np.testing.assert_array_equal(again.poses, selection.poses)
    other = postures.choose_postures(NOMINAL, 40, 300, seed=4)
    assert not np.array_equal(other.poses, selection.poses)


def test_choose_postures_rejects_bad_counts():
    with pytest.raises(postures.CalibrationError, match='pool_size'):
        postures.choose_postures(NOMINAL, 10, 5, seed=0)
    with pytest.raises(postures.CalibrationError, match='>= 1'):
        postures.choose_postures(NOMINAL, 0, 5, seed=0)


def test_selection_key_changes_with_its_inputs():
    key = postures.selection_key(NOMINAL, 60, 600, 0, SIGMAS, None, 'implicit')
    assert key == postures.selection_key(NOMINAL, 60, 600, 0, SIGMAS, None, 'implicit')
    assert key != postures.selection_key(NOMINAL, 60, 600, 1, SIGMAS, None, 'implicit')
    assert key != postures.selection_key(NOMINAL, 60, 600, 0, SIGMAS, ['D0'], 'implicit')
    assert key != postures.selection_key(TRUE, 60, 600, 0, SIGMAS, None, 'implicit')
    # fk and paper select with the same (FK) information model.
    assert postures.selection_key(
        NOMINAL, 60, 600, 0, SIGMAS, None, 'fk'
    ) == postures.selection_key(NOMINAL, 60, 600, 0, SIGMAS, None, 'paper')


@pytest.mark.parametrize('formulation', ['implicit', 'fk'])
def test_identification_recovers_the_true_geometry(selection, formulation):
    samples = synthetic_samples(selection.poses)
    outcome = identify_from_samples(
        NOMINAL, samples, SIGMAS, formulation=formulation, noise_source='configured'
    )
    assert outcome.success, outcome.message
    assert outcome.postures == len(samples) and outcome.duration_s > 0
    errors = parameter_errors(outcome.geometry, TRUE)
    assert np.max(np.abs(errors[:43])) < 0.05  # mm (nominal errors are up to ~5 mm)
    assert abs(errors[43]) < 0.01  # deg
    assert outcome.identifiability['rank'] == 51  # extended
    assert outcome.identifiability['names'] == []
    assert outcome.fit_accepted, outcome.fit_diagnosis
    # Averaged rows weigh as sigma / sqrt(n).
    assert outcome.sigmas.leg_lengths == pytest.approx(SIGMAS.leg_lengths / math.sqrt(10))


def test_a_subset_of_free_parameters_keeps_the_others_nominal(selection):
    samples = synthetic_samples(selection.poses)
    outcome = identify_from_samples(
        NOMINAL, samples, SIGMAS, free=['Loff1', 'Loff2', 'D0', 'gamma']
    )
    assert outcome.success, outcome.message
    vector, nominal = outcome.geometry.to_vector(), NOMINAL.to_vector()
    assert outcome.result.free.sum() == 4
    np.testing.assert_array_equal(vector[:36], nominal[:36])


@pytest.mark.parametrize('free', [postures.DEFAULT_FREE, ['auto']])
def test_too_few_postures_name_the_unidentifiable_parameters(selection, free):
    """With ``auto`` too: the plain model cannot be judged, no group is tried (the choice says
    why) and the plain model's own message names the parameters."""
    samples = synthetic_samples(selection.poses[:6])
    outcome = identify_from_samples(NOMINAL, samples, SIGMAS, free=free)
    assert not outcome.success and outcome.geometry is None
    assert 'non-identifiable parameters' in outcome.message
    names = outcome.identifiability['names']
    assert names and all(name in outcome.message for name in names)
    assert outcome.identifiability['rank'] < 44
    assert 'nothing applied' in outcome.message
    if 'auto' in free:
        choice = outcome.effects['model_choice']
        assert choice['groups'] == [] and 'no effect group tried' in choice['reason']


def test_no_convergence_is_a_failure(selection):
    samples = synthetic_samples(selection.poses)
    outcome = identify_from_samples(NOMINAL, samples, SIGMAS, options=Options(max_iterations=1))
    assert not outcome.success and outcome.geometry is None
    assert 'did not converge' in outcome.message


def test_no_samples_is_a_failure():
    outcome = identify_from_samples(NOMINAL, Rows.empty(), SIGMAS)
    assert not outcome.success and 'no posture' in outcome.message


def test_bad_inputs_are_a_failure_not_an_exception(selection):
    samples = synthetic_samples(selection.poses[:12])
    samples.readings[3, 1] = np.nan
    outcome = identify_from_samples(NOMINAL, samples, SIGMAS)
    assert not outcome.success and 'identification failed' in outcome.message
    with pytest.raises(postures.CalibrationError, match='formulation'):
        identify_from_samples(NOMINAL, samples, SIGMAS, formulation='magic')


def test_response_round_trip(selection, tmp_path):
    samples = synthetic_samples(selection.poses)
    outcome = identify_from_samples(NOMINAL, samples, SIGMAS)
    summary = outcome_summary(
        outcome, selected=40, skipped=[(7, 'rejected: far')], run_directory=tmp_path, reference=TRUE
    )
    assert summary.splitlines()[0].startswith('calibration succeeded')
    assert 'skipped posture 7: rejected: far' in summary
    message = format_response(summary, outcome.geometry)
    parsed = parse_response(message)
    assert parsed.summary == summary and parsed.run_directory == str(tmp_path)
    assert parsed.identification_ms == pytest.approx(outcome.duration_s * 1000.0, abs=0.1)
    np.testing.assert_array_equal(
        geometry_from_yaml(parsed.geometry_yaml).to_vector(), outcome.geometry.to_vector()
    )
    failed = parse_response('calibration FAILED: no posture')
    assert failed.geometry_yaml == '' and failed.run_directory == ''
    assert math.isnan(failed.identification_ms)


def test_posture_residuals_against_the_nominal_model(selection):
    pose = selection.poses[0]
    q = inverse_kinematics(NOMINAL, pose[None])[0]
    readings = device_readings(NOMINAL, pose[None])[0]
    residuals = posture_residuals(NOMINAL, pose, q, readings)
    assert set(residuals) == {'leg_lengths', 'alpha', 'beta', 'phi', 'd_m'}
    assert max(abs(v) for v in residuals.values()) < 1e-12
    residuals = posture_residuals(NOMINAL, pose, q + 1e-3, readings + [0, 0, 0, 2e-3])
    assert residuals['leg_lengths'] == pytest.approx(1e-3) and residuals['d_m'] == pytest.approx(
        2e-3
    )


def test_paper_model_on_sensor_errors_is_not_accepted_with_a_verdict(selection):
    """The 44 on a platform with sensor errors: the accuracy the device measures on held-out
    postures misses the required 0.1 mm, so the result is not accepted, and the summary says by
    how much; the goodness of fit names the likely cause as a diagnostic."""
    samples = synthetic_samples(selection.poses)
    outcome = identify_from_samples(
        NOMINAL, samples, SIGMAS, free=['paper'], noise_source='configured'
    )
    assert outcome.success and not outcome.fit_accepted and not outcome.accepted
    assert 'does NOT explain the data' in outcome.fit_diagnosis
    assert 'try free_parameters: extended' in outcome.fit_diagnosis
    summary = outcome_summary(outcome)
    assert summary.startswith(NOT_ACCEPTED_HEAD)
    assert 'exceeds the required 0.1 mm' in summary
    extended = identify_from_samples(NOMINAL, samples, SIGMAS, noise_source='configured')
    assert extended.fit_accepted and 'explains the data' in extended.fit_diagnosis
    assert extended.accepted
    assert 'sensor errors: kq1 ' in outcome_summary(extended)


def test_noise_estimates_warn_when_the_configured_sigma_is_wrong(selection):
    # The LVDT is three times noisier than configured.
    device = SensorNoise(SIGMAS.leg_lengths, SIGMAS.inclinometer, SIGMAS.encoder, 3 * SIGMAS.lvdt)
    samples = synthetic_samples(selection.poses, sigmas=device, windows=True)
    outcome = identify_from_samples(NOMINAL, samples, SIGMAS)
    estimates = outcome.noise_estimates
    assert estimates['leg_lengths']['estimated'] == pytest.approx(SIGMAS.leg_lengths, rel=0.1)
    assert estimates['lvdt']['warning'] and not estimates['inclinometer']['warning']
    assert 'sensor noise lvdt: configured' in outcome_summary(outcome)
    assert 'WARNING: differs by more than 2x' in outcome_summary(outcome)


def test_noise_3x_is_estimated_accepted_and_weighs_the_fit(selection):
    """The issue's scenario in the pure pipeline: every sensor 3x noisier than configured."""
    noisy = SensorNoise(*(3.0 * value for value in SIGMAS.channels().values()))
    samples = synthetic_samples(selection.poses, sigmas=noisy, seed=5, windows=True)
    outcome = identify_from_samples(NOMINAL, samples, SIGMAS)
    assert outcome.success and outcome.fit_accepted, outcome.fit_diagnosis
    assert outcome.noise_source == 'estimated' and 'lack-of-fit F test' in outcome.fit_diagnosis
    assert outcome.sigmas.leg_lengths == pytest.approx(noisy.leg_lengths / math.sqrt(10), rel=0.1)
    for channel, entry in outcome.noise_estimates.items():
        assert entry['source'] == 'pooled'
        assert entry['estimated'] == pytest.approx(getattr(noisy, channel), rel=0.1), channel
    configured = identify_from_samples(NOMINAL, samples, SIGMAS, noise_source='configured')
    assert configured.success and not configured.fit_accepted
    assert configured.result.outliers == [] and 'wrong sigmas' in configured.fit_diagnosis
    # The goodness of fit is a diagnostic: the accuracy measured on held-out postures decides.
    assert configured.accepted
    summary = outcome_summary(configured)
    assert summary.splitlines()[0].startswith('calibration succeeded:')
    assert 'does NOT explain the data' in summary
    assert 'weights from the configured noise' in summary
    with pytest.raises(postures.CalibrationError, match='noise_source'):
        identify_from_samples(NOMINAL, samples, SIGMAS, noise_source='guessed')


def test_last_progress_message_agrees_with_the_phase():
    rejected = f'{NOT_ACCEPTED_HEAD}: 60 posture(s) of 60 commanded\nmore'
    assert final_progress_message(rejected, False, '').startswith('calibration NOT ACCEPTED')
    assert (
        final_progress_message('calibration succeeded: 60\nx', False, 'NOT applied: why')
        == 'NOT applied: why'
    )
    assert (
        final_progress_message('calibration succeeded: 60\nx', True, 'applied')
        == 'calibration succeeded: 60'
    )


def test_rows_of_a_platform_elsewhere_fail_the_identification_naming_their_postures(selection):
    """Rows measured with the platform not where it was commanded (another assembly) would
    spoil every fit: the identification refuses them by name, as the collection does."""
    samples = synthetic_samples(selection.poses[:30])
    assert identify_from_samples(NOMINAL, samples, SIGMAS, max_posture_error=0.05).success
    samples.readings[[4, 9], 3] += 0.3  # m: the LVDT of postures 5 and 10 reads 300 mm long
    outcome = identify_from_samples(NOMINAL, samples, SIGMAS, max_posture_error=0.05)
    assert not outcome.success and outcome.geometry is None
    # 300 mm along the link, a few mm of it the geometry's error
    assert re.search(r'measures the platform 29\d-30\d mm from the commanded', outcome.message)
    assert 'posture(s) [5, 10] (max_posture_error 50 mm)' in outcome.message
