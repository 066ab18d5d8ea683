"""Posture selection (paper section 4.2) and validation errors."""

import math

import numpy as np
import pytest

from gsp_kinematics.estimation.identifiability import posture_information, scaled_condition_number
from gsp_kinematics.model.device import link_direction_derivatives, position_to_inclinations
from gsp_kinematics.model.kinematics import (
    forward_kinematics,
    inverse_kinematics,
    sample_valid_postures,
)
from gsp_kinematics.model.validation import commanded_articular, pose_errors, validate
from gsp_kinematics.planning.selection import (
    select_postures,
)
from gsp_kinematics.rotation import euler_to_matrix, matrix_to_euler


def reached_poses(true, controller, commanded):
    """Where the rigid real platform goes when ``controller`` drives ``commanded``."""
    return forward_kinematics(true, commanded_articular(true, controller, commanded), commanded)


@pytest.fixture(scope='module')
def selection(nominal_sets):
    nominal = nominal_sets[1]
    pool = sample_valid_postures(nominal, 150, np.random.default_rng(3))
    indices, condition = select_postures(nominal, pool, 45)
    return nominal, pool, indices, condition


def test_selection_returns_distinct_indices_into_the_pool(selection):
    _, pool, indices, condition = selection
    assert indices.shape == (45,)
    assert len(set(indices.tolist())) == 45
    assert np.all((indices >= 0) & (indices < len(pool)))
    assert math.isfinite(condition) and condition >= 1.0


def test_selection_beats_random_picks(selection):
    nominal, pool, indices, condition = selection
    information = posture_information(nominal, pool)
    assert scaled_condition_number(information[indices].sum(axis=0)) == pytest.approx(
        condition, rel=1e-6
    )
    rng = np.random.default_rng(4)
    random_conditions = [
        scaled_condition_number(information[rng.choice(len(pool), 45, replace=False)].sum(axis=0))
        for _ in range(20)
    ]
    assert condition < min(random_conditions)


def test_selection_needs_a_large_enough_pool(nominal_sets):
    pool = sample_valid_postures(nominal_sets[1], 10, np.random.default_rng(5))
    with pytest.raises(ValueError, match='fewer'):
        select_postures(nominal_sets[1], pool, 20)


