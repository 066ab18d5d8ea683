"""Cross-validated accuracy: the noise it removes against Monte-Carlo, and the held-out error
against the truth on a platform with an error the 44-parameter model does not contain."""

import math

import numpy as np
import pytest
from cross_validations import validation_of

from gsp_kinematics.estimation import noise_from_data
from gsp_kinematics.estimation.identification import identify
from gsp_kinematics.estimation.verdict.comparison import leverage_ratios
from gsp_kinematics.estimation.verdict.cross_validation import (
    cross_validate,
    device_pose,
    fold_assignment,
    noise_removed,
    noise_variances,
)
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.model.validation import sensor_measurements

SAMPLES = 10
ROWS = DEFAULT_SENSOR_NOISE.averaged([SAMPLES])


def smooth_leg_error(poses, amplitude=5e-6):
    """A leg-length error (M, 6) m that is a smooth function of the pose and no geometry: a
    sag that grows with the platform's offset from the centre, different on each leg."""
    legs = np.arange(6)
    x, y = poses[:, 0:1], poses[:, 1:2]
    return amplitude * np.sin(8.0 * x + 3.0 * legs) * np.cos(6.0 * y - legs)


def rows(truth, poses, rng, leg_error=None):
    """Averaged rows of ``poses`` (noise of ``SAMPLES`` samples; None rng: noise-free)."""
    legs, readings = sensor_measurements(truth, poses)
    if leg_error is not None:
        legs = legs + leg_error(poses)
    if rng is not None:
        legs = legs + rng.normal(0.0, ROWS.leg_lengths, legs.shape)
        readings = readings + rng.normal(0.0, 1.0, readings.shape) * ROWS.readings()
    return legs, readings


def test_folds_interleave_and_leave_one_out_when_few():
    assert fold_assignment(25, 10).tolist()[:12] == [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0, 1]
    assert fold_assignment(7, 10).tolist() == list(range(7))
    with pytest.raises(ValueError):
        fold_assignment(10, 1)


def test_the_device_pose_is_the_true_position_and_phi(exact, moderate_postures):
    _, readings = sensor_measurements(exact, moderate_postures)
    position, phi = device_pose(exact, readings)
    assert np.abs(position - moderate_postures[:, :3]).max() < 1e-12  # m
    assert np.abs(phi - moderate_postures[:, 5]).max() < 1e-12  # rad


def test_noise_variances_match_monte_carlo(exact, moderate_postures):
    """The propagated noise of a prediction error against the scatter of the errors of many
    noisy copies of the same rows (legs through FK, device through eq 9)."""
    poses = moderate_postures[:8]
    legs, readings = sensor_measurements(exact, poses)
    rng = np.random.default_rng(3)
    draws = 3000
    position = np.zeros((draws, len(poses), 3))
    phi = np.zeros((draws, len(poses)))
    from gsp_kinematics.estimation.verdict.cross_validation import prediction_errors

    for k in range(draws):
        noisy_legs = legs + rng.normal(0.0, ROWS.leg_lengths, legs.shape)
        noisy = readings + rng.normal(0.0, 1.0, readings.shape) * ROWS.readings()
        position[k], phi[k], _ = prediction_errors(exact, noisy_legs, noisy, poses)
    expected_position, expected_phi = noise_variances(exact, poses, readings, ROWS)
    measured_position = np.sum(position.var(axis=0), axis=1)
    # 3000 draws: the variance is known to about 2.6 % (sqrt(2 / 3000)); 10 % per posture.
    assert np.allclose(measured_position, expected_position, rtol=0.1)
    assert np.allclose(phi.var(axis=0), expected_phi, rtol=0.1)


def test_noise_removed_takes_the_noise_out_in_quadrature():
    rng = np.random.default_rng(5)
    model = np.full(20000, 3.0)
    noise = rng.normal(0.0, 4.0, model.shape)
    mean, p95, rms, factor = noise_removed(np.abs(model + noise), np.full(model.shape, 16.0))
    assert rms == pytest.approx(3.0, rel=0.05)
    assert factor == pytest.approx(3.0 / 5.0, rel=0.05)
    assert noise_removed(np.ones(3), np.full(3, 4.0))[0] == 0.0  # never negative


