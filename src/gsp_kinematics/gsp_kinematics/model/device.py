"""Measurement device model (paper section 3.3): the passive link from the base origin to the
platform origin, ``D = |t| = D0 + Dm``, inclinometer axes ``gamma`` apart (docs/physics.md)."""

import numpy as np

from gsp_kinematics import channels

#: Reading columns, in this order everywhere (from :data:`.channels.CHANNELS`).
READING_NAMES = channels.READING_NAMES
#: The device's sensors -> their columns of :data:`READING_NAMES`.
SENSORS = channels.DEVICE_READING_COLUMNS


def per_reading(inclinometer, encoder, lvdt):
    """One value per sensor -> one per reading (4,), in :data:`READING_NAMES` order."""
    values = np.zeros(len(READING_NAMES))
    for columns, value in zip(SENSORS.values(), (inclinometer, encoder, lvdt), strict=True):
        values[list(columns)] = value
    return values


class DeviceModelError(RuntimeError):
    """The inclination angles could not be solved for a link direction."""


def link_direction(alpha, beta, gamma):
    """Unit link direction for inclinations ``alpha``, ``beta`` (rad), eq (9) with D = 1."""
    alpha, beta, gamma = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (alpha, beta, gamma))
    )
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    cg, sg = np.cos(gamma), np.sin(gamma)
    return np.stack(
        [
            sg * ((cb - 1.0) * cg * sa + ca * sb),
            cg * ca * sb + sa * (cg**2 * cb + sg**2),
            ca * cb - cg * sa * sb,
        ],
        axis=-1,
    )


def link_direction_derivatives(alpha, beta, gamma):
    """Derivatives of :func:`link_direction` w.r.t. alpha, beta, gamma: each ``[..., 3]``."""
    alpha, beta, gamma = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (alpha, beta, gamma))
    )
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    cg, sg = np.cos(gamma), np.sin(gamma)
    d_alpha = np.stack(
        [
            sg * ((cb - 1.0) * cg * ca - sa * sb),
            -cg * sa * sb + ca * (cg**2 * cb + sg**2),
            -sa * cb - cg * ca * sb,
        ],
        axis=-1,
    )
    d_beta = np.stack(
        [sg * (-sb * cg * sa + ca * cb), cg * ca * cb - sa * cg**2 * sb, -ca * sb - cg * sa * cb],
        axis=-1,
    )
    d_gamma = np.stack(
        [
            cg * ((cb - 1.0) * cg * sa + ca * sb) - sg**2 * (cb - 1.0) * sa,
            -sg * ca * sb + sa * (2.0 * sg * cg * (1.0 - cb)),
            sg * sa * sb,
        ],
        axis=-1,
    )
    return d_alpha, d_beta, d_gamma


def device_position(alpha, beta, link_length, gamma):
    """Platform position ``t`` (..., 3) from inclinations and link length D (m), eq (9)."""
    return np.asarray(link_length, dtype=float)[..., None] * link_direction(alpha, beta, gamma)


def distance_from_commands(geometry, poses, readings):
    """Distance (M,) m of the platform positions the device ``readings`` (M, 4) measure (eq 9
    with ``geometry``) from the commanded ``poses`` (M, 6): a few mm when the platform is where
    it was sent and ``geometry`` is close to its own."""
    readings = np.atleast_2d(np.asarray(readings, dtype=float))
    length = geometry.device_length + readings[:, 3]
    measured = device_position(
        readings[:, 0], readings[:, 1], length, geometry.inclinometer_axes_angle
    )
    return np.linalg.norm(measured - np.atleast_2d(poses)[:, :3], axis=1)


def position_to_inclinations(position, gamma):
    """Solve eq (9) for ``(alpha, beta)`` given platform positions (..., 3); inverse of the model.

    Closed form, with ``u = t / |t|``: eq (9) gives ``u_y - u_x cot(gamma) = sin(alpha)``, and
    with ``a = cos(gamma) sin(alpha)``, ``b = cos(alpha)`` it is linear in ``(cos beta, sin beta)``:
    ``a cos(beta) + b sin(beta) = u_x / sin(gamma) + a`` and ``b cos(beta) - a sin(beta) = u_z``.
    At gamma = pi/2 this is eq (8).
    """
    position = np.asarray(position, dtype=float)
    length = np.linalg.norm(position, axis=-1)
    if np.any(~(length > 0.0)):
        raise DeviceModelError('link length must be positive and finite')
    direction = position / length[..., None]
    gamma = np.asarray(gamma, dtype=float)
    sin_gamma, cos_gamma = np.sin(gamma), np.cos(gamma)
    sin_alpha = direction[..., 1] - direction[..., 0] * cos_gamma / sin_gamma
    if np.any(np.abs(sin_alpha) > 1.0 + 1e-12):
        raise DeviceModelError(
            "link direction is outside the inclinometer's model (|sin alpha| > 1)"
        )
    alpha = np.arcsin(np.clip(sin_alpha, -1.0, 1.0))
    a, b = cos_gamma * np.sin(alpha), np.cos(alpha)
    rhs_x = direction[..., 0] / sin_gamma + a
    beta = np.arctan2(b * rhs_x - a * direction[..., 2], a * rhs_x + b * direction[..., 2])
    return alpha, beta


