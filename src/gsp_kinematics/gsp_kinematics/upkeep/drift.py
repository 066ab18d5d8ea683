"""Drift between two calibrations of one platform: what changed, whether it is significant, and
what it does to the pose (pure numpy/scipy)."""

import dataclasses
import math

import numpy as np
from scipy import stats

from ..estimation.prediction import expected_norm, mean_p95_max, pose_sensitivities
from ..model.geometry import (
    ALL_PARAMETER_NAMES,
    ANGULAR_SENSOR_PARAMETERS,
    NUM_ALL_PARAMETERS,
    PARAMETER_INDEX,
    SENSOR_PARAMETER_NAMES,
)
from ..model.kinematics import Workspace, sample_valid_postures

#: Family-wise level of the drift and check tests (two calibrations of an unchanged platform
#: are called changed in about this fraction of cases).
DEFAULT_LEVEL = 0.01
#: Random reachable postures the effect on the pose is taken over (seeded: repeatable).
EFFECT_POSTURES = 200


def report_scale(name):
    """``(factor, unit)`` turning parameter ``name``'s SI value into report units: mm for
    lengths, deg for angles, ppm for the gain errors (``kq1..kq6``, ``kDm``)."""
    if name == 'gamma' or name in ANGULAR_SENSOR_PARAMETERS:
        return math.degrees(1.0), 'deg'
    if name in SENSOR_PARAMETER_NAMES:
        return 1e6, 'ppm'
    return 1e3, 'mm'


@dataclasses.dataclass(frozen=True)
class Calibration:
    """What a comparison needs of one calibration (or of a check's small identification)."""

    names: tuple  #: the free parameters (names of ALL_PARAMETER_NAMES)
    estimates: np.ndarray  #: (n,) SI
    covariance: np.ndarray  #: (n, n) SI; a diagonal one when only sigmas are known
    geometry: object = None  #: the calibrated Geometry (the pose effect is taken about it)
    label: str = ''  #: e.g. the run directory

    def __post_init__(self):
        unknown = [name for name in self.names if name not in PARAMETER_INDEX]
        if unknown:
            raise ValueError(f'unknown parameter names {unknown}')
        n = len(self.names)
        if np.shape(self.estimates) != (n,) or np.shape(self.covariance) != (n, n):
            raise ValueError(
                f'{self.label or "calibration"}: {n} names need {n} estimates and an {n}x{n} '
                f'covariance, got {np.shape(self.estimates)} and {np.shape(self.covariance)}'
            )

    def subset(self, names):
        index = [self.names.index(name) for name in names]
        return self.estimates[index], self.covariance[np.ix_(index, index)]


def _critical(level, count):
    """Two-sided Bonferroni bound on a standard normal for ``count`` tests at family ``level``."""
    return float(stats.norm.isf(level / (2.0 * max(count, 1))))


def localise(change, weight, level=DEFAULT_LEVEL, dof=None):
    """Iterated w-tests: ``(named, rest)`` with ``named`` a list of ``(index, change, sigma, w)``
    (the change of each named parameter given the others named before it) and ``rest`` the
    ``(T, dof, p)`` of what the named changes leave unexplained."""
    count = len(change)
    dof = count if dof is None else dof
    critical = _critical(level, count)
    named = []
    while True:
        chosen = [index for index, *_ in named]
        residual_weight = weight
        if chosen:  # W - W E (E^T W E)^-1 E^T W: the weight of d once the named ones are free
            block = weight[:, chosen]
            residual_weight = weight - block @ np.linalg.solve(block[chosen], block.T)
        statistic = float(change @ residual_weight @ change)
        rest_dof = dof - len(chosen)
        p_value = float(stats.chi2.sf(statistic, max(rest_dof, 1)))
        if p_value >= level or rest_dof <= 0:
            break
        projected = residual_weight @ change
        diagonal = np.diagonal(residual_weight).copy()
        diagonal[chosen] = np.inf
        w = projected / np.sqrt(np.maximum(diagonal, 1e-300))
        best = int(np.argmax(np.abs(w)))
        if abs(w[best]) < critical:
            break
        named.append([best, 0.0, 0.0, float(w[best])])
        # The named changes estimated together (the earlier ones shift as later ones join).
        chosen = [index for index, *_ in named]
        information = weight[np.ix_(chosen, chosen)]
        covariance = np.linalg.inv(information)
        estimate = covariance @ (weight[chosen] @ change)
        for entry, value, variance in zip(named, estimate, np.diag(covariance), strict=True):
            entry[1], entry[2] = float(value), float(math.sqrt(max(variance, 0.0)))
    return [tuple(entry) for entry in named], (statistic, rest_dof, p_value)


