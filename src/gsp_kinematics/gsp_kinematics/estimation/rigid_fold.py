"""The best rigid geometry for a controller that cannot compensate the identified effects
(docs/platform_effects.md)."""

import dataclasses

import numpy as np

from ..model.effect_groups import EffectDesign, compensated_leg_readings, model_poses
from ..model.effects import EFFECT_GROUPS, IdentifiedEffects, approach_directions
from ..model.geometry import PARAMETER_INDEX
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
#: The fold's parameters in ``Geometry.to_full_vector`` order: A (18), B (18), L_off (6), and
#: the leg sensors' gain errors kq (6), which the controller's IK goes through.
_GAINS = PARAMETER_INDEX['kq1']
FOLD_PARAMETERS = np.r_[0:42, _GAINS : _GAINS + 6]
RIGID_PARAMETERS = len(FOLD_PARAMETERS)
#: m per rad: a rotation's weight beside a position in the pose error the fold minimises.
ROTATION_WEIGHT_M = 0.5
#: Gauss-Newton iterations of the fold: the first :data:`PLAIN_ITERATIONS` in least squares,
#: then each posture weighted by the inverse of its pose error (the mean pose error, not its
#: square, which the few postures near the workspace's edge would rule).
FOLD_ITERATIONS = 12
PLAIN_ITERATIONS = 2
#: Pose errors (m) below this weigh as this in the reweighting.
ERROR_FLOOR = 1e-7
#: Groups a rigid geometry can take a share of (the thermal growth is zero at the operating
#: state; the backlash's share is its mean over the directions the legs arrive from).
FOLDED_GROUPS = ('compliance', 'backlash', 'joint_offsets')
_GROUP_INDEX = {group: index for index, group in enumerate(EFFECT_GROUPS)}
_BACKLASH = slice(6 * _GROUP_INDEX['backlash'], 6 * _GROUP_INDEX['backlash'] + 6)


def fold_postures(geometry, workspace=Workspace(), count=FOLD_POSTURES, seed=FOLD_SEED):
    """The postures (count, 6) the fold is taken over: reachable ones of ``geometry`` drawn
    uniformly over ``workspace`` (seeded by ``seed``)."""
    return sample_valid_postures(geometry, count, np.random.default_rng(seed), workspace)


def operating_effects(effects):
    """``effects`` (IdentifiedEffects) at the operating state a rigid geometry is folded for,
    without the backlash (its share is :func:`compensated_leg_lengths`'): the thermal parameters
    zero (the reference instant)."""
    values = np.array(effects.values)
    for group in EFFECT_GROUPS:
        if group not in ('compliance', 'joint_offsets'):
            index = _GROUP_INDEX[group]
            values[6 * index : 6 * index + 6] = 0.0
    return dataclasses.replace(effects, values=values)


def mean_directions(lengths):
    """The mean approach direction (M, 6), in [-1, 1], of each leg at each of the M workspace
    postures of its ``lengths`` (M, 6) when the controller moves among them at random: a leg
    arrives extending from a shorter length, so ``2 F(q) - 1`` with F the distribution of the
    leg's length over the postures (its rank among them)."""
    ranks = np.argsort(np.argsort(lengths, axis=0, kind='stable'), axis=0, kind='stable')
    return 2.0 * ranks / max(len(lengths) - 1, 1) - 1.0


def compensated_leg_lengths(geometry, poses):
    """True leg lengths (M, 6) m (articular, ``(1 + kq) q``) the compensating controller of
    ``geometry`` (its identified effects at the operating state) drives to at the workspace
    ``poses`` (M, 6), moving among them at random: the backlash's half in each leg's mean
    approach direction there (:func:`mean_directions`)."""
    readings = compensated_leg_readings(geometry, operating_effects(geometry.effects), poses)
    lengths = geometry.sensors.true_leg_lengths(readings)
    return lengths + 0.5 * mean_directions(lengths) * geometry.effects.values[_BACKLASH]


def rigid_leg_jacobian(geometry, poses, sensors=None):
    """True leg lengths (M, 6) m the rigid controller of ``geometry`` drives to at ``poses``
    (its IK through its leg gains ``kq``) on legs whose sensors are ``sensors`` (None:
    ``geometry``'s), and their derivatives (M, 6, 48) with respect to
    :data:`FOLD_PARAMETERS` (analytic)."""
    return _driven_legs(geometry, poses, sensors)[:2]