def test_the_headline_is_the_workspace_postures_held_out_error():
    """With workspace rows, the measured accuracy is theirs (the selected postures, the
    workspace's extremes, are a figure apart); without, every posture's."""
    count = 8
    workspace = np.arange(count) >= 5
    position = np.zeros((count, 3))
    position[:, 0] = np.where(workspace, 1e-3, 5e-3)  # m: 1 mm on the workspace postures
    validation = validation_of(position, 4)
    summary = validation.summary(workspace)
    assert summary['measured_on'] == 'workspace' and summary['workspace_rows'] == [5, 6, 7]
    assert summary['postures'] == 3
    assert summary['calibrated']['position_mm']['mean'] == pytest.approx(1.0)
    assert summary['nominal']['position_mm']['mean'] == pytest.approx(10.0)
    assert summary['selected']['postures'] == 5
    assert summary['selected']['calibrated']['position_mm']['mean'] == pytest.approx(5.0)
    everything = validation.summary()
    assert everything['measured_on'] == 'selected' and 'selected' not in everything
    assert everything['calibrated']['position_mm']['mean'] == pytest.approx(3.5)


def _device_only(geometry, sigma):
    """A result whose only uncertain parameter is D0 (standard deviation ``sigma``, m): the
    device's own error, which the legs do not share."""
    import types

    from gsp_kinematics.model.geometry import ALL_PARAMETER_NAMES

    free = np.zeros(len(ALL_PARAMETER_NAMES), bool)
    free[[ALL_PARAMETER_NAMES.index('Loff1'), ALL_PARAMETER_NAMES.index('D0')]] = True
    return types.SimpleNamespace(
        free=free, covariance=np.diag([0.0, sigma**2]), geometry=geometry, effect_free=None
    )


def test_the_device_own_error_is_in_the_comparison_not_in_the_truth(exact, moderate_postures):
    """An uncertainty of D0 alone (sigma) moves what the device measures along the link by sigma
    at every posture and leaves the controller's pose alone: the held-out comparison holds
    sigma^2 the truth does not, so it is subtracted (an unseen part of -sigma^2), not added."""
    from gsp_kinematics.estimation.verdict.comparison import comparison_variances

    sigma = 4e-6
    poses = moderate_postures[:10]
    _, readings = sensor_measurements(exact, poses)
    (controller, _), (comparison, comparison_phi) = comparison_variances(
        _device_only(exact, sigma), poses, readings
    )
    np.testing.assert_allclose(comparison, sigma**2, rtol=1e-3)
    assert np.all(np.abs(controller) < 1e-20) and np.all(np.abs(comparison_phi) < 1e-20)
    position = np.zeros((10, 3))
    position[:, 0] = 5e-6  # m: 3 um of the fit's error (+) the device's 4 um
    validation = validation_of(position, 2, position_unseen=controller - comparison)
    assert validation.summary()['calibrated']['position_mm']['mean'] == pytest.approx(
        3e-3, rel=1e-3
    )
    assert validation.summary()['calibrated']['position_mm']['unseen_rms'] == pytest.approx(
        -4e-3, rel=1e-3
    )


