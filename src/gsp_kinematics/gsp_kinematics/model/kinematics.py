"""Inverse and forward kinematics of the Gough-Stewart platform (paper eq 4-5), batched over
poses (M, 6) ``[x, y, z, psi, theta, phi]`` (m, rad); ``q_i = L_i - L_off_i`` (m)."""

import dataclasses
import math

import numpy as np

from ..rotation import euler_to_matrix, euler_to_matrix_derivatives


class ForwardKinematicsError(RuntimeError):
    """Newton's method did not converge, or converged far from the guess, for some postures."""

    def __init__(self, message, indices):
        super().__init__(message)
        self.indices = tuple(int(index) for index in indices)


def _as_poses(poses):
    poses = np.asarray(poses, dtype=float)
    if poses.ndim == 1:
        poses = poses[None, :]
    if poses.ndim != 2 or poses.shape[1] != 6:
        raise ValueError(f'poses must have shape (M, 6), got {poses.shape}')
    return poses


def leg_vectors(geometry, poses):
    """``v_i = R B_i + t - A_i`` (M, 6, 3) and the rotation matrices (M, 3, 3)."""
    poses = _as_poses(poses)
    rotation = euler_to_matrix(poses[:, 3:])
    vectors = (
        np.einsum('mjk,ik->mij', rotation, geometry.platform_joints)
        + poses[:, None, :3]
        - geometry.base_joints[None]
    )
    return vectors, rotation


def inverse_kinematics(geometry, poses):
    """Articular variables ``q = |R B_i + t - A_i| - L_off_i`` (M, 6), eq (4)-(5)."""
    vectors, _ = leg_vectors(geometry, poses)
    return np.linalg.norm(vectors, axis=2) - geometry.leg_offsets[None]


def inverse_kinematics_jacobians(geometry, poses):
    """IK and its analytic derivatives: ``q`` (M, 6), ``dq/dX`` (M, 6, 6) and ``dq/du_leg``
    (M, 6, 7), ``u_leg`` = ``[A_ix, A_iy, A_iz, B_ix, B_iy, B_iz, L_off_i]``."""
    poses = _as_poses(poses)
    vectors, rotation = leg_vectors(geometry, poses)
    lengths = np.linalg.norm(vectors, axis=2)
    directions = vectors / lengths[..., None]
    d_rotation = euler_to_matrix_derivatives(poses[:, 3:])  # (M, 3, 3, 3)
    d_rotated_joints = np.einsum('makl,il->maik', d_rotation, geometry.platform_joints)
    d_q_d_pose = np.concatenate(
        [directions, np.einsum('mik,maik->mia', directions, d_rotated_joints)], axis=2
    )
    d_q_d_leg = np.concatenate(
        [
            -directions,
            np.einsum('mik,mkl->mil', directions, rotation),  # n^T R
            -np.ones(lengths.shape + (1,)),
        ],
        axis=2,
    )
    return lengths - geometry.leg_offsets[None], d_q_d_pose, d_q_d_leg


def expand_leg_parameters(d_q_d_leg):
    """Scatter per-leg derivatives (M, 6, 7) into the 42 platform parameters (M, 6, 42)."""
    count = d_q_d_leg.shape[0]
    full = np.zeros((count, 6, 42))
    legs = np.arange(6)
    for axis in range(3):
        full[:, legs, 3 * legs + axis] = d_q_d_leg[:, :, axis]
        full[:, legs, 18 + 3 * legs + axis] = d_q_d_leg[:, :, 3 + axis]
    full[:, legs, 36 + legs] = d_q_d_leg[:, :, 6]
    return full


