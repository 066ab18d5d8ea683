"""Where a platform with effects really is, for the readings of its legs (vectorised over M)."""

import numpy as np

from ..rotation import euler_to_matrix
from .effects import backlash_lengths, effective_base_joints, leg_forces, thermal_strains
from .kinematics import forward_kinematics_masked, inverse_kinematics_jacobians

#: Leg length residual (m) at which the consistent pose counts as found.
TOLERANCE = 1e-13
#: Largest residual (m) a converged pose may keep (rounding of a metre-long leg is ~2e-16).
ACCEPTED_RESIDUAL = 1e-10


def free_leg_lengths(geometry, effects, leg_readings, directions, times_s):
    """Unloaded joint-to-joint leg lengths (M, 6) m for the readings (M, 6), approach
    ``directions`` (M, 6) and ``times_s`` (M,) since the start."""
    articular = geometry.sensors.true_leg_lengths(leg_readings)
    rigid = geometry.leg_offsets[None] + articular
    return rigid * (1.0 + thermal_strains(effects, times_s)) + backlash_lengths(effects, directions)


def loaded_leg_state(geometry, effects, poses):
    """Distances (M, 6) m between the effective joint points at ``poses`` and the leg forces
    (M, 6) N (compression positive) there."""
    poses = np.atleast_2d(poses)
    base_points = effective_base_joints(geometry, effects, poses)
    rotation = euler_to_matrix(poses[:, 3:])
    platform_points = (
        np.einsum('mjk,ik->mij', rotation, geometry.platform_joints) + poses[:, None, :3]
    )
    lengths = np.linalg.norm(platform_points - base_points, axis=2)
    if effects.compliant:
        forces = leg_forces(geometry, effects, poses, base_points)
    else:
        forces = np.zeros_like(lengths)
    return lengths, forces


def real_poses(
    geometry, effects, leg_readings, guess, directions=None, times_s=None, max_iterations=12
):
    """Real poses (M, 6) of a platform with ``geometry`` and ``effects`` whose legs read
    ``leg_readings`` (M, 6), and ``converged`` (M,). ``guess`` (M, 6) or (6,): near each pose;
    ``directions`` (M, 6): approach directions (default +1); ``times_s`` (M,) s (default 0)."""
    readings = np.atleast_2d(np.asarray(leg_readings, dtype=float))
    poses, converged = forward_kinematics_masked(
        geometry, geometry.sensors.true_leg_lengths(readings), guess
    )
    if effects is None or effects.ideal:
        return poses, converged
    count = readings.shape[0]
    directions = np.ones((count, 6)) if directions is None else np.atleast_2d(directions)
    times = np.zeros(count) if times_s is None else np.broadcast_to(times_s, (count,))
    free = free_leg_lengths(geometry, effects, readings, directions, times)
    compliance = effects.leg_compliance
    residual = np.zeros_like(free)
    for _ in range(max_iterations):
        lengths, forces = loaded_leg_state(geometry, effects, poses)
        converged &= np.all(np.isfinite(forces), axis=1)  # a singular pose holds no load
        residual = np.where(converged[:, None], lengths - (free - compliance * forces), 0.0)
        if not np.max(np.abs(residual), initial=0.0) > TOLERANCE:
            break
        _, jacobian, _ = inverse_kinematics_jacobians(geometry, poses)
        jacobian[~converged] = np.eye(6)
        poses -= np.linalg.solve(jacobian, residual[..., None])[..., 0]
    converged = converged & np.all(np.isfinite(poses), axis=1)
    converged &= np.max(np.abs(residual), axis=1) < ACCEPTED_RESIDUAL
    return poses, converged