def test_the_comparison_sensitivities_match_finite_differences(
    exact, nominal_sets, moderate_postures
):
    """Forward kinematics minus the device, per free parameter, against finite differences of
    the prediction errors (per column: to 1e-3 of the column's largest, position and phi)."""
    from gsp_kinematics.estimation.verdict.comparison import comparison_sensitivities
    from gsp_kinematics.estimation.verdict.cross_validation import prediction_errors
    from gsp_kinematics.model.geometry import ALL_PARAMETER_NAMES, Geometry

    legs, readings = sensor_measurements(exact, moderate_postures)
    result = identify(
        nominal_sets[1], legs, readings, ROWS, free='extended', pose_guesses=moderate_postures
    )
    poses, legs, readings = moderate_postures[:12], legs[:12], readings[:12]
    geometry = result.geometry
    _, comparison = comparison_sensitivities(result, poses, readings)
    vector = geometry.to_full_vector()
    names = [n for n, on in zip(ALL_PARAMETER_NAMES, result.free, strict=True) if on]
    step = 1e-6  # central differences: FK converges to 1e-12 m
    for column, name in enumerate(names):
        moved = []
        for sign in (1.0, -1.0):
            shifted = vector.copy()
            shifted[ALL_PARAMETER_NAMES.index(name)] += sign * step
            shifted_geometry = Geometry.from_full_vector(shifted, geometry.limits)
            moved.append(prediction_errors(shifted_geometry, legs, readings, poses))
        position = (moved[0][0] - moved[1][0]) / (2 * step)
        phi = (moved[0][1] - moved[1][1]) / (2 * step)
        expected = np.concatenate([position, phi[:, None]], axis=1)
        scale = max(float(np.abs(expected).max()), 1e-9)
        assert np.abs(comparison[:, :, column] - expected).max() < 1e-3 * scale, name


def test_the_device_sensitivities_match_finite_differences(exact, nominal_sets, moderate_postures):
    """What the device measures, per device parameter (D0, gamma, alpha0, beta0, phi0, kDm),
    against central differences of eq 9 with the sensor errors (per column: to 1e-6 of the
    column's largest), at a geometry with every sensor error nonzero; zero for the others."""
    import dataclasses

    from gsp_kinematics.estimation.verdict.comparison import DEVICE_PARAMETERS, device_sensitivities
    from gsp_kinematics.model.geometry import ALL_PARAMETER_NAMES, Geometry

    legs, readings = sensor_measurements(exact, moderate_postures)
    result = identify(
        nominal_sets[1], legs, readings, ROWS, free='extended', pose_guesses=moderate_postures
    )
    vector = result.geometry.to_full_vector()
    for name, value in zip(
        ('alpha0', 'beta0', 'phi0', 'kDm'), (2e-3, -3e-3, 5e-3, 4e-3), strict=True
    ):
        vector[ALL_PARAMETER_NAMES.index(name)] = value
    geometry = Geometry.from_full_vector(vector, result.geometry.limits)
    result = dataclasses.replace(result, geometry=geometry)
    readings = readings[:12]
    position, phi = device_sensitivities(result, readings)
    names = [n for n, on in zip(ALL_PARAMETER_NAMES, result.free, strict=True) if on]
    step = 1e-7
    for column, name in enumerate(names):
        moved = []
        for sign in (1.0, -1.0):
            shifted = vector.copy()
            shifted[ALL_PARAMETER_NAMES.index(name)] += sign * step
            moved.append(device_pose(Geometry.from_full_vector(shifted, geometry.limits), readings))
        expected = np.concatenate(
            [(moved[0][0] - moved[1][0]), (moved[0][1] - moved[1][1])[:, None]], axis=1
        ) / (2 * step)
        got = np.concatenate([position[:, :, column], phi[:, column, None]], axis=1)
        if name not in DEVICE_PARAMETERS:
            assert not got.any() and np.abs(expected).max() == 0.0, name
            continue
        scale = float(np.abs(expected).max())
        assert scale > 0.0 and np.abs(got - expected).max() < 1e-6 * scale, name


def test_the_unseen_part_is_added_to_every_figure():
    count = 4
    workspace = np.array([False, False, True, True])
    position = np.zeros((count, 3))
    position[:, 0] = 3e-3
    validation = validation_of(position, 2, position_unseen=np.full(count, (4e-3) ** 2))
    summary = validation.summary(workspace)
    assert summary['calibrated']['position_mm']['mean'] == pytest.approx(5.0)  # 3 (+) 4 mm
    assert summary['calibrated']['position_mm']['unseen_rms'] == pytest.approx(4.0)
    assert summary['selected']['calibrated']['position_mm']['mean'] == pytest.approx(5.0)
    assert summary['calibrated']['position_mm']['measured_mean'] == pytest.approx(3.0)
    assert validation.summary()['calibrated']['position_mm']['mean'] == pytest.approx(5.0)


