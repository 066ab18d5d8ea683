"""Does freeing an effect group make the compensated platform more accurate? The predicted mean
squared position error over the workspace with the group and without it
(docs/platform_effects.md#choosing-the-model-auto)."""

import dataclasses

import numpy as np

from ...model.effects import EFFECT_GROUPS, NUM_LEGS
from ...model.kinematics import Workspace, inverse_kinematics_jacobians, sample_valid_postures
from ..identifiability import analyse_result, identifies_all
from ..prediction import pose_sensitivities

#: Groups the controllers compensate at each commanded pose: the rule judges these.
COMPENSATED_GROUPS = ('compliance', 'backlash', 'joint_offsets')
#: Random workspace postures the mean is taken over (seeded: the choice is repeatable).
WORKSPACE_POSTURES = 200
_BACKLASH = list(EFFECT_GROUPS).index('backlash')


@dataclasses.dataclass(frozen=True)
class FreeingGain:
    """Predicted rms position errors (mm) over the workspace without the group (its variance
    plus the estimated bias of leaving it out) and with it (its variance); NaN: not predicted
    (a fit's covariance is not a covariance: :func:`freeing_gain`)."""

    without_mm: float
    with_mm: float


def workspace_postures(geometry, count=WORKSPACE_POSTURES, workspace=Workspace()):
    """The seeded random workspace postures (M, 6) the rule averages over."""
    return sample_valid_postures(geometry, count, np.random.default_rng(0), workspace)


def _columns(result, poses):
    """``(S (M, 3, n), backlash (M, 3, n))``: position sensitivities over ``result``'s free
    parameters then free effects; the backlash columns apart (added in quadrature)."""
    geometry, effect_free = result.geometry, np.asarray(result.effect_free, bool)
    main = pose_sensitivities(geometry, poses, result.free, effect_free=effect_free)[:, :3]
    backlash = np.zeros_like(main)
    first = int(np.sum(result.free))
    _, d_q_d_pose, _ = inverse_kinematics_jacobians(geometry, poses)
    per_leg = 0.5 * np.linalg.inv(d_q_d_pose)[:, :3, :]  # (M, 3, legs): dp per unit lost motion
    for leg in range(NUM_LEGS):
        index = _BACKLASH * NUM_LEGS + leg
        if effect_free[index]:
            backlash[:, :, first + int(np.sum(effect_free[:index]))] = per_leg[:, :, leg]
    return main, backlash


def _in_parameters_of(result, reference):
    """``reference``'s estimates and covariance in ``result``'s free parameters then effects
    (a parameter ``reference`` keeps fixed: its value, zero variance)."""
    free, effect_free = result.free, np.asarray(result.effect_free, bool)
    values = np.concatenate([reference.parameters[free], reference.effect_values[effect_free]])
    own = np.concatenate([reference.free, reference.effect_free])[
        np.concatenate([free, effect_free])
    ]
    covariance = np.zeros((own.size, own.size))
    covariance[np.ix_(own, own)] = reference.covariance
    return values, covariance


def _mean_square(main, backlash, vector=None, covariance=None):
    """Mean over the postures of ``E|dp|^2`` (m^2) of ``vector`` or of a ``covariance``."""
    if vector is not None:
        return float(
            np.mean(
                np.sum((main @ vector) ** 2, axis=1) + np.sum((backlash * vector) ** 2, axis=(1, 2))
            )
        )
    spread = np.einsum('mik,mik->m', main @ covariance, main)  # two operands: one matmul
    spread += np.einsum('mij,j,mij->m', backlash, np.diag(covariance), backlash)
    return float(np.mean(spread))


def freeing_gain(reference, extended, poses):
    """:class:`FreeingGain` of the fit ``extended`` (``reference`` plus effect groups, the
    same rows and weights) at the workspace ``poses`` (M, 6; :func:`workspace_postures`); NaN
    gain unless both fits identify their parameters (checked on the rank)."""
    if not all(identifies_all(analyse_result(fit)) for fit in (reference, extended)):
        return FreeingGain(float('nan'), float('nan'))
    main, backlash = _columns(extended, poses)
    own = np.concatenate(
        [extended.parameters[extended.free], extended.effect_values[extended.effect_free]]
    )
    values, covariance_a = _in_parameters_of(extended, reference)
    var_b = _mean_square(main, backlash, covariance=np.asarray(extended.covariance, float))
    var_a = _mean_square(main, backlash, covariance=covariance_a)
    difference = _mean_square(main, backlash, vector=own - values)
    if not (var_a >= 0.0 and var_b >= 0.0):  # not a covariance (also False for NaN)
        return FreeingGain(float('nan'), float('nan'))
    # The bias estimate is a difference of noisy terms: below zero it is noise, no bias.
    bias = max(difference - (var_b - var_a), 0.0)
    return FreeingGain(1e3 * np.sqrt(var_a + bias), 1e3 * np.sqrt(var_b))
