"""Redundancy numbers of a weighted least-squares fit (private)."""

import numpy as np


def redundancy_flat(jacobian, active=None):
    """``(M, k)`` redundancy numbers of a Jacobian ``(M, k, n)``; rows of inactive postures
    (``active`` False) are NaN (they are not in the fit)."""
    count, k, n = jacobian.shape
    flat = jacobian.reshape(-1, n)
    covariance = np.linalg.pinv(flat.T @ flat)
    leverage = np.einsum('ik,ik->i', flat @ covariance, flat).reshape(count, k)
    redundancy = 1.0 - leverage
    if active is not None:
        redundancy[~np.asarray(active, dtype=bool)] = np.nan
    return redundancy


def redundancy_with_poses(jac_pose, jac_u, information):
    """``(M, k)`` redundancy numbers of the implicit formulation (the hat matrix's diagonal by
    the block inverse, docs/sensor_errors.md): Jacobians w.r.t. each posture's pose ``(M, k, 6)``
    and the parameters ``(M, k, n)``, ``information`` the Schur-reduced ``S`` (n, n)."""
    inverse_u = np.linalg.pinv(np.matmul(np.swapaxes(jac_pose, 1, 2), jac_pose))
    pose_part = jac_pose @ inverse_u  # (M, k, 6)
    leverage = np.einsum('mkj,mkj->mk', pose_part, jac_pose)
    if jac_u.shape[2]:
        w = np.matmul(np.swapaxes(jac_pose, 1, 2), jac_u)  # (M, 6, n)
        e = jac_u - pose_part @ w
        covariance = np.linalg.pinv(information)
        leverage += np.einsum('mkj,mkj->mk', e @ covariance, e)  # a matmul, not a 3-way loop
    return 1.0 - leverage