def test_the_leverage_scales_a_held_out_error_to_the_full_fit_but_not_a_model_error():
    """A posture the fit without it predicts with 100x the full fit's variance keeps 1 % of its
    excess over the noise; a model error (the unmodelled part) is in both fits and keeps its
    size; an unknown variance corrects nothing."""
    ratios = leverage_ratios([1.0, 1.0, 1.0, 2.0], [100.0, 100.0, np.nan, 1.0], [0.0, 1e4, 0, 0])
    np.testing.assert_allclose(ratios, [0.01, 10001.0 / 10100.0, 1.0, 1.0], rtol=1e-6)
    # The rms is the signal's, sum(r (e^2 - n)) / K, whatever the shape.
    _, _, rms, _ = noise_removed([10.0, 6.0], [4.0, 16.0], None, [0.01, 0.5], [100.0, 100.0])
    assert rms**2 * 2 == pytest.approx(0.01 * 96.0 + 0.5 * 20.0)
    # An excess beyond 3 standard deviations of the held-out prediction is a model error: kept.
    # (The cap is 9 times the predicted variance, the held-out fit's and the noise's: 9 (50 + 4)
    # and 9 (1 + 4), less the noise.)
    _, _, rms, _ = noise_removed([20.0, 20.0], [4.0, 4.0], None, [0.01, 0.01], [50.0, 1.0])
    assert rms**2 * 2 == pytest.approx(0.01 * 396.0 + 0.01 * 41.0 + 355.0)


def test_the_leverage_corrected_mean_keeps_the_shape_of_the_errors():
    """Held-out errors = the full fit's error (3-D Gaussian, variance p) + the fold's ignorance
    (h - p) + noise (n), as on the ideal platform (p, h, n = 7.7, 18.4, 64 um^2): with the
    leverage r = p / h and the noise taken out, the mean is the full fit's mean error, not
    that of magnitudes shrunk towards the noise's (a constant), which is 8 % more."""
    rng = np.random.default_rng(7)
    count, full, held, noise = 40000, 7.7, 18.4, 64.0
    signal = rng.normal(size=(count, 3)) * math.sqrt(full / 3)
    extra = rng.normal(size=(count, 3)) * math.sqrt((held - full) / 3)
    measured = signal + extra + rng.normal(size=(count, 3)) * math.sqrt(noise / 3)
    truth = float(np.mean(np.linalg.norm(signal, axis=1)))
    mean, _, rms, _ = noise_removed(
        np.linalg.norm(measured, axis=1),
        np.full(count, noise),
        None,
        np.full(count, full / held),
        np.full(count, held),
    )
    assert rms == pytest.approx(math.sqrt(full), rel=0.03)
    assert mean == pytest.approx(truth, rel=0.03)


def test_the_requirement_is_judged_on_the_larger_of_the_workspace_and_selected_figures():
    """The workspace postures cannot see an error the device's own parameters share with the
    legs; the selected postures' larger errors bound it: a run is judged on the larger."""
    from gsp_kinematics.estimation.verdict.acceptance import Requirement, judge

    def figures(position_mm):
        return {
            'position_mm': {'mean': position_mm, 'p95': position_mm},
            'phi_deg': {'mean': 0.001, 'p95': 0.001},
        }

    accuracy = {
        'folds': 10,
        'postures': 20,
        'measured_on': 'workspace',
        'calibrated': figures(0.05),
        'nominal': figures(5.0),
        'selected': {'postures': 60, 'calibrated': figures(0.15), 'nominal': figures(5.0)},
    }
    verdict = judge(accuracy, Requirement())
    assert not verdict.accepted
    assert any(f.startswith('position 0.15 mm exceeds') for f in verdict.failures), verdict.failures
    accuracy['selected']['calibrated'] = figures(0.08)
    assert judge(accuracy, Requirement()).accepted


@pytest.fixture(scope='module')
def smooth_platform(exact, nominal_sets, moderate_postures):
    """The exact platform with a smooth leg error; 60 postures fitted from nominal set 1."""
    nominal = nominal_sets[1]
    clean = rows(exact, moderate_postures, None, smooth_leg_error)
    noisy = rows(exact, moderate_postures, np.random.default_rng(11), smooth_leg_error)
    fits = [
        identify(nominal, legs, readings, ROWS, free='paper', pose_guesses=moderate_postures)
        for legs, readings in (clean, noisy)
    ]
    assert all(fit.converged for fit in fits)
    return nominal, clean, noisy, fits