def pose_effect(geometry, names, vector, covariance, poses):
    """Effect of parameter changes ``vector`` (over ``names``) at ``poses``: mean, p95, max of
    the position (mm) and orientation (deg) change, and the 1-sigma expected magnitude of the
    change's uncertainty ``covariance``."""
    mask = np.zeros(NUM_ALL_PARAMETERS, dtype=bool)
    index = [PARAMETER_INDEX[name] for name in names]
    mask[index] = True
    order = np.argsort(index)  # the sensitivity's columns follow ALL_PARAMETER_NAMES
    sensitivity = pose_sensitivities(geometry, poses, mask)
    shift = sensitivity @ np.asarray(vector)[order]
    position = 1000.0 * np.linalg.norm(shift[:, :3], axis=1)
    orientation = np.degrees(np.linalg.norm(shift[:, 3:], axis=1))
    effect = {
        'position_mm': mean_p95_max(position),
        'orientation_deg': mean_p95_max(orientation),
        'postures': int(len(poses)),
    }
    if covariance is not None:
        ordered = np.asarray(covariance)[np.ix_(order, order)]
        pose_covariance = sensitivity @ ordered @ np.swapaxes(sensitivity, 1, 2)
        effect['uncertainty_position_mm_mean'] = float(
            1000.0 * expected_norm(pose_covariance[:, :3, :3]).mean()
        )
        effect['uncertainty_orientation_deg_mean'] = float(
            np.degrees(expected_norm(pose_covariance[:, 3:, 3:])).mean()
        )
    return effect


def effect_poses(geometry, count=EFFECT_POSTURES, seed=0, workspace=Workspace()):
    """The seeded random reachable postures a pose effect is taken over."""
    return sample_valid_postures(geometry, count, np.random.default_rng(seed), workspace)


def compare(first, second, level=DEFAULT_LEVEL, poses=None):
    """Drift from calibration ``first`` to ``second`` (:class:`Calibration`): a JSON-ready dict of
    ``parameters`` (per common parameter: change, sigma, ``z``, ``w``), ``global_test``,
    ``significant`` (iterated w-tests) and ``effect`` on the pose over ``poses`` (default
    :func:`effect_poses`; docs/upkeep.md)."""
    names = tuple(
        name for name in ALL_PARAMETER_NAMES if name in first.names and name in second.names
    )
    if not names:
        raise ValueError('the two calibrations have no free parameter in common')
    estimates_1, covariance_1 = first.subset(names)
    estimates_2, covariance_2 = second.subset(names)
    change = estimates_2 - estimates_1
    covariance = covariance_1 + covariance_2
    weight = np.linalg.pinv(covariance, hermitian=True)
    dof = int(np.linalg.matrix_rank(covariance, hermitian=True))
    statistic = float(change @ weight @ change)
    named, rest = localise(change, weight, level, dof)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    diagonal = np.maximum(np.diag(weight), 1e-300)
    w = (weight @ change) / np.sqrt(diagonal)
    parameters = {}
    for j, name in enumerate(names):
        factor, unit = report_scale(name)
        parameters[name] = {
            'change_si': float(change[j]),
            'sigma_si': float(sigma[j]),
            'change_report': float(change[j] * factor),
            'sigma_report': float(sigma[j] * factor),
            'conditional_sigma_report': float(factor / math.sqrt(diagonal[j])),
            'unit': unit,
            'z': float(change[j] / sigma[j]) if sigma[j] > 0 else None,
            'w': float(w[j]),
        }
    significant = []
    for index, value, value_sigma, score in named:
        factor, unit = report_scale(names[index])
        significant.append(
            {
                'parameter': names[index],
                'change_report': value * factor,
                'sigma_report': value_sigma * factor,
                'unit': unit,
                'w': score,
            }
        )
    data = {
        'first': first.label,
        'second': second.label,
        'level': level,
        'test': (
            'global chi-square of the change over both covariances, then iterated Baarda '
            f'w-tests, two-sided Bonferroni over {len(names)} parameters '
            f'(|w| > {_critical(level, len(names)):.2f})'
        ),
        'global_test': {
            'statistic': statistic,
            'dof': dof,
            'p_value': float(stats.chi2.sf(statistic, max(dof, 1))),
            'changed': bool(stats.chi2.sf(statistic, max(dof, 1)) < level),
        },
        'unexplained': {'statistic': rest[0], 'dof': rest[1], 'p_value': rest[2]},
        'significant': significant,
        'parameters': parameters,
    }
    geometry = second.geometry if second.geometry is not None else first.geometry
    if geometry is not None:
        poses = effect_poses(geometry) if poses is None else poses
        data['effect'] = {'all': pose_effect(geometry, names, change, covariance, poses)}
        if named:
            chosen = [names[index] for index, *_ in named]
            values = [value for _, value, *_ in named]
            data['effect']['significant'] = pose_effect(geometry, chosen, values, None, poses)
    return data
