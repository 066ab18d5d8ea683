"""Orientation conventions of the paper (eq 1-2) and conversions for geometry_msgs.

Pose vector ``X = [x, y, z, psi, theta, phi]`` (m, rad); ``R = R_Y(theta) R_X(psi) R_z(phi)``.
All functions broadcast over leading axes.
"""

import numpy as np
from scipy.spatial.transform import Rotation


def euler_to_matrix(euler):
    """Rotation matrices from ``[..., (psi, theta, phi)]`` (rad), eq (2)."""
    euler = np.asarray(euler, dtype=float)
    psi, theta, phi = euler[..., 0], euler[..., 1], euler[..., 2]
    cps, sps = np.cos(psi), np.sin(psi)
    cth, sth = np.cos(theta), np.sin(theta)
    cph, sph = np.cos(phi), np.sin(phi)
    rotation = np.empty(euler.shape[:-1] + (3, 3))
    rotation[..., 0, 0] = cth * cph + sth * sph * sps
    rotation[..., 0, 1] = -cth * sph + sth * sps * cph
    rotation[..., 0, 2] = sth * cps
    rotation[..., 1, 0] = cps * sph
    rotation[..., 1, 1] = cps * cph
    rotation[..., 1, 2] = -sps
    rotation[..., 2, 0] = -sth * cph + cth * sps * sph
    rotation[..., 2, 1] = sth * sph + cth * sps * cph
    rotation[..., 2, 2] = cth * cps
    return rotation


def euler_to_matrix_derivatives(euler):
    """``dR/dpsi, dR/dtheta, dR/dphi`` stacked on axis -3: shape ``[..., 3, 3, 3]``."""
    euler = np.asarray(euler, dtype=float)
    psi, theta, phi = euler[..., 0], euler[..., 1], euler[..., 2]
    zero, one = np.zeros_like(psi), np.ones_like(psi)

    def stack(rows):
        return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)

    c, s = np.cos, np.sin
    rot_x = stack([[one, zero, zero], [zero, c(psi), -s(psi)], [zero, s(psi), c(psi)]])
    rot_y = stack([[c(theta), zero, s(theta)], [zero, one, zero], [-s(theta), zero, c(theta)]])
    rot_z = stack([[c(phi), -s(phi), zero], [s(phi), c(phi), zero], [zero, zero, one]])
    d_rot_x = stack([[zero, zero, zero], [zero, -s(psi), -c(psi)], [zero, c(psi), -s(psi)]])
    d_rot_y = stack([[-s(theta), zero, c(theta)], [zero, zero, zero], [-c(theta), zero, -s(theta)]])
    d_rot_z = stack([[-s(phi), -c(phi), zero], [c(phi), -s(phi), zero], [zero, zero, zero]])
    return np.stack(
        [
            rot_y @ d_rot_x @ rot_z,
            d_rot_y @ rot_x @ rot_z,
            rot_y @ rot_x @ d_rot_z,
        ],
        axis=-3,
    )


def matrix_to_euler(rotation):
    """Inverse of :func:`euler_to_matrix`; returns ``[..., (psi, theta, phi)]`` with |psi| <= pi/2."""
    rotation = np.asarray(rotation, dtype=float)
    psi = np.arcsin(np.clip(-rotation[..., 1, 2], -1.0, 1.0))
    theta = np.arctan2(rotation[..., 0, 2], rotation[..., 2, 2])
    phi = np.arctan2(rotation[..., 1, 0], rotation[..., 1, 1])
    return np.stack([psi, theta, phi], axis=-1)


def matrix_to_quaternion(rotation):
    """Quaternion ``[..., (x, y, z, w)]`` (geometry_msgs order) with w >= 0."""
    rotation = np.asarray(rotation, dtype=float)
    flat = Rotation.from_matrix(rotation.reshape(-1, 3, 3)).as_quat()
    flat = np.where(flat[:, 3:4] < 0.0, -flat, flat)
    return flat.reshape(rotation.shape[:-2] + (4,))


def quaternion_to_matrix(quaternion):
    """Rotation matrices from ``[..., (x, y, z, w)]``; the quaternion need not be unit length."""
    quaternion = np.asarray(quaternion, dtype=float)
    flat = quaternion.reshape(-1, 4)
    norms = np.linalg.norm(flat, axis=1)
    if np.any(~np.isfinite(norms)) or np.any(norms < 1e-9):
        raise ValueError("quaternion must be finite and non-zero")
    matrices = Rotation.from_quat(flat).as_matrix()
    return matrices.reshape(quaternion.shape[:-1] + (3, 3))


def pose_to_position_quaternion(poses):
    """Split pose vectors ``[..., 6]`` into positions ``[..., 3]`` and quaternions ``[..., 4]``."""
    poses = np.asarray(poses, dtype=float)
    return poses[..., :3].copy(), matrix_to_quaternion(euler_to_matrix(poses[..., 3:]))


def position_quaternion_to_pose(position, quaternion):
    """Pose vectors ``[..., 6]`` from positions and ``(x, y, z, w)`` quaternions."""
    position = np.asarray(position, dtype=float)
    euler = matrix_to_euler(quaternion_to_matrix(quaternion))
    return np.concatenate([position, euler], axis=-1)


def rotation_angle_between(rotation_a, rotation_b):
    """Angle (rad) of the relative rotation ``R_a^T R_b``."""
    relative = np.swapaxes(rotation_a, -1, -2) @ rotation_b
    trace = np.trace(relative, axis1=-2, axis2=-1)
    # arccos loses precision near 0; the skew part keeps small angles accurate.
    skew = np.stack(
        [
            relative[..., 2, 1] - relative[..., 1, 2],
            relative[..., 0, 2] - relative[..., 2, 0],
            relative[..., 1, 0] - relative[..., 0, 1],
        ],
        axis=-1,
    )
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), 0.5 * (trace - 1.0))
