"""Predicted accuracy: pose sensitivities against finite differences, and the prediction against
Monte-Carlo identifications."""

import numpy as np
import pytest

from gsp_kinematics.estimation.identification import identify
from gsp_kinematics.estimation.prediction import (
    accuracy_summary,
    effect_pose_sensitivities,
    expected_norm,
    pose_sensitivities,
    predict_accuracy,
    predicted_errors,
    thermal_strain_rms,
)
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.effect_groups import EffectDesign, EffectTerms, commanded_leg_readings
from gsp_kinematics.model.effects import NUM_EFFECT_PARAMETERS, IdentifiedEffects
from gsp_kinematics.model.geometry import (
    NUM_ALL_PARAMETERS,
    NUM_PARAMETERS,
    PARAMETER_INDEX,
    Geometry,
)
from gsp_kinematics.model.kinematics import (
    forward_kinematics,
    forward_kinematics_masked,
    inverse_kinematics,
    leg_vectors,
)
from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_kinematics.model.validation import commanded_articular, validate
from gsp_kinematics.planning.selection import select_postures
from gsp_kinematics.rotation import euler_to_matrix


def reached_poses(true, controller, commanded):
    """Where the rigid real platform goes when ``controller`` drives ``commanded``."""
    return forward_kinematics(true, commanded_articular(true, controller, commanded), commanded)


def _rotation_vector(commanded, reached):
    relative = np.einsum('mji,mjk->mik', euler_to_matrix(commanded), euler_to_matrix(reached))
    skew = 0.5 * (relative - np.swapaxes(relative, 1, 2))
    return np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=1)


def _assert_columns_match_finite_differences(
    exact, poses, sensitivity, vector, columns, build, reach=reached_poses
):
    """Each column of ``sensitivity`` against a central difference of the reached pose when the
    controller's parameter ``vector[column]`` moves (``build``: vector -> controller geometry;
    ``reach(true, controller, poses)``: where the real platform goes)."""
    step = 1e-7
    for column in columns:
        moves = []
        for sign in (1.0, -1.0):
            moved = vector.copy()
            moved[column] += sign * step
            reached = reach(exact, build(moved), poses)
            moves.append(
                np.concatenate(
                    [reached[:, :3] - poses[:, :3], _rotation_vector(poses[:, 3:], reached[:, 3:])],
                    axis=1,
                )
            )
        numeric = (moves[0] - moves[1]) / (2 * step)
        scale = max(np.abs(numeric).max(), 1e-3)
        assert np.abs(numeric - sensitivity[:, :, column]).max() < 1e-5 * scale, column


def test_pose_sensitivities_match_finite_differences(exact, postures):
    poses = postures[:5]
    sensitivity = pose_sensitivities(exact, poses)
    assert sensitivity.shape == (5, 6, NUM_PARAMETERS)
    assert np.all(sensitivity[:, :, 42:] == 0.0)  # the device does not move the platform
    _assert_columns_match_finite_differences(
        exact,
        poses,
        sensitivity,
        exact.to_vector(),
        range(42),
        lambda moved: Geometry.from_vector(moved, exact.limits),
    )


def test_leg_gain_columns_match_finite_differences(exact, postures):
    """A controller's leg gain error moves the platform (the device sensors' errors do not)."""
    poses = postures[:5]
    sensitivity = pose_sensitivities(exact, poses, np.ones(NUM_ALL_PARAMETERS, dtype=bool))
    first_gain = PARAMETER_INDEX['kq1']
    others = [PARAMETER_INDEX[name] for name in ('alpha0', 'beta0', 'phi0', 'kDm')]
    assert np.all(sensitivity[:, :, others] == 0.0)
    _assert_columns_match_finite_differences(
        exact,
        poses,
        sensitivity,
        exact.to_full_vector(),
        range(first_gain, first_gain + 6),
        lambda moved: Geometry.from_full_vector(moved, exact.limits),
    )


def test_free_mask_selects_columns(exact, postures):
    free = np.zeros(NUM_PARAMETERS, dtype=bool)
    free[[0, 7, 43]] = True
    full = pose_sensitivities(exact, postures[:3])
    # Bit-equal: the mask selects columns of the very same computation (same operations).
    assert np.array_equal(pose_sensitivities(exact, postures[:3], free), full[:, :, free])


