"""The best rigid geometry for a controller that cannot compensate the identified effects
(docs/platform_effects.md)."""

import dataclasses

import numpy as np

from ..model.effect_groups import EffectDesign, compensated_leg_readings, model_poses
from ..model.effects import EFFECT_GROUPS, IdentifiedEffects
from ..model.kinematics import (
    Workspace,
    expand_leg_parameters,
    inverse_kinematics,
    inverse_kinematics_jacobians,
    sample_valid_postures,
)
from ..model.validation import pose_errors
from ..rotation import wrap_angle

#: Workspace postures of the fold (reachable, well-conditioned; seeded: the same fold each time).
FOLD_POSTURES = 400
FOLD_SEED = 0
#: Workspace postures a rigid geometry's accuracy is taken over: its error has a tail (a few
#: postures in a thousand near the workspace's edge, 50x the mean) that 1000 sample to 20 %.
ACCURACY_POSTURES = 4000
#: The fold's 42 parameters: A (18), B (18), L_off (6), in ``Geometry.to_vector`` order.
RIGID_PARAMETERS = 42
#: Gauss-Newton stops when the largest step is below this (m): the effects are micrometres.
STEP_TOLERANCE = 1e-13
#: Groups a rigid geometry can take a share of (the others are zero at the operating state).
FOLDED_GROUPS = ('compliance', 'joint_offsets')
_GROUP_INDEX = {group: index for index, group in enumerate(EFFECT_GROUPS)}


def fold_postures(geometry, workspace=Workspace(), count=FOLD_POSTURES, seed=FOLD_SEED):
    """The postures (count, 6) the fold is taken over: reachable ones of ``geometry`` drawn
    uniformly over ``workspace`` (seeded by ``seed``)."""
    return sample_valid_postures(geometry, count, np.random.default_rng(seed), workspace)


def operating_effects(effects):
    """``effects`` (IdentifiedEffects) at the operating state a rigid geometry is folded for:
    the backlash and thermal parameters zero (the mean of both approach directions, the
    reference instant)."""
    values = np.array(effects.values)
    for group in EFFECT_GROUPS:
        if group not in FOLDED_GROUPS:
            index = _GROUP_INDEX[group]
            values[6 * index : 6 * index + 6] = 0.0
    return dataclasses.replace(effects, values=values)


def compensated_leg_lengths(geometry, poses):
    """True leg lengths (M, 6) m (articular, ``(1 + kq) q``) the compensating controller of
    ``geometry`` (with its identified effects at the operating state) drives to at ``poses``."""
    readings = compensated_leg_readings(geometry, operating_effects(geometry.effects), poses)
    return geometry.sensors.true_leg_lengths(readings)


def rigid_leg_jacobian(geometry, poses):
    """Leg lengths (M, 6) of ``geometry``'s rigid IK at ``poses`` and their derivatives
    (M, 6, 42) with respect to A, B and L_off (analytic)."""
    lengths, _, d_leg = inverse_kinematics_jacobians(geometry, poses)
    return lengths, expand_leg_parameters(d_leg)


def fit_rigid_geometry(geometry, poses, leg_lengths, iterations=8):
    """The rigid geometry (``geometry`` with A, B and L_off refitted, no effects) whose IK best
    reproduces ``leg_lengths`` (M, 6) m (articular) at ``poses`` (M, 6), by Gauss-Newton from
    ``geometry`` in leg-length least squares."""
    rigid = geometry.replace(effects=IdentifiedEffects())
    target = np.asarray(leg_lengths, dtype=float)
    vector = rigid.to_vector()
    for _ in range(iterations):
        lengths, jacobian = rigid_leg_jacobian(rigid, poses)
        matrix = jacobian.reshape(-1, RIGID_PARAMETERS)
        scale = np.linalg.norm(matrix, axis=0)
        step, *_ = np.linalg.lstsq(matrix / scale, (target - lengths).ravel(), rcond=None)
        step /= scale
        vector[:RIGID_PARAMETERS] += step
        rigid = _with_vector(rigid, vector)
        if not np.max(np.abs(step)) > STEP_TOLERANCE:
            break
    return rigid