def test_cross_validation_on_clean_data_sees_the_unmodelled_error(
    moderate_postures, smooth_platform
):
    """Noise-free rows of a platform the model does not contain: the cross-validated error is
    what the fitted geometry cannot explain (tens of um), the nominal baseline 100x more."""
    nominal, (legs, readings), _, (fit, _) = smooth_platform
    cv = cross_validate(fit, nominal, legs, readings, ROWS)
    summary = cv.summary()
    assert cv.folds == 10 and cv.predicted == len(moderate_postures) and not cv.failed_folds
    calibrated = summary['calibrated']['position_mm']
    nominal_mm = summary['nominal']['position_mm']
    assert 1e-3 < calibrated['measured_mean'] < 0.05  # um: the smooth error
    assert nominal_mm['measured_mean'] > 100 * calibrated['measured_mean']
    # Every posture was predicted by a fit that did not see it: its fold's.
    assert set(cv.fold_of_posture.tolist()) == set(range(10))
    assert np.all(np.isfinite(cv.position_error)) and np.all(np.isfinite(cv.phi_error))


def test_noise_removed_cross_validation_agrees_with_the_clean_one(smooth_platform):
    """Noisy rows: with the propagated noise taken out, the cross-validated accuracy is within
    25 % of the noise-free one (the held-out error against the truth), the raw figure is not."""
    nominal, clean, noisy, (clean_fit, noisy_fit) = smooth_platform
    # At the run's postures (no transfer to the workspace: these are within +-25 deg).
    truth = cross_validate(clean_fit, nominal, *clean, ROWS, workspace=None).summary()
    measured = cross_validate(noisy_fit, nominal, *noisy, ROWS, workspace=None).summary()
    truth, measured = truth['calibrated'], measured['calibrated']
    true_rms = truth['position_mm']['measured_mean']
    assert measured['position_mm']['measured_mean'] > 1.25 * true_rms  # the noise's share
    assert measured['position_mm']['mean'] == pytest.approx(true_rms, rel=0.25)
    assert math.isfinite(measured['phi_deg']['mean'])


def _within(rows, dof=5000.0):
    """The within-posture estimate a run of well-sampled windows gives (the rows' true noise)."""
    return {
        channel: noise_from_data.WithinNoise(value, dof, SAMPLES, False)
        for channel, value in rows.channels().items()
    }


@pytest.fixture(scope='module')
def strong_smooth(exact, nominal_sets, moderate_postures):
    """Noisy rows of the exact platform with a 30 um smooth leg error, fitted with the noise
    estimated from the run (the calibrator's default)."""
    rng = np.random.default_rng(21)
    legs, readings = rows(exact, moderate_postures, rng, lambda p: smooth_leg_error(p, 30e-6))
    return legs, readings


def test_the_unmodelled_error_is_kept_apart_from_the_noise(
    nominal_sets, moderate_postures, strong_smooth
):
    """The legs' noise stays their noise (the within estimate); the excess of the residuals
    between postures is the unmodelled part, of the order of the smooth error;
    and a smooth field names no outlier."""
    legs, readings = strong_smooth
    result, estimates, _ = noise_from_data.identify_with_noise(
        'estimated', nominal_sets[1], legs, readings, ROWS, _within(ROWS),
        free='paper', pose_guesses=moderate_postures,
    )  # fmt: skip
    assert not result.goodness_of_fit.accepted
    assert estimates['leg_lengths'].noise == pytest.approx(ROWS.leg_lengths)
    unmodelled = noise_from_data.unmodelled_error(estimates)
    # The weights put the 30 um leg error where it is cheapest: in the legs and, through the
    # estimated poses, in the inclinations (about 1 m of link: 1 urad is 1 um).
    assert 10e-6 < unmodelled.leg_lengths + 1.0 * unmodelled.inclinometer < 60e-6
    assert result.outliers == []
    record = noise_from_data.noise_record(estimates, DEFAULT_SENSOR_NOISE, [SAMPLES])
    assert record['leg_lengths']['estimated'] == pytest.approx(DEFAULT_SENSOR_NOISE.leg_lengths)
    assert not record['leg_lengths']['warning']