def forward_kinematics_masked(
    geometry,
    leg_lengths,
    guess,
    tolerance=1e-12,
    max_iterations=25,
    max_position_jump=0.15,
    max_angle_jump=math.radians(30.0),
):
    """Newton's method from ``guess``, never raising: ``(poses, converged)``, False where a
    posture missed ``tolerance`` (m) or jumped beyond the limits (another assembly mode)."""
    leg_lengths = np.asarray(leg_lengths, dtype=float)
    if leg_lengths.ndim == 1:
        leg_lengths = leg_lengths[None, :]
    guess = _as_poses(guess)
    if guess.shape[0] == 1 and leg_lengths.shape[0] > 1:
        guess = np.repeat(guess, leg_lengths.shape[0], axis=0)
    if leg_lengths.shape != guess.shape:
        raise ValueError(
            f'leg_lengths {leg_lengths.shape} and guess {guess.shape} must both be (M, 6)'
        )
    poses = guess.copy()
    active = np.all(np.isfinite(leg_lengths), axis=1) & np.all(np.isfinite(poses), axis=1)
    residual_norm = np.full(poses.shape[0], np.inf)
    for iteration in range(max_iterations):
        index = np.flatnonzero(active)
        if index.size == 0:
            break
        q, d_q_d_pose, _ = inverse_kinematics_jacobians(geometry, poses[index])
        residual = q - leg_lengths[index]
        residual_norm[index] = np.max(np.abs(residual), axis=1)
        determinant = np.linalg.det(d_q_d_pose)
        solvable = np.abs(determinant) > 1e-12
        step = np.zeros_like(residual)
        if np.any(solvable):
            step[solvable] = np.linalg.solve(d_q_d_pose[solvable], residual[solvable][..., None])[
                ..., 0
            ]
        # Cap the step so a poor guess cannot throw Newton into another assembly mode.
        scale = np.maximum(
            1.0,
            np.maximum(
                np.linalg.norm(step[:, :3], axis=1) / 0.1, np.max(np.abs(step[:, 3:]), axis=1) / 0.2
            ),
        )
        poses[index] -= step / scale[:, None]
        done = (residual_norm[index] < tolerance) & (np.max(np.abs(step), axis=1) < 1e-10)
        # Newton converges quadratically from a near guess; a residual that stalls means there
        # is no solution nearby, so stop spending iterations on it.
        stalled = (iteration >= 8) & (residual_norm[index] > 1e-6)
        active[index[done | ~solvable | stalled]] = False
    final_q = inverse_kinematics(geometry, poses)
    final_residual = np.max(np.abs(final_q - leg_lengths), axis=1)
    jump_position = np.linalg.norm(poses[:, :3] - guess[:, :3], axis=1)
    jump_angle = np.max(np.abs(poses[:, 3:] - guess[:, 3:]), axis=1)
    converged = (
        np.isfinite(final_residual)
        & (final_residual < max(tolerance * 100.0, 1e-10))
        & (jump_position <= max_position_jump)
        & (jump_angle <= max_angle_jump)
    )
    return poses, converged


def forward_kinematics(geometry, leg_lengths, guess, **options):
    """Poses (M, 6) for articular variables (M, 6), by Newton's method from ``guess``;
    :class:`ForwardKinematicsError` names the posture indices that failed."""
    poses, converged = forward_kinematics_masked(geometry, leg_lengths, guess, **options)
    if not np.all(converged):
        failed = np.flatnonzero(~converged)
        raise ForwardKinematicsError(
            f'forward kinematics failed for posture(s) {failed.tolist()[:20]}: no solution '
            'within tolerance near the guess (unreachable leg lengths, singularity or another '
            'assembly mode)',
            failed,
        )
    return poses


def pose_from_leg_readings(geometry, leg_readings, guess=None):
    """The pose (6,) (m, rad) of a platform with ``geometry`` whose leg sensors read
    ``leg_readings`` (6,) m: FK from ``guess`` (default: home) with jump limits as wide as the
    workspace. :class:`ForwardKinematicsError` when none is found, ValueError on a shape."""
    readings = np.asarray(leg_readings, dtype=float)
    if readings.shape != (6,):
        raise ValueError(f'leg_readings must have shape (6,), got {readings.shape}')
    workspace = Workspace()
    guess = home_pose(workspace) if guess is None else np.asarray(guess, dtype=float)
    reach = math.hypot(workspace.xy_range, workspace.xy_range, workspace.z_max - workspace.z_min)
    return forward_kinematics(
        geometry,
        geometry.sensors.true_leg_lengths(readings[None]),
        guess[None],
        max_position_jump=reach,
        max_angle_jump=2.0 * workspace.rotation_range,
    )[0]


# --- reachability ------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Workspace:
    """Sampling ranges for random postures (the paper's: +-400 mm in x, y and +-40 deg)."""

    xy_range: float = 0.4  #: m, +- about the origin
    z_min: float = 0.85  #: m
    z_max: float = 1.15  #: m
    rotation_range: float = math.radians(40.0)  #: rad, +- for psi, theta and phi
    #: largest condition number of dq/dX allowed (away from singularity)
    max_condition: float = 60.0


