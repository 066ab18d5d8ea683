"""Rotation conventions (paper eq 1-2) and conversions."""

import math

import numpy as np
import pytest

from gsp_kinematics.rotation import (
    euler_to_matrix,
    euler_to_matrix_derivatives,
    matrix_to_euler,
    matrix_to_quaternion,
    quaternion_to_matrix,
    rotation_angle_between,
)


def rot_x(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def axis_angle(axis, angle):
    """Rodrigues' formula, independent of the module under test."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def random_euler(rng, count):
    """psi in (-pi/2, pi/2) (the branch matrix_to_euler returns), theta and phi in (-pi, pi)."""
    return np.column_stack(
        [
            rng.uniform(-1.5, 1.5, count),
            rng.uniform(-3.1, 3.1, count),
            rng.uniform(-3.1, 3.1, count),
        ]
    )


def test_matrix_is_the_product_RY_RX_Rz_element_by_element(rng):
    euler = rng.uniform(-math.pi, math.pi, (300, 3))
    matrices = euler_to_matrix(euler)
    assert matrices.shape == (300, 3, 3)
    for (psi, theta, phi), matrix in zip(euler, matrices, strict=True):
        expected = rot_y(theta) @ rot_x(psi) @ rot_z(phi)
        for i in range(3):
            for j in range(3):
                assert matrix[i, j] == pytest.approx(expected[i, j], abs=1e-14), (i, j)


def test_matrix_matches_eq2_as_printed():
    psi, theta, phi = 0.3, -0.7, 1.1
    cps, sps, cth, sth, cph, sph = (
        math.cos(psi),
        math.sin(psi),
        math.cos(theta),
        math.sin(theta),
        math.cos(phi),
        math.sin(phi),
    )
    eq2 = np.array(
        [
            [cth * cph + sth * sph * sps, -cth * sph + sth * sps * cph, sth * cps],
            [cps * sph, cps * cph, -sps],
            [-sth * cph + cth * sps * sph, sth * sph + cth * sps * cph, cth * cps],
        ]
    )
    np.testing.assert_allclose(euler_to_matrix([psi, theta, phi]), eq2, atol=1e-15)
    # psi about the global X axis, theta about the global Y axis, phi about the local z axis.
    np.testing.assert_allclose(euler_to_matrix([psi, 0, 0]), rot_x(psi), atol=1e-15)
    np.testing.assert_allclose(euler_to_matrix([0, theta, 0]), rot_y(theta), atol=1e-15)
    np.testing.assert_allclose(euler_to_matrix([0, 0, phi]), rot_z(phi), atol=1e-15)


def test_matrices_are_rotations(rng):
    matrices = euler_to_matrix(rng.uniform(-4, 4, (100, 3)))
    np.testing.assert_allclose(
        matrices @ np.swapaxes(matrices, -1, -2),
        np.broadcast_to(np.eye(3), (100, 3, 3)),
        atol=1e-14,
    )
    np.testing.assert_allclose(np.linalg.det(matrices), 1.0, atol=1e-14)


def test_matrix_euler_round_trip(rng):
    euler = random_euler(rng, 500)
    np.testing.assert_allclose(matrix_to_euler(euler_to_matrix(euler)), euler, atol=1e-12)
    matrices = euler_to_matrix(rng.uniform(-4, 4, (500, 3)))
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(matrices)), matrices, atol=1e-12)


def test_quaternion_round_trips(rng):
    matrices = euler_to_matrix(random_euler(rng, 300))
    quaternions = matrix_to_quaternion(matrices)
    assert quaternions.shape == (300, 4)
    np.testing.assert_allclose(np.linalg.norm(quaternions, axis=1), 1.0, atol=1e-14)
    assert np.all(quaternions[:, 3] >= 0.0)
    np.testing.assert_allclose(quaternion_to_matrix(quaternions), matrices, atol=1e-14)
    raw = rng.normal(size=(300, 4)) * rng.uniform(0.1, 10.0, (300, 1))  # any length, any sign
    unit = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    unit *= np.where(unit[:, 3:] < 0.0, -1.0, 1.0)
    np.testing.assert_allclose(matrix_to_quaternion(quaternion_to_matrix(raw)), unit, atol=1e-12)


def test_quaternion_is_in_geometry_msgs_order():
    angle = 0.8
    expected = [0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)]  # x, y, z, w about z
    np.testing.assert_allclose(
        matrix_to_quaternion(euler_to_matrix([0.0, 0.0, angle])), expected, atol=1e-15
    )
    expected = [math.sin(angle / 2), 0.0, 0.0, math.cos(angle / 2)]  # about X (psi)
    np.testing.assert_allclose(
        matrix_to_quaternion(euler_to_matrix([angle, 0.0, 0.0])), expected, atol=1e-15
    )


def test_degenerate_quaternion_is_rejected():
    with pytest.raises(ValueError):
        quaternion_to_matrix([0.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError):
        quaternion_to_matrix([np.nan, 0.0, 0.0, 1.0])


def test_euler_derivatives_match_finite_differences(rng, fd):
    euler = rng.uniform(-1.4, 1.4, (20, 3))
    analytic = euler_to_matrix_derivatives(euler)  # (M, 3, 3, 3): axis -3 is the angle
    assert analytic.shape == (20, 3, 3, 3)
    for m in range(euler.shape[0]):
        numeric = fd(euler_to_matrix, euler[m], 1e-6)  # (3, 3, angle)
        np.testing.assert_allclose(analytic[m], np.moveaxis(numeric, -1, 0), atol=1e-9)


def test_rotation_angle_between_is_the_relative_rotation_angle(rng):
    for _ in range(50):
        base = euler_to_matrix(rng.uniform(-1.5, 1.5, 3))
        angle = rng.uniform(0.0, math.pi - 1e-3)
        other = base @ axis_angle(rng.normal(size=3), angle)
        assert rotation_angle_between(base, other) == pytest.approx(angle, abs=1e-12)
        assert rotation_angle_between(other, base) == pytest.approx(angle, abs=1e-12)
    # Small angles stay accurate (no arccos cancellation).
    base = euler_to_matrix([0.2, -0.3, 0.4])
    assert rotation_angle_between(base, base @ axis_angle([1, 2, 3], 1e-9)) == pytest.approx(
        1e-9, rel=1e-6
    )
    # R^T R goes through BLAS, whose kernels round per CPU: zero within 1e-15 rad (arccos gives
    # ~1e-8 here).
    assert rotation_angle_between(base, base) == pytest.approx(0.0, abs=1e-15)
