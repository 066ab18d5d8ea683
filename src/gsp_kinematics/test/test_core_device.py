"""Measurement device model (paper eq 6-9) and its Jacobians."""

import math

import numpy as np
import pytest

from gsp_kinematics.model.device import (
    DeviceModelError,
    device_position,
    device_readings,
    distance_from_commands,
    paper_inclinations_jacobians,
    position_to_inclinations,
)


def random_inclinations(rng, count):
    alpha = rng.uniform(-0.6, 0.6, count)
    beta = rng.uniform(-0.6, 0.6, count)
    gamma = rng.uniform(math.radians(70.0), math.radians(110.0), count)
    length = rng.uniform(0.7, 1.4, count)
    return alpha, beta, gamma, length


def test_eq9_forward_then_inverse_for_random_gamma(rng):
    alpha, beta, gamma, length = random_inclinations(rng, 2000)
    position = device_position(alpha, beta, length, gamma)
    np.testing.assert_allclose(np.linalg.norm(position, axis=1), length, rtol=1e-14)
    alpha_back, beta_back = position_to_inclinations(position, gamma)
    np.testing.assert_allclose(alpha_back, alpha, atol=1e-12)
    np.testing.assert_allclose(beta_back, beta, atol=1e-12)


def test_eq9_inverse_then_forward_for_random_gamma(rng):
    position = np.column_stack([rng.uniform(-0.4, 0.4, (500, 2)), rng.uniform(0.8, 1.2, 500)])
    gamma = rng.uniform(math.radians(80.0), math.radians(100.0), 500)
    alpha, beta = position_to_inclinations(position, gamma)
    length = np.linalg.norm(position, axis=1)
    np.testing.assert_allclose(device_position(alpha, beta, length, gamma), position, atol=1e-13)


def test_reduces_to_eq7_and_eq8_at_right_angle(rng):
    alpha, beta, _, length = random_inclinations(rng, 500)
    position = device_position(alpha, beta, length, math.pi / 2)
    eq7 = np.column_stack(
        [
            length * np.cos(alpha) * np.sin(beta),
            length * np.sin(alpha),
            length * np.cos(alpha) * np.cos(beta),
        ]
    )
    np.testing.assert_allclose(position, eq7, atol=1e-15)
    alpha_back, beta_back = position_to_inclinations(position, math.pi / 2)
    np.testing.assert_allclose(alpha_back, np.arcsin(position[:, 1] / length), atol=1e-15)  # eq (8)
    np.testing.assert_allclose(beta_back, np.arctan(position[:, 0] / position[:, 2]), atol=1e-15)


def test_inclinations_of_a_zero_length_link_are_an_error():
    with pytest.raises(DeviceModelError):
        position_to_inclinations(np.zeros((1, 3)), math.pi / 2)


def test_device_readings(exact, postures):
    geometry = exact.replace(inclinometer_axes_angle=math.radians(91.0), device_length=0.8493)
    readings = device_readings(geometry, postures)
    assert readings.shape == (len(postures), 4)
    length = np.linalg.norm(postures[:, :3], axis=1)
    np.testing.assert_allclose(readings[:, 3], length - 0.8493, atol=1e-15)  # D = D0 + Dm, eq (6)
    np.testing.assert_array_equal(readings[:, 2], postures[:, 5])  # the encoder reads phi
    position = device_position(
        readings[:, 0], readings[:, 1], readings[:, 3] + 0.8493, math.radians(91.0)
    )
    np.testing.assert_allclose(position, postures[:, :3], atol=1e-13)


def test_the_distance_from_the_commands_is_the_measured_position_error(exact, postures):
    readings = device_readings(exact, postures)
    np.testing.assert_allclose(distance_from_commands(exact, postures, readings), 0.0, atol=1e-12)
    moved = postures + [0.003, -0.004, 0.0, 0.0, 0.0, 0.0]  # the platform 5 mm off in x, y
    distances = distance_from_commands(exact, postures, device_readings(exact, moved))
    np.testing.assert_allclose(distances, 0.005, rtol=0.0, atol=1e-12)  # m


@pytest.mark.parametrize('gamma_deg', [90.0, 89.5, 91.0])
def test_paper_inclinations_jacobians_match_finite_differences(exact, postures, gamma_deg, fd):
    geometry = exact.replace(inclinometer_axes_angle=math.radians(gamma_deg), device_length=0.8487)
    poses = postures[:15]
    d_m = np.linalg.norm(poses[:, :3], axis=1) - 0.85 + 1e-4  # D = D0 + Dm is an input
    angles, d_pose, d_device = paper_inclinations_jacobians(geometry, poses, d_m)
    assert angles.shape == (15, 2) and d_pose.shape == (15, 2, 6) and d_device.shape == (15, 2, 2)
    for m, pose in enumerate(poses):
        numeric = fd(
            lambda x, m=m: paper_inclinations_jacobians(geometry, x, d_m[m : m + 1])[0][0],
            pose,
            1e-7,
        )
        np.testing.assert_allclose(d_pose[m], numeric, atol=1e-7)

    def of_device(device):
        changed = geometry.replace(device_length=device[0], inclinometer_axes_angle=device[1])
        return paper_inclinations_jacobians(changed, poses, d_m)[0]

    numeric = fd(of_device, [geometry.device_length, geometry.inclinometer_axes_angle], 1e-7)
    np.testing.assert_allclose(d_device, numeric, atol=1e-7)


def test_paper_inclinations_are_eq8_at_right_angle_and_agree_with_the_readings(exact, postures):
    poses = postures[:50]
    d_m = np.linalg.norm(poses[:, :3], axis=1) - exact.device_length
    angles, _, _ = paper_inclinations_jacobians(exact, poses, d_m)
    link_length = exact.device_length + d_m
    np.testing.assert_allclose(angles[:, 0], np.arcsin(poses[:, 1] / link_length), atol=1e-14)
    np.testing.assert_allclose(angles[:, 1], np.arctan(poses[:, 0] / poses[:, 2]), atol=1e-14)
    skewed = exact.replace(inclinometer_axes_angle=math.radians(90.7))
    d_m = np.linalg.norm(poses[:, :3], axis=1) - skewed.device_length
    angles, _, _ = paper_inclinations_jacobians(skewed, poses, d_m)
    np.testing.assert_allclose(angles, device_readings(skewed, poses)[:, :2], atol=1e-12)
