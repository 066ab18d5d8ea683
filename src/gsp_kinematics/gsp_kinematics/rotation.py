"""Orientation conventions of the paper (eq 1-2), ``R = R_Y(theta) R_X(psi) R_z(phi)``, and
conversions for geometry_msgs; broadcast over leading axes."""

import numpy as np
from scipy.spatial.transform import Rotation


def wrap_angle(angle):
    """``angle`` (rad, scalar or array) wrapped into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def _cosines_and_sines(euler):
    """``(euler as an array, cos psi, sin psi, cos theta, sin theta, cos phi, sin phi)``."""
    euler = np.asarray(euler, dtype=float)
    psi, theta, phi = euler[..., 0], euler[..., 1], euler[..., 2]
    return euler, np.cos(psi), np.sin(psi), np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)


def euler_to_matrix(euler):
    """Rotation matrices from ``[..., (psi, theta, phi)]`` (rad), eq (2)."""
    euler, cps, sps, cth, sth, cph, sph = _cosines_and_sines(euler)
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
    euler, cps, sps, cth, sth, cph, sph = _cosines_and_sines(euler)
    out = np.zeros(euler.shape[:-1] + (3, 3, 3))
    # Element-wise derivatives of eq (2).
    out[..., 0, 0, 0] = sth * sph * cps
    out[..., 0, 0, 1] = sth * cps * cph
    out[..., 0, 0, 2] = -sth * sps
    out[..., 0, 1, 0] = -sps * sph
    out[..., 0, 1, 1] = -sps * cph
    out[..., 0, 1, 2] = -cps
    out[..., 0, 2, 0] = cth * cps * sph
    out[..., 0, 2, 1] = cth * cps * cph
    out[..., 0, 2, 2] = -cth * sps
    out[..., 1, 0, 0] = -sth * cph + cth * sph * sps
    out[..., 1, 0, 1] = sth * sph + cth * sps * cph
    out[..., 1, 0, 2] = cth * cps
    out[..., 1, 2, 0] = -cth * cph - sth * sps * sph
    out[..., 1, 2, 1] = cth * sph - sth * sps * cph
    out[..., 1, 2, 2] = -sth * cps
    out[..., 2, 0, 0] = -cth * sph + sth * cph * sps
    out[..., 2, 0, 1] = -cth * cph - sth * sps * sph
    out[..., 2, 1, 0] = cps * cph
    out[..., 2, 1, 1] = -cps * sph
    out[..., 2, 2, 0] = sth * sph + cth * sps * cph
    out[..., 2, 2, 1] = sth * cph - cth * sps * sph
    return out


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
        raise ValueError('quaternion must be finite and non-zero')
    matrices = Rotation.from_quat(flat).as_matrix()
    return matrices.reshape(quaternion.shape[:-1] + (3, 3))


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
