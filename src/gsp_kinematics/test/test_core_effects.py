"""The platform effects' physics (gsp_kinematics.model), each against a hand calculation."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from gsp_kinematics.model.effects import (
    GRAVITY,
    REALISTIC,
    EffectsError,
    PlatformEffects,
    approach_directions,
    base_joint_first_axes,
    effective_base_joints,
    leg_forces,
)
from gsp_kinematics.model.geometry import Geometry
from gsp_kinematics.model.kinematics import (
    forward_kinematics_masked,
    inverse_kinematics,
    leg_vectors,
)
from gsp_kinematics.model.real_pose import real_poses
from gsp_kinematics.model.validation import simulate_commands, validate
from gsp_kinematics.rotation import euler_to_matrix

HEIGHT = 1.0  # m, of the symmetric platform's home pose


@pytest.fixture(scope='module')
def symmetric():
    """Legs in mirror pairs about three vertical planes 120 deg apart: under a centred load at
    a level pose every leg carries the same force."""
    base, platform = [], []
    for k in range(3):
        for side in (1.0, -1.0):
            a = math.radians(120.0 * k + side * 15.0)
            b = math.radians(120.0 * k + side * 45.0)
            base.append([0.6 * math.cos(a), 0.6 * math.sin(a), 0.0])
            platform.append([0.4 * math.cos(b), 0.4 * math.sin(b), 0.0])
    return Geometry(np.array(base), np.array(platform), np.full(6, 0.5), 0.85, math.pi / 2)


def level(z):
    return np.array([[0.0, 0.0, z, 0.0, 0.0, 0.0]])


def test_defaults_are_ideal_and_bad_values_are_named():
    assert PlatformEffects().ideal and not REALISTIC.ideal
    assert PlatformEffects(payload_mass=40.0).ideal  # rigid legs: no deflection
    with pytest.raises(EffectsError, match='leg_stiffness'):
        PlatformEffects(leg_stiffness=[-1.0] * 6)
    with pytest.raises(EffectsError, match='backlash'):
        PlatformEffects(backlash=[1e-6] * 5)
    with pytest.raises(EffectsError, match='thermal_time_constant'):
        PlatformEffects(thermal_time_constant=0.0)
    round_trip = PlatformEffects.from_parameters(REALISTIC.to_parameters('e.'), 'e.')
    assert round_trip.to_parameters() == REALISTIC.to_parameters()


def test_no_effect_is_the_rigid_forward_kinematics_bit_for_bit(exact, postures):
    readings = inverse_kinematics(exact, postures[:20]) + 1e-5
    rigid = forward_kinematics_masked(exact, readings, postures[:20])
    for effects in (None, PlatformEffects()):
        poses, converged = real_poses(exact, effects, readings, postures[:20])
        assert np.array_equal(poses, rigid[0]) and np.array_equal(converged, rigid[1])


def test_the_consistent_solve_reduces_to_rigid_for_very_stiff_legs(exact, postures):
    readings = inverse_kinematics(exact, postures[:20])
    stiff = PlatformEffects(payload_mass=40.0, leg_stiffness=np.full(6, 1e30))
    poses, converged = real_poses(exact, stiff, readings, postures[:20] + 1e-4)
    assert converged.all()
    np.testing.assert_allclose(poses, postures[:20], atol=1e-11)


def test_centred_load_on_a_symmetric_platform_every_leg_takes_mg_over_6_cos(symmetric):
    effects = PlatformEffects(payload_mass=40.0, leg_stiffness=np.full(6, 30e6))
    vectors, _ = leg_vectors(symmetric, level(HEIGHT))
    cos = vectors[0, 0, 2] / np.linalg.norm(vectors[0, 0])
    forces = leg_forces(symmetric, effects, level(HEIGHT))
    np.testing.assert_allclose(forces, 40.0 * GRAVITY / (6.0 * cos), rtol=1e-12)
    # The real pose: every leg shortened by f / k, the forces taken at the lowered pose. By
    # hand: the horizontal span r of a leg is fixed, so solve sqrt(r^2 + z^2) = L0 - f(z) / k.
    radial = math.hypot(*vectors[0, 0, :2])
    free_length = math.hypot(radial, HEIGHT)

    def mismatch(z):
        length = math.hypot(radial, z)
        return length - (free_length - 40.0 * GRAVITY * length / (6.0 * z) / 30e6)

    z = brentq(mismatch, HEIGHT - 1e-3, HEIGHT, xtol=1e-15)
    readings = inverse_kinematics(symmetric, level(HEIGHT))
    poses, converged = real_poses(symmetric, effects, readings, level(HEIGHT))
    assert converged[0]
    assert HEIGHT - z > 2e-6  # the hand calculation sees a real sag
    np.testing.assert_allclose(poses[0], [0.0, 0.0, z, 0.0, 0.0, 0.0], atol=1e-12)


def test_leg_forces_balance_the_weight_at_any_pose(exact, postures):
    effects = PlatformEffects(payload_mass=40.0, centre_of_mass=(0.02, -0.01, 0.05))
    forces = leg_forces(exact, effects, postures[:30])
    vectors, rotation = leg_vectors(exact, postures[:30])
    units = vectors / np.linalg.norm(vectors, axis=2, keepdims=True)
    arms = np.einsum('mjk,ik->mij', rotation, exact.platform_joints)
    weight = np.array([0.0, 0.0, -40.0 * GRAVITY])
    centre = rotation @ effects.centre_of_mass
    net_force = np.einsum('mi,mik->mk', forces, units) + weight
    net_moment = np.einsum('mi,mik->mk', forces, np.cross(arms, units)) + np.cross(centre, weight)
    assert np.max(np.abs(net_force)) < 1e-9 and np.max(np.abs(net_moment)) < 1e-9


def test_a_singular_pose_holds_no_load_and_fails_alone(symmetric):
    """In the base plane (z = 0) no leg pushes up: the statics have no solution there. Its
    forces are NaN, the other pose's are solved; real_poses marks it not converged, not
    raising."""
    effects = PlatformEffects(payload_mass=40.0, leg_stiffness=[3e7] * 6, leg_mass=[10.0] * 6)
    poses = np.concatenate([level(0.0), level(HEIGHT)])
    forces = leg_forces(symmetric, effects, poses)
    assert np.all(np.isnan(forces[0]))
    np.testing.assert_allclose(forces[1], leg_forces(symmetric, effects, poses[1:])[0], rtol=1e-12)
    readings = inverse_kinematics(symmetric, level(HEIGHT))[0]
    # Readings whose rigid pose is the home pose, from a guess at the singular plane: the
    # statics fail at the guess the first iteration meets.
    reached, converged = real_poses(symmetric, effects, [readings, readings], poses)
    assert converged[1] and not converged[0]
    assert abs(reached[1, 2] - HEIGHT) < 1e-3  # m: a sag of um, not a jump


def _gravity_potential(geometry, effects, poses):
    """J (M,): gravity's potential of the platform and of the legs, each leg two equal halves:
    its body ``d`` from the base joint along it, its rod ``d`` from the platform joint (any
    ``d``: the halves' moments about the base joint sum to the bar's, centre at mid-length)."""
    vectors, rotation = leg_vectors(geometry, poses)
    units = vectors / np.linalg.norm(vectors, axis=2, keepdims=True)
    tips = np.einsum('mjk,ik->mij', rotation, geometry.platform_joints) + poses[:, None, :3]
    body = geometry.base_joints[None, :, 2] + 0.1 * units[..., 2]
    rod = tips[..., 2] - 0.1 * units[..., 2]
    centre = (rotation @ effects.centre_of_mass)[:, 2] + poses[:, 2]
    return GRAVITY * (
        effects.payload_mass * centre + (0.5 * effects.leg_mass * (body + rod)).sum(1)
    )


def test_leg_forces_with_heavy_legs_are_the_virtual_work_of_gravity(exact, postures):
    """A virtual displacement of the pose does gravity's work in the springs: ``J^T f = dV/dX``
    (J: the leg lengths' derivatives, V: the gravity potential of the platform and of the
    legs, the rod's half above the spring moving with the platform joint), by central
    differences; the massless-leg forces miss the legs' weight by tens of newtons."""
    effects = PlatformEffects(
        payload_mass=40.0, centre_of_mass=(0.02, -0.01, 0.05), leg_mass=np.linspace(8, 14, 6)
    )
    poses, step = postures[:8], 1e-6
    jacobian, gradient = np.zeros((len(poses), 6, 6)), np.zeros((len(poses), 6))
    for k in range(6):
        shift = np.zeros(6)
        shift[k] = step
        up, down = poses + shift, poses - shift
        jacobian[:, :, k] = (inverse_kinematics(exact, up) - inverse_kinematics(exact, down)) / (
            2 * step
        )
        gradient[:, k] = (
            _gravity_potential(exact, effects, up) - _gravity_potential(exact, effects, down)
        ) / (2 * step)
    # In equilibrium the springs' forces (compression shortens) balance gravity's: J^T f = dV/dX.
    expected = np.linalg.solve(np.swapaxes(jacobian, 1, 2), gradient[..., None])[..., 0]
    forces = leg_forces(exact, effects, poses)
    np.testing.assert_allclose(forces, expected, rtol=0, atol=1e-4)  # N, of about 100-300 N
    massless = leg_forces(exact, effects.replace(leg_mass=np.zeros(6)), poses)
    assert np.max(np.abs(forces - massless)) > 20.0


def test_approach_directions_follow_the_sign_of_the_last_motion():
    legs = np.array([[1.0, 1.0], [1.1, 0.9], [1.1, 0.9], [1.0, 0.95], [1.0, 0.95]])
    sequence = np.repeat(legs, 3, axis=1)
    directions = approach_directions(sequence)
    expected = np.array([[1, 1], [1, -1], [1, -1], [-1, 1], [-1, 1]], dtype=float)
    np.testing.assert_array_equal(directions, np.repeat(expected, 3, axis=1))
    # From a previous state: the first row compares with the previous readings.
    first = approach_directions(legs[:1].repeat(3, 1), previous=np.full(6, 2.0))
    np.testing.assert_array_equal(first, -np.ones((1, 6)))
    kept = approach_directions(legs[:1].repeat(3, 1), previous=legs[0].repeat(3), initial=-1.0)
    np.testing.assert_array_equal(kept, -np.ones((1, 6)))


def _leg_distances(geometry, effects, poses):
    base = effective_base_joints(geometry, effects, poses)
    rotation = euler_to_matrix(poses[:, 3:])
    tips = np.einsum('mjk,ik->mij', rotation, geometry.platform_joints) + poses[:, None, :3]
    return np.linalg.norm(tips - base, axis=2)


def test_backlash_shortens_a_leg_arrived_extending_by_half_the_lost_motion(exact, postures):
    effects = PlatformEffects(backlash=np.array([4e-6, 2e-6, 0, 0, 1e-6, 8e-6]))
    readings = inverse_kinematics(exact, postures[:4])
    directions = np.array([[1.0] * 6, [-1.0] * 6, [1, -1, 1, -1, 1, -1], [-1, 1, -1, 1, -1, 1]])
    poses, converged = real_poses(exact, effects, readings, postures[:4], directions)
    assert converged.all()
    expected = readings + exact.leg_offsets - directions * effects.backlash / 2.0
    np.testing.assert_allclose(_leg_distances(exact, effects, poses), expected, atol=1e-13)


def test_thermal_growth_at_time_t(exact, postures):
    effects = PlatformEffects(temperature_rise=np.arange(1.0, 7.0) * 0.5, thermal_time_constant=300)
    readings = inverse_kinematics(exact, postures[:3])
    times = np.array([0.0, 300.0, 900.0])
    poses, converged = real_poses(exact, effects, readings, postures[:3], times_s=times)
    assert converged.all()
    rise = np.outer([0.0, 1.0 - math.exp(-1.0), 1.0 - math.exp(-3.0)], np.arange(1.0, 7.0) * 0.5)
    expected = (readings + exact.leg_offsets) * (1.0 + 12e-6 * rise)
    np.testing.assert_allclose(_leg_distances(exact, effects, poses), expected, atol=1e-13)
    np.testing.assert_allclose(poses[0], postures[0], atol=1e-12)  # no growth at t = 0


def test_joint_offset_geometry(exact, postures):
    effects = PlatformEffects(base_joint_offsets=np.linspace(10e-6, 60e-6, 6))
    axes = base_joint_first_axes(exact)
    home_vectors, _ = leg_vectors(exact, np.array([[0, 0, 1.0, 0, 0, 0]]))
    np.testing.assert_allclose(axes[:, 2], 0.0, atol=1e-15)  # horizontal
    np.testing.assert_allclose(np.einsum('ik,ik->i', axes, home_vectors[0]), 0.0, atol=1e-15)
    base = effective_base_joints(exact, effects, postures[:25])
    offset = base - exact.base_joints
    rotation = euler_to_matrix(postures[:25, 3:])
    tips = np.einsum('mjk,ik->mij', rotation, exact.platform_joints) + postures[:25, None, :3]
    leg = (tips - base) / np.linalg.norm(tips - base, axis=2, keepdims=True)
    second_axes = np.cross(axes, leg)  # perpendicular to the first axis and to the leg
    # The common normal of the two axes: e long, normal to both, on the leg's side.
    np.testing.assert_allclose(
        np.linalg.norm(offset, axis=2), np.broadcast_to(effects.base_joint_offsets, (25, 6))
    )
    assert np.max(np.abs(np.einsum('mik,ik->mi', offset, axes))) < 1e-15
    assert np.max(np.abs(np.einsum('mik,mik->mi', offset, second_axes))) < 1e-15
    assert np.all(np.einsum('mik,mik->mi', offset, leg) > 0.0)
    # A vertical leg with its first axis along x: the second axis is y, the point e above A.
    vertical = Geometry(
        exact.base_joints, exact.base_joints, np.zeros(6), 0.85, math.pi / 2
    )  # every leg vertical at the level poses
    points = effective_base_joints(vertical, effects, np.array([[0, 0, 1.0, 0, 0, 0]]))
    np.testing.assert_allclose(
        points[0] - exact.base_joints, np.outer(effects.base_joint_offsets, [0, 0, 1]), atol=1e-15
    )


def test_simulate_commands_reads_the_actuators_and_measures_the_real_pose(exact, postures):
    times = np.linspace(0.0, 600.0, 12)
    run = simulate_commands(exact, exact, postures[:12], REALISTIC, times)
    np.testing.assert_allclose(run.leg_readings, inverse_kinematics(exact, postures[:12]))
    assert run.reachable.all()
    error = np.linalg.norm(run.real_poses[:, :3] - postures[:12, :3], axis=1)
    assert np.all(error > 1e-6) and np.all(error < 1e-3)  # the effects move the platform
    rigid = simulate_commands(exact, exact, postures[:12], None, times)
    np.testing.assert_allclose(rigid.real_poses, postures[:12], atol=1e-11)
    assert validate(exact, exact, postures[:12], REALISTIC, times)['position_mm_mean'] > 1e-3