def axis_angle(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def test_orientation_error_is_the_relative_rotation_angle(rng):
    commanded = np.array([[0.1, -0.2, 1.0, 0.3, -0.5, 0.7], [0.0, 0.0, 0.9, 1.45, 0.0, 0.0]])
    angles = [math.radians(0.25), math.radians(3.0)]
    reached = commanded.copy()
    for m, angle in enumerate(angles):
        rotation = euler_to_matrix(commanded[m, 3:]) @ axis_angle(
            [0.2, 1.0, 0.3] if m else rng.normal(size=3), angle
        )
        reached[m, 3:] = matrix_to_euler(rotation)
    reached[:, :3] += [[0.003, 0.004, 0.0], [0.0, 0.0, -0.002]]
    position_mm, orientation_deg = pose_errors(commanded, reached)
    np.testing.assert_allclose(position_mm, [5.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(orientation_deg, np.degrees(angles), atol=1e-9)
    # Near psi = 83 deg (close to gimbal lock) the Euler angles of a 3 deg rotation change by far more than 3 deg.
    assert np.max(np.abs(np.degrees(reached[1, 3:] - commanded[1, 3:]))) > 3.5


def test_validation_of_the_exact_controller_is_zero(exact, postures):
    errors = validate(exact, exact, postures[:50])
    keys = ('position_mm_mean', 'position_mm_max', 'orientation_deg_mean', 'orientation_deg_max')
    assert set(keys) <= set(errors)
    assert max(errors[key] for key in keys) < 1e-8


def test_validation_commands_with_the_controller_and_moves_the_true_platform(
    exact, nominal_sets, postures
):
    commanded = postures[:50]
    nominal = nominal_sets[1]
    reached = reached_poses(exact, nominal, commanded)
    np.testing.assert_allclose(
        inverse_kinematics(exact, reached), inverse_kinematics(nominal, commanded), atol=1e-11
    )
    np.testing.assert_allclose(
        reached,
        forward_kinematics(exact, inverse_kinematics(nominal, commanded), commanded),
        atol=1e-12,
    )
    errors = validate(exact, nominal, commanded)
    position_mm, orientation_deg = pose_errors(commanded, reached)
    assert errors['position_mm_mean'] == pytest.approx(position_mm.mean())
    assert errors['orientation_deg_max'] == pytest.approx(orientation_deg.max())
    assert 0.5 < errors['position_mm_mean'] < 50.0 and 0.01 < errors['orientation_deg_mean'] < 5.0


def device_readings_jacobians(geometry, poses):
    """Readings (M, 4), their derivatives w.r.t. the pose (M, 4, 6) and w.r.t. (D0, gamma) (M, 4, 2)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    position = poses[:, :3]
    gamma = geometry.inclinometer_axes_angle
    alpha, beta = position_to_inclinations(position, gamma)
    length = np.linalg.norm(position, axis=1)
    direction = position / length[:, None]
    d_alpha, d_beta, d_gamma = link_direction_derivatives(alpha, beta, gamma)
    tangent = np.stack([d_alpha, d_beta], axis=-1)  # (M, 3, 2)
    # The direction moves on the unit sphere; the tangent's pseudo-inverse maps it to the angles.
    pseudo_inverse = np.linalg.solve(
        np.swapaxes(tangent, -1, -2) @ tangent, np.swapaxes(tangent, -1, -2)
    )  # (M, 2, 3)
    projector = (np.eye(3)[None] - direction[:, :, None] * direction[:, None, :]) / length[
        :, None, None
    ]
    d_angles_d_position = pseudo_inverse @ projector  # (M, 2, 3)
    d_angles_d_gamma = -(pseudo_inverse @ d_gamma[..., None])[..., 0]  # (M, 2)
    count = poses.shape[0]
    d_readings_d_pose = np.zeros((count, 4, 6))
    d_readings_d_pose[:, 0:2, 0:3] = d_angles_d_position
    d_readings_d_pose[:, 2, 5] = 1.0
    d_readings_d_pose[:, 3, 0:3] = direction
    d_readings_d_device = np.zeros((count, 4, 2))
    d_readings_d_device[:, 0:2, 1] = d_angles_d_gamma
    d_readings_d_device[:, 3, 0] = -1.0
    readings = np.stack([alpha, beta, poses[:, 5], length - geometry.device_length], axis=1)
    return readings, d_readings_d_pose, d_readings_d_device


def schur_information(jac_pose, jac_u, per_posture=False):
    """Information ``J^T J`` of the parameters with each posture's pose eliminated,
    ``H_uu - sum_m H_Xu_m^T H_XX_m^-1 H_Xu_m``, from the Jacobians ``(M, k, 6)`` and
    ``(M, k, n)``; ``per_posture``: ``(M, n, n)``, one complement a posture."""
    jac_pose_t = np.swapaxes(jac_pose, 1, 2)
    h_xu = jac_pose_t @ jac_u
    solved = np.linalg.inv(jac_pose_t @ jac_pose) @ h_xu
    if per_posture:
        return np.swapaxes(jac_u, 1, 2) @ jac_u - np.swapaxes(h_xu, 1, 2) @ solved
    size = jac_u.shape[2]
    flat_u = jac_u.reshape(-1, size)
    return flat_u.T @ flat_u - h_xu.reshape(-1, size).T @ solved.reshape(-1, size)


def test_posture_factors_give_the_schur_complement(nominal_sets, postures):
    from gsp_kinematics.estimation.identifiability import posture_factors
    from gsp_kinematics.model.kinematics import expand_leg_parameters, inverse_kinematics_jacobians
    from gsp_kinematics.model.sensor_noise import SensorNoise

    nominal, sigmas, poses = nominal_sets[2], SensorNoise(), postures[:30]
    factors = posture_factors(nominal, poses, sigmas)
    assert factors.shape == (30, 4, 44)
    # The pose eliminated by the normal equations' Schur complement, built independently.
    _, d_q_d_pose, d_q_d_leg = inverse_kinematics_jacobians(nominal, poses)
    _, d_h_d_pose, d_h_d_device = device_readings_jacobians(nominal, poses)
    jac_u = np.zeros((30, 10, 44))
    jac_u[:, :6, :42] = expand_leg_parameters(d_q_d_leg) / sigmas.leg_lengths
    jac_u[:, 6:, 42:] = d_h_d_device / sigmas.readings()[None, :, None]
    jac_pose = np.concatenate(
        [d_q_d_pose / sigmas.leg_lengths, d_h_d_pose / sigmas.readings()[None, :, None]], axis=1
    )
    expected = schur_information(jac_pose, jac_u, per_posture=True)
    information = posture_information(nominal, poses, sigmas)
    assert np.allclose(information, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def test_selection_is_not_worse_than_scoring_every_candidate(nominal_sets):
    nominal = nominal_sets[1]
    pool = sample_valid_postures(nominal, 120, np.random.default_rng(11))
    _, shortlisted = select_postures(nominal, pool, 30)
    _, exhaustive = select_postures(nominal, pool, 30, shortlist=None)
    assert shortlisted <= 1.1 * exhaustive


def test_best_addition_picks_the_posture_that_lowers_the_condition_number_most():
    from gsp_kinematics.estimation.identifiability import (
        posture_information,
        scaled_condition_number,
    )
    from gsp_kinematics.model.geometry import default_geometry
    from gsp_kinematics.model.kinematics import sample_valid_postures
    from gsp_kinematics.planning.selection import best_addition

    nominal = default_geometry('nominal')
    pool = sample_valid_postures(nominal, 80, np.random.default_rng(5))
    chosen = list(range(20))
    excluded = [20, 21]
    information = posture_information(nominal, pool)
    best = best_addition(information, chosen, excluded)
    assert best not in chosen and best not in excluded
    base = information[chosen].sum(axis=0)
    others = [k for k in range(80) if k not in chosen + excluded]
    conditions = {k: float(scaled_condition_number(base + information[k])) for k in others}
    assert conditions[best] == min(conditions.values())