def device_readings(geometry, poses):
    """Noise-free readings ``[alpha, beta, phi, d_m]`` (M, 4) for poses (M, 6)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    alpha, beta = position_to_inclinations(poses[:, :3], geometry.inclinometer_axes_angle)
    d_m = np.linalg.norm(poses[:, :3], axis=1) - geometry.device_length
    return np.stack([alpha, beta, poses[:, 5], d_m], axis=1)


def paper_inclinations_jacobians(geometry, poses, d_m):
    """The paper's predicted inclinations (eq 8, generalised to any gamma) with D = D0 + Dm input.

    Solves ``y/D = G_y(alpha, beta)`` and ``x/z = G_x/G_z(alpha, beta)`` where ``G`` is the unit
    link direction of eq (9); at gamma = pi/2 this is exactly ``alpha = asin(y/D)``,
    ``beta = atan(x/z)``. Returns ``angles`` (M, 2), ``d/dpose`` (M, 2, 6) and
    ``d/d(D0, gamma)`` (M, 2, 2).
    """
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    x, y, z = poses[:, 0], poses[:, 1], poses[:, 2]
    gamma = geometry.inclinometer_axes_angle
    link_length = geometry.device_length + np.asarray(d_m, dtype=float)
    target = np.stack([np.clip(y / link_length, -1.0, 1.0), x / z], axis=1)
    alpha = np.arcsin(target[:, 0])
    beta = np.arctan(target[:, 1])

    def model(alpha, beta):
        direction = link_direction(alpha, beta, gamma)
        d_alpha, d_beta, d_gamma = link_direction_derivatives(alpha, beta, gamma)
        values = np.stack([direction[:, 1], direction[:, 0] / direction[:, 2]], axis=1)

        def ratio_derivative(derivative):
            return (
                derivative[:, 0] * direction[:, 2] - direction[:, 0] * derivative[:, 2]
            ) / direction[:, 2] ** 2

        jac_angles = np.stack(
            [
                np.stack([d_alpha[:, 1], d_beta[:, 1]], axis=1),
                np.stack([ratio_derivative(d_alpha), ratio_derivative(d_beta)], axis=1),
            ],
            axis=1,
        )  # (M, 2, 2)
        jac_gamma = np.stack([d_gamma[:, 1], ratio_derivative(d_gamma)], axis=1)
        return values, jac_angles, jac_gamma

    for _ in range(30):
        values, jac_angles, _ = model(alpha, beta)
        step = np.linalg.solve(jac_angles, (values - target)[..., None])[..., 0]
        alpha, beta = alpha - step[:, 0], beta - step[:, 1]
        if np.max(np.abs(step), initial=0.0) < 1e-15:
            break
    values, jac_angles, jac_gamma = model(alpha, beta)
    if np.any(~(np.abs(values - target) < 1e-9)):
        raise DeviceModelError('paper inclinations did not converge')
    count = poses.shape[0]
    d_target_d_pose = np.zeros((count, 2, 6))
    d_target_d_pose[:, 0, 1] = 1.0 / link_length
    d_target_d_pose[:, 1, 0] = 1.0 / z
    d_target_d_pose[:, 1, 2] = -x / z**2
    d_target_d_device = np.zeros((count, 2, 2))
    d_target_d_device[:, 0, 0] = -y / link_length**2
    inverse = np.linalg.inv(jac_angles)
    d_angles_d_pose = inverse @ d_target_d_pose
    d_angles_d_device = inverse @ d_target_d_device
    d_angles_d_device[:, :, 1] -= (inverse @ jac_gamma[..., None])[..., 0]
    return np.stack([alpha, beta], axis=1), d_angles_d_pose, d_angles_d_device