def _driven_legs(geometry, poses, sensors=None):
    """:func:`rigid_leg_jacobian`'s lengths and derivatives, and the map (M, 6, 6) of a leg
    length error to the pose error (position m, rotation at :data:`ROTATION_WEIGHT_M`)."""
    sensors = geometry.sensors if sensors is None else sensors
    articular, d_pose, d_leg = inverse_kinematics_jacobians(geometry, poses)
    own = 1.0 + geometry.sensors.leg_gain_errors
    ratio = (1.0 + sensors.leg_gain_errors) / own
    lengths = articular * ratio
    d_gains = (-lengths / own)[..., None] * np.eye(6)
    jacobian = np.concatenate([expand_leg_parameters(d_leg) * ratio[:, None], d_gains], 2)
    to_pose = np.linalg.inv(d_pose)
    to_pose[:, 3:] *= ROTATION_WEIGHT_M
    return lengths, jacobian, to_pose


def fit_rigid_geometry(geometry, poses, leg_lengths, iterations=FOLD_ITERATIONS):
    """The rigid geometry (``geometry`` with A, B, L_off and the leg gains refitted, no
    effects) that best drives the legs of ``geometry`` (its sensors) to ``leg_lengths`` (M, 6)
    m (articular) at ``poses`` (M, 6): the least mean pose error there (the leg errors through
    the inverse leg Jacobian, rotation at :data:`ROTATION_WEIGHT_M`), by Gauss-Newton from
    ``geometry``, least squares first, then each posture weighted by its error's inverse."""
    rigid = geometry.replace(effects=IdentifiedEffects())
    target = np.asarray(leg_lengths, dtype=float)
    vector = rigid.to_full_vector()
    weights = np.ones(len(target))
    for iteration in range(iterations):
        lengths, jacobian, to_pose = _driven_legs(rigid, poses, geometry.sensors)
        errors = (to_pose @ (target - lengths)[..., None])[..., 0]
        if iteration >= PLAIN_ITERATIONS:
            norms = np.linalg.norm(errors, axis=1)
            weights = 1.0 / np.sqrt(np.maximum(norms, ERROR_FLOOR))
        matrix = (weights[:, None, None] * (to_pose @ jacobian)).reshape(-1, RIGID_PARAMETERS)
        scale = np.linalg.norm(matrix, axis=0)
        step, *_ = np.linalg.lstsq(matrix / scale, (weights[:, None] * errors).ravel(), rcond=None)
        vector[FOLD_PARAMETERS] += step / scale
        rigid = type(geometry).from_full_vector(vector, geometry.limits)
    return rigid


def fold_effects(geometry, poses=None):
    """The best rigid geometry (no effects) for ``geometry`` and its identified effects over
    the workspace ``poses`` (M, 6; None: :func:`fold_postures`), the controller moving among
    them at random; ``geometry`` itself without effects when it has none a rigid geometry can
    take a share of."""
    if not any(group in FOLDED_GROUPS for group in geometry.effects.groups()):
        return geometry.replace(effects=IdentifiedEffects())
    poses = fold_postures(geometry) if poses is None else np.asarray(poses, dtype=float)
    return fit_rigid_geometry(geometry, poses, compensated_leg_lengths(geometry, poses))


def workspace_directions(readings):
    """Both ``(M, 6)`` approach directions of the legs at M workspace postures of leg
    ``readings`` (M, 6): visited in their order, then in reverse (each posture approached
    from the one before it, then from the one after it: a controller moving among them at
    random when they are drawn at random)."""
    readings = np.asarray(readings, dtype=float)
    return approach_directions(readings), approach_directions(readings[::-1])[::-1]


def rigid_model_errors(geometry, rigid, poses, phi=False):
    """``(position (2M,) mm, phi (2M,) deg)`` errors where the platform the identified model
    describes (``geometry`` with its effects) goes when the rigid controller of ``rigid`` drives
    ``poses`` (M, 6), each approached from both neighbours (:func:`workspace_directions`)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    readings = rigid.sensors.leg_readings(inverse_kinematics(rigid, poses))
    effects = geometry.effects
    errors, phi_errors = [], []
    for directions in workspace_directions(readings):
        design = EffectDesign(
            np.full(len(poses), effects.reference_time_s),
            directions,
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
    readings = rigid.sensors.leg_readings(inverse_kinematics(rigid, poses))
    commanded = sensors.true_leg_lengths(readings)
    _, d_leg_d_pose, _ = inverse_kinematics_jacobians(geometry, poses)
    errors, phi_errors = [], []
    for directions in workspace_directions(readings):
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