def joint_angles(geometry, poses):
    """Angles (rad) of each leg to the base normal and to the platform normal, each (M, 6)."""
    vectors, rotation = leg_vectors(geometry, poses)
    lengths = np.linalg.norm(vectors, axis=2)
    base_angle = np.arccos(np.clip(vectors[..., 2] / lengths, -1.0, 1.0))
    platform_normal = rotation[:, :, 2]
    platform_angle = np.arccos(
        np.clip(np.einsum('mik,mk->mi', vectors, platform_normal) / lengths, -1.0, 1.0)
    )
    return base_angle, platform_angle


def check_reachable(geometry, poses, max_condition=None):
    """``(ok[M], reasons)``: reasons[m] is '' when reachable, else what limit is violated."""
    poses = _as_poses(poses)
    limits = geometry.limits
    finite = np.all(np.isfinite(poses), axis=1)
    safe = np.where(finite[:, None], poses, 0.0)
    q, d_q_d_pose, _ = inverse_kinematics_jacobians(geometry, safe)
    base_angle, platform_angle = joint_angles(geometry, safe)
    condition = np.linalg.cond(d_q_d_pose) if max_condition is not None else None
    ok = np.ones(poses.shape[0], dtype=bool)
    reasons = []
    for m in range(poses.shape[0]):
        problems = []
        if not finite[m]:
            problems.append('pose is not finite')
        else:
            for leg in range(6):
                if q[m, leg] < limits.leg_stroke_min:
                    problems.append(
                        f'leg_{leg + 1} stroke {q[m, leg]:.4f} m below {limits.leg_stroke_min:.4f} m'
                    )
                elif q[m, leg] > limits.leg_stroke_max:
                    problems.append(
                        f'leg_{leg + 1} stroke {q[m, leg]:.4f} m above {limits.leg_stroke_max:.4f} m'
                    )
                if base_angle[m, leg] > limits.base_joint_max_angle:
                    problems.append(
                        f'base joint {leg + 1} angle {math.degrees(base_angle[m, leg]):.1f} deg '
                        f'above {math.degrees(limits.base_joint_max_angle):.1f} deg'
                    )
                if platform_angle[m, leg] > limits.platform_joint_max_angle:
                    problems.append(
                        f'platform joint {leg + 1} angle '
                        f'{math.degrees(platform_angle[m, leg]):.1f} deg above '
                        f'{math.degrees(limits.platform_joint_max_angle):.1f} deg'
                    )
            if condition is not None and not condition[m] < max_condition:
                problems.append(f'near a singularity (condition number {condition[m]:.0f})')
        ok[m] = not problems
        reasons.append('; '.join(problems))
    return ok, reasons


def reachable_mask(geometry, poses, max_condition=None):
    """Vectorised reachability test (no reasons), for sampling."""
    poses = _as_poses(poses)
    limits = geometry.limits
    q, d_q_d_pose, _ = inverse_kinematics_jacobians(geometry, poses)
    base_angle, platform_angle = joint_angles(geometry, poses)
    ok = (
        np.all(q >= limits.leg_stroke_min, axis=1)
        & np.all(q <= limits.leg_stroke_max, axis=1)
        & np.all(base_angle <= limits.base_joint_max_angle, axis=1)
        & np.all(platform_angle <= limits.platform_joint_max_angle, axis=1)
    )
    if max_condition is not None:
        ok &= np.linalg.cond(d_q_d_pose) < max_condition
    return ok


def sample_postures(rng, count, workspace=Workspace()):
    """Uniform random postures in the workspace box (not checked for reachability)."""
    high = np.array([workspace.xy_range] * 2 + [workspace.z_max] + [workspace.rotation_range] * 3)
    low = -high
    low[2] = workspace.z_min
    return rng.uniform(low, high, size=(count, 6))


def sample_valid_postures(geometry, count, rng, workspace=Workspace(), max_draws=2_000_000):
    """``count`` random reachable, well-conditioned postures (M, 6) from the workspace box."""
    accepted, total, drawn = [], 0, 0
    while total < count:
        if drawn >= max_draws:
            raise RuntimeError(
                f'only {total} of {count} reachable postures in {drawn} draws: the workspace '
                "does not fit the geometry's limits"
            )
        batch = sample_postures(rng, 4096, workspace)
        drawn += batch.shape[0]
        good = batch[reachable_mask(geometry, batch, workspace.max_condition)]
        accepted.append(good)
        total += good.shape[0]
    return np.concatenate(accepted)[:count]


def home_pose(workspace=Workspace()):
    """Centre of the workspace, level."""
    return np.array([0.0, 0.0, 0.5 * (workspace.z_min + workspace.z_max), 0.0, 0.0, 0.0])