def fold_effects(geometry, poses=None):
    """The best rigid geometry (no effects) for ``geometry`` and its identified effects over
    the workspace ``poses`` (M, 6; None: :func:`fold_postures`); ``geometry`` itself without
    effects when it has none a rigid geometry can take a share of."""
    if not np.any(operating_effects(geometry.effects).values):
        return geometry.replace(effects=IdentifiedEffects())
    poses = fold_postures(geometry) if poses is None else np.asarray(poses, dtype=float)
    return fit_rigid_geometry(geometry, poses, compensated_leg_lengths(geometry, poses))


def rigid_model_errors(geometry, rigid, poses, phi=False):
    """``(position (2M,) mm, phi (2M,) deg)`` errors where the platform the identified model
    describes (``geometry`` with its effects) goes when the rigid controller of ``rigid`` drives
    ``poses`` (M, 6), every leg arriving extending then retracting."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    readings = rigid.sensors.leg_readings(inverse_kinematics(rigid, poses))
    effects = geometry.effects
    errors, phi_errors = [], []
    for direction in (1.0, -1.0):
        design = EffectDesign(
            np.full(len(poses), effects.reference_time_s),
            np.full((len(poses), 6), direction),
            effects.payload_mass,
            effects.centre_of_mass,
            effects.reference_time_s,
        )
        reached, converged = model_poses(geometry, readings, poses, design)
        errors.append(pose_errors(poses[converged], reached[converged])[0])
        phi_errors.append(
            np.degrees(np.abs(wrap_angle(reached[converged, 5] - poses[converged, 5])))
        )
    if phi:
        return np.concatenate(errors), np.concatenate(phi_errors)
    return np.concatenate(errors)


def linearised_model_errors(geometry, rigid, poses):
    """``(position (2M,) mm, phi (2M,) deg)``: :func:`rigid_model_errors` to first order (ten
    times cheaper), through the inverse of ``geometry``'s rigid leg Jacobian ``dq/dX``."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    sensors = geometry.sensors
    commanded = sensors.true_leg_lengths(
        rigid.sensors.leg_readings(inverse_kinematics(rigid, poses))
    )
    _, d_leg_d_pose, _ = inverse_kinematics_jacobians(geometry, poses)
    errors, phi_errors = [], []
    for direction in (1.0, -1.0):
        directions = np.full((len(poses), 6), direction)
        needed = compensated_leg_readings(geometry, geometry.effects, poses, directions)
        step = np.linalg.solve(
            d_leg_d_pose, (commanded - sensors.true_leg_lengths(needed))[..., None]
        )
        errors.append(1e3 * np.linalg.norm(step[:, :3, 0], axis=1))
        phi_errors.append(np.degrees(np.abs(step[:, 5, 0])))
    return np.concatenate(errors), np.concatenate(phi_errors)


def held_out_postures(geometry):
    """The workspace postures (:data:`ACCURACY_POSTURES`, 6) a rigid geometry's accuracy is
    taken over: drawn as the fold's (:func:`fold_postures`), with another seed."""
    return fold_postures(geometry, count=ACCURACY_POSTURES, seed=FOLD_SEED + 1)


def _with_vector(geometry, vector):
    rigid = type(geometry).from_vector(vector, geometry.limits)
    return rigid.replace(sensors=geometry.sensors)


def rigid_accuracy(geometry, rigid, compensated_mm=0.0, poses=None, systematic=None):
    """The predicted accuracy (mm) over the workspace of a rigid controller running ``rigid`` on
    the platform ``geometry`` (with its effects) describes: ``{'position_mm': {mean, max},
    'systematic_position_mm': {mean, max, rms}, 'postures'}``: :func:`rigid_model_errors` over
    ``poses`` (None: workspace postures; ``systematic``: those errors, already computed) and
    ``compensated_mm`` added in quadrature at each."""
    if poses is None:
        poses = held_out_postures(geometry)
    if systematic is None:
        systematic = rigid_model_errors(geometry, rigid, poses)
    total = np.hypot(systematic, compensated_mm)
    return {
        'position_mm': {'mean': float(total.mean()), 'max': float(total.max())},
        'systematic_position_mm': {
            'mean': float(systematic.mean()),
            'max': float(systematic.max()),
            'rms': float(np.sqrt(np.mean(systematic**2))),
        },
        'postures': int(len(poses)),
    }