def test_expected_norm_of_isotropic_gaussian():
    sigma = 2.0
    covariance = np.eye(3) * sigma**2
    # E|v| = sqrt(8/pi) sigma for a 3-D isotropic Gaussian.
    assert expected_norm(covariance[None])[0] == pytest.approx(np.sqrt(8 / np.pi) * sigma, rel=0.02)
    # One axis only: E|v| = sqrt(2/pi) sigma.
    single = np.diag([sigma**2, 0.0, 0.0])
    assert expected_norm(single[None])[0] == pytest.approx(np.sqrt(2 / np.pi) * sigma, rel=0.03)


def test_prediction_agrees_with_monte_carlo(exact, nominal_sets, postures):
    nominal, sigmas = nominal_sets[1], SensorNoise()
    chosen, _ = select_postures(nominal, postures[:200], 40, sigmas)
    poses = postures[chosen]
    legs = inverse_kinematics(nominal, poses)
    reached, ok = forward_kinematics_masked(exact, legs, poses)
    poses, legs, reached = poses[ok], legs[ok], reached[ok]
    validation = postures[200:300]
    measured, predicted = [], []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        result = identify(
            nominal,
            legs + rng.normal(0.0, sigmas.leg_lengths, legs.shape),
            device_readings(exact, reached)
            + rng.normal(0.0, 1.0, (len(legs), 4)) * sigmas.readings(),
            sigmas,
            pose_guesses=poses,
        )
        assert result.converged
        errors = validate(exact, result.geometry, validation)
        position, orientation = predicted_errors(
            result.geometry, result.covariance, validation, result.free
        )
        measured.append((errors['position_mm_mean'], errors['orientation_deg_mean']))
        predicted.append((position.mean(), orientation.mean()))
    ratio = np.mean(measured, axis=0) / np.mean(predicted, axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def test_predict_accuracy_maps_and_summary(exact):
    covariance = np.eye(NUM_PARAMETERS) * 1e-10
    prediction = predict_accuracy(exact, covariance, postures=50)
    summary = accuracy_summary(prediction)
    assert 0 < summary['position_mm_mean'] <= summary['position_mm_p95']
    assert summary['worst_cell_position_mm'] >= np.nanmax(prediction['maps'][0]['position_mm'])
    assert len(prediction['maps']) == 5
    panel = prediction['maps'][1]
    assert np.asarray(panel['position_mm']).shape == (len(panel['y_m']), len(panel['x_m']))
    with pytest.raises(ValueError, match='covariance must be'):
        predicted_errors(exact, np.eye(3), prediction['worst_cell']['pose'])


def test_the_uncompensated_thermal_growth_adds_its_pose_error(exact, postures):
    """Legs longer by a strain s (of their whole length) than the controller assumes put the
    platform where FK of the
    grown legs does: with no other error, the prediction is that pose error, as the expected
    magnitude of a Gaussian of that rms (about sqrt(2 / pi) of it)."""
    poses = postures[:20]
    strain = np.array([20e-6, 18e-6, 22e-6, 20e-6, 19e-6, 21e-6])
    lengths = np.linalg.norm(leg_vectors(exact, poses)[0], axis=2)  # the whole leg grows
    grown = inverse_kinematics(exact, poses) + strain * lengths
    reached, converged = forward_kinematics_masked(exact, grown, poses)
    assert converged.all()
    shift_mm = 1e3 * np.linalg.norm(reached[:, :3] - poses[:, :3], axis=1)
    zero = np.zeros((NUM_PARAMETERS, NUM_PARAMETERS))
    position, _ = predicted_errors(exact, zero, poses, thermal_strain=strain)
    # E|z| of one normal as expected_norm integrates it (its fixed draws: within 3 % of sqrt(2/pi))
    one_dimensional = expected_norm(np.diag([1.0, 0.0, 0.0]))
    assert one_dimensional == pytest.approx(np.sqrt(2 / np.pi), rel=0.03)
    np.testing.assert_allclose(position, one_dimensional * shift_mm, rtol=0.01)
    assert np.all(predicted_errors(exact, zero, poses)[0] < 1e-9)


def test_the_thermal_strain_rms_is_over_the_runs_times_from_the_reference():
    """A linear growth over 0..T referred to T: rms (T - t) over the rows is T / sqrt(3)."""
    times = np.linspace(0.0, 900.0, 10001)
    design = EffectDesign(times_s=times, reference_time_s=900.0)
    rates = np.array([1e-8, -2e-8, 1e-8, 1e-8, 1e-8, 1e-8])
    expected = np.abs(rates) * 900.0 / np.sqrt(3.0)
    np.testing.assert_allclose(thermal_strain_rms(rates, design), expected, rtol=1e-3)


def _with_effects(geometry, values):
    """``geometry`` whose controller compensates the effect ``values`` (24,) under 40 kg."""
    return geometry.replace(
        effects=IdentifiedEffects(values, payload_mass=40.0, centre_of_mass=(0.0, 0.0, 0.05))
    )


def _compensated_reached(true, controller, poses):
    """Where the rigid real platform goes when ``controller`` drives ``poses`` compensating its
    identified effects (the identification's model read backwards)."""
    readings = commanded_leg_readings(controller, poses)
    return forward_kinematics(true, true.sensors.true_leg_lengths(readings), poses)


def test_effect_columns_match_finite_differences(exact, postures):
    """A controller's compliance and joint offset errors move the platform as its compensation
    says (backlash and thermal: no column)."""
    poses = postures[:5]
    free = np.ones(NUM_EFFECT_PARAMETERS, dtype=bool)
    sensitivity = effect_pose_sensitivities(_with_effects(exact, np.zeros(24)), poses, free)
    assert sensitivity.shape == (5, 6, NUM_EFFECT_PARAMETERS)
    assert np.all(sensitivity[:, :, 6:18] == 0.0)
    assert np.abs(sensitivity[:, :, 18:]).max() > 0.1  # a joint offset error moves the pose
    truth = _with_effects(exact, np.zeros(24))
    _assert_columns_match_finite_differences(
        truth,
        poses,
        sensitivity,
        np.zeros(NUM_EFFECT_PARAMETERS),
        [*range(6), *range(18, 24)],
        lambda moved: _with_effects(exact, moved),
        _compensated_reached,
    )


def test_prediction_with_freed_joint_offsets_agrees_with_monte_carlo(exact, postures):
    """Leg and joint offset errors strongly correlated (a joint offset's regressor is nearly a
    leg offset's): the compensating controller's pose errors, drawn over that covariance, are
    what the joint prediction says; the geometry's marginal block alone overstates them."""
    poses, rng = postures[:40], np.random.default_rng(3)
    free = np.zeros(NUM_PARAMETERS, dtype=bool)
    free[PARAMETER_INDEX['Loff1'] : PARAMETER_INDEX['Loff6'] + 1] = True
    effect_free = np.zeros(NUM_EFFECT_PARAMETERS, dtype=bool)
    effect_free[18:] = True  # joint_offset1..6
    truth = _with_effects(exact, np.zeros(NUM_EFFECT_PARAMETERS))
    # Per leg: the leg offset's error is the joint offset's times its mean regressor (what the
    # offset absorbs of it) plus a small independent part.
    mean_regressor = np.mean(
        EffectTerms(exact, EffectDesign(), effect_free, 200).regressors(postures[:200]), axis=0
    ).diagonal()
    mixing = np.zeros((12, 12))
    mixing[range(6), range(6)] = 2e-6
    mixing[range(6), range(6, 12)] = 50e-6 * mean_regressor
    mixing[range(6, 12), range(6, 12)] = 50e-6
    covariance = mixing @ mixing.T
    joint, _ = predicted_errors(truth, covariance, poses, free, effect_free=effect_free)
    marginal, _ = predicted_errors(truth, covariance[:6, :6], poses, free)
    errors = []
    for draw in rng.standard_normal((200, 12)) @ mixing.T:
        vector = exact.to_vector()
        vector[free] += draw[:6]
        values = np.zeros(NUM_EFFECT_PARAMETERS)
        values[effect_free] = draw[6:]
        controller = _with_effects(Geometry.from_vector(vector, exact.limits), values)
        reached = _compensated_reached(truth, controller, poses)
        errors.append(1000.0 * np.linalg.norm(reached[:, :3] - poses[:, :3], axis=1))
    assert np.mean(errors) / np.mean(joint) == pytest.approx(1.0, abs=0.15)
    assert np.mean(marginal) > 3.0 * np.mean(joint)
