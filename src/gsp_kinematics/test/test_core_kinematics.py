"""Inverse and forward kinematics (paper eq 4-5), batched, and their Jacobians."""

import math

import numpy as np
import pytest

from gsp_kinematics.model.geometry import Geometry, default_geometry
from gsp_kinematics.model.kinematics import (
    ForwardKinematicsError,
    check_reachable,
    expand_leg_parameters,
    forward_kinematics,
    forward_kinematics_masked,
    home_pose,
    inverse_kinematics,
    inverse_kinematics_jacobians,
    pose_from_leg_readings,
    sample_valid_postures,
)
from gsp_kinematics.rotation import euler_to_matrix


def perturbed(poses, rng, position=0.005, angle_deg=1.0):
    noise = np.concatenate(
        [
            rng.normal(0.0, position, (len(poses), 3)),
            rng.normal(0.0, math.radians(angle_deg), (len(poses), 3)),
        ],
        axis=1,
    )
    return poses + noise


def test_inverse_kinematics_is_eq4_eq5(exact, postures):
    q = inverse_kinematics(exact, postures[:20])
    for m, pose in enumerate(postures[:20]):
        rotation = euler_to_matrix(pose[3:])
        for i in range(6):
            length = np.linalg.norm(
                rotation @ exact.platform_joints[i] + pose[:3] - exact.base_joints[i]
            )
            assert q[m, i] == pytest.approx(length - exact.leg_offsets[i], abs=1e-15)


def test_ik_then_fk_is_the_identity(exact, postures, rng):
    leg_lengths = inverse_kinematics(exact, postures)
    solved = forward_kinematics(exact, leg_lengths, perturbed(postures, rng))
    np.testing.assert_allclose(solved, postures, atol=1e-10)


@pytest.mark.parametrize('kind', ['true', 'nominal'])
def test_ik_then_fk_on_the_shipped_geometries(kind, rng):
    geometry = default_geometry(kind)
    poses = sample_valid_postures(geometry, 200, rng)
    solved = forward_kinematics(
        geometry, inverse_kinematics(geometry, poses), perturbed(poses, rng)
    )
    np.testing.assert_allclose(solved, poses, atol=1e-10)


def test_fk_accepts_one_guess_for_all_postures(exact, rng):
    home = home_pose()
    poses = home + np.concatenate(
        [rng.normal(0, 0.01, (30, 3)), rng.normal(0, 0.02, (30, 3))], axis=1
    )
    solved = forward_kinematics(exact, inverse_kinematics(exact, poses), home)
    np.testing.assert_allclose(solved, poses, atol=1e-10)


def test_the_pose_from_leg_readings_anywhere_in_the_workspace(rng):
    """FK from the home pose of the readings IK gives: the posture, even far from home (the
    calibrator's route starts there)."""
    from gsp_kinematics.model.motion import posture_leg_lengths

    geometry = default_geometry('true')  # leg gain errors: readings are not articular values
    poses = sample_valid_postures(geometry, 40, rng)
    far = np.max(np.abs(poses[:, 3:]), axis=1) > math.radians(30.0)
    far |= np.linalg.norm(poses[:, :3] - home_pose()[:3], axis=1) > 0.15
    assert far.sum() >= 10  # beyond forward_kinematics' default jump limits
    readings = posture_leg_lengths(geometry, poses)
    solved = np.array([pose_from_leg_readings(geometry, q) for q in readings])
    np.testing.assert_allclose(solved[:, :3], poses[:, :3], atol=1e-9)  # m
    np.testing.assert_allclose(solved[:, 3:], poses[:, 3:], atol=1e-9)  # rad
    with pytest.raises(ForwardKinematicsError):
        pose_from_leg_readings(geometry, np.full(6, 5.0))  # legs 5 m beyond the stroke
    with pytest.raises(ValueError, match='shape'):
        pose_from_leg_readings(geometry, np.zeros(5))


def test_ik_jacobian_with_respect_to_the_pose(exact, postures, fd):
    poses = postures[:25]
    _, d_q_d_pose, _ = inverse_kinematics_jacobians(exact, poses)
    for m, pose in enumerate(poses):
        numeric = fd(lambda x: inverse_kinematics(exact, x)[0], pose, 1e-6)
        np.testing.assert_allclose(d_q_d_pose[m], numeric, atol=1e-8)


def test_ik_jacobian_with_respect_to_each_legs_parameters(exact, postures, fd):
    poses = postures[:25]
    q, _, d_q_d_leg = inverse_kinematics_jacobians(exact, poses)
    np.testing.assert_allclose(q, inverse_kinematics(exact, poses), atol=1e-15)
    limits = exact.limits

    def ik_of_vector(vector):
        return inverse_kinematics(Geometry.from_vector(vector, limits), poses)

    numeric = fd(ik_of_vector, exact.to_vector(), 1e-6)  # (M, 6, 44)
    np.testing.assert_allclose(expand_leg_parameters(d_q_d_leg), numeric[:, :, :42], atol=1e-8)
    np.testing.assert_allclose(
        numeric[:, :, 42:], 0.0, atol=1e-12
    )  # the device does not move the legs
    for leg in range(6):
        columns = [
            3 * leg,
            3 * leg + 1,
            3 * leg + 2,
            18 + 3 * leg,
            19 + 3 * leg,
            20 + 3 * leg,
            36 + leg,
        ]
        np.testing.assert_allclose(d_q_d_leg[:, leg, :], numeric[:, leg, columns], atol=1e-8)


def test_fk_failure_names_the_posture(exact, postures):
    poses = postures[:8]
    leg_lengths = inverse_kinematics(exact, poses)
    leg_lengths[5] += 0.6  # no assembly with these lengths near posture 5
    solved, converged = forward_kinematics_masked(exact, leg_lengths, poses)
    assert converged.tolist() == [True] * 5 + [False] + [True] * 2
    np.testing.assert_allclose(solved[converged], poses[converged], atol=1e-10)
    with pytest.raises(ForwardKinematicsError) as caught:
        forward_kinematics(exact, leg_lengths, poses)
    assert caught.value.indices == (5,)
    assert '5' in str(caught.value)


def test_fk_failure_for_non_finite_input_and_far_solutions(exact, postures):
    poses = postures[:4].copy()
    leg_lengths = inverse_kinematics(exact, poses)
    leg_lengths[1, 2] = np.nan
    guesses = poses.copy()
    guesses[3, :3] += [0.2, 0.0, 0.0]  # the solution is farther than the jump limit from the guess
    with pytest.raises(ForwardKinematicsError) as caught:
        forward_kinematics(exact, leg_lengths, guesses)
    assert caught.value.indices == (1, 3)


def test_check_reachable_gives_reasons(exact):
    poses = np.array([home_pose(), [0.0, 0.0, 3.0, 0.0, 0.0, 0.0], [np.nan] * 6])
    ok, reasons = check_reachable(exact, poses)
    assert ok.tolist() == [True, False, False]
    assert reasons[0] == ''
    assert 'stroke' in reasons[1] and 'above' in reasons[1]
    assert 'not finite' in reasons[2]


def test_sampled_postures_are_valid_and_in_the_paper_ranges(exact, postures):
    assert postures.shape == (400, 6)
    assert np.all(np.abs(postures[:, :2]) <= 0.4)
    assert np.all(np.abs(postures[:, 3:]) <= math.radians(40.0))
    ok, _ = check_reachable(exact, postures)
    assert ok.all()
    # The range really is used: some postures are near the +-40 deg edge.
    assert np.max(np.abs(postures[:, 3:])) > math.radians(38.0)