def test_a_bad_row_in_a_smooth_field_is_still_named(nominal_sets, moderate_postures, strong_smooth):
    legs, readings = strong_smooth
    legs = legs.copy()
    legs[17, 2] += 0.5e-3  # a glitch on leg 3
    result, _, _ = noise_from_data.identify_with_noise(
        'estimated', nominal_sets[1], legs, readings, ROWS, _within(ROWS),
        free='paper', pose_guesses=moderate_postures,
    )  # fmt: skip
    assert [entry['posture'] for entry in result.outliers] == [17]


def test_the_prediction_adds_the_unmodelled_part(exact, moderate_postures):
    from gsp_kinematics.estimation.prediction import assumption, predicted_errors
    from gsp_kinematics.model.geometry import NUM_PARAMETERS
    from gsp_kinematics.model.sensor_noise import SensorNoise

    covariance = np.eye(NUM_PARAMETERS) * 1e-12
    alone, _ = predicted_errors(exact, covariance, moderate_postures[:5])
    unmodelled = SensorNoise(10e-6, 0.0, 0.0, 0.0)
    added, _ = predicted_errors(exact, covariance, moderate_postures[:5], unmodelled=unmodelled)
    only, _ = predicted_errors(exact, covariance * 0.0, moderate_postures[:5], None, unmodelled)
    # Independent parts add in quadrature (E|v| of a 3-D Gaussian: to within a few %).
    assert np.allclose(added, np.hypot(alone, only), rtol=0.1)
    assert np.all(only > 5e-3)  # 10 um in each leg moves the platform by several um (mm here)
    assert 'exactly the model' in assumption(None) and '10 um rms' in assumption(unmodelled)


def test_on_an_ideal_platform_the_measured_accuracy_is_the_true_one(exact, nominal_sets):
    """The calibrator's plan on an ideal platform (60 postures selected from 600: the
    workspace's extremes), 24 noisy runs: the measured accuracy (held out, its leverage and
    noise taken out, the part no held-out posture sees added, carried to the workspace) against
    the true mean position error of the calibrated controller over 100 random workspace
    postures: the means over the runs within 12 %. Per run both scatter by tens of percent (the
    truth holds a draw of the error the legs share with the device); the estimator that added
    the device's own variance, took the leverage of the controller's variance and the shape of
    magnitudes shrunk towards the noise read 1.17x here."""
    from gsp_kinematics.estimation.identification import resolve_free
    from gsp_kinematics.model.kinematics import Workspace, sample_valid_postures
    from gsp_kinematics.model.validation import validate
    from gsp_kinematics.planning.selection import select_postures

    nominal = nominal_sets[1]
    pool = sample_valid_postures(nominal, 600, np.random.default_rng(0), Workspace())
    free = resolve_free(['extended'])
    chosen, _ = select_postures(nominal, pool, 60, ROWS, free=free, formulation='implicit')
    poses = pool[chosen]
    check = sample_valid_postures(exact, 100, np.random.default_rng(9), Workspace())
    exact_legs, exact_readings = sensor_measurements(exact, poses)
    measured, true = [], []
    for seed in range(24):
        rng = np.random.default_rng(seed)
        legs = exact_legs + rng.normal(0.0, ROWS.leg_lengths, exact_legs.shape)
        readings = exact_readings + rng.normal(size=exact_readings.shape) * ROWS.readings()
        fit = identify(nominal, legs, readings, ROWS, free=free, pose_guesses=poses)
        summary = cross_validate(fit, nominal, legs, readings, ROWS).summary()
        measured.append(summary['calibrated']['position_mm']['mean'])
        true.append(validate(exact, fit.geometry, check)['position_mm_mean'])
    assert sum(measured) / sum(true) == pytest.approx(1.0, abs=0.12)
