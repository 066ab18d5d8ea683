"""What a held-out posture's comparison sees of a fit's parameter error, and what it cannot
(docs/verdict.md)."""

import numpy as np

from ...model.device import device_position, link_direction, link_direction_derivatives
from ...model.effects import EFFECT_GROUPS, NUM_EFFECT_PARAMETERS
from ...model.geometry import ALL_PARAMETER_NAMES
from ..prediction import POSTURE_EFFECT_GROUPS, effect_pose_derivatives, pose_sensitivities

#: The device's own parameters: their errors move where the device says the platform is.
DEVICE_PARAMETERS = ('D0', 'gamma', 'alpha0', 'beta0', 'phi0', 'kDm')


def device_pose(geometry, readings):
    """What the device measures under ``geometry``'s device parameters and sensor errors:
    ``(position (M, 3) m, phi (M,) rad)`` from readings ``[alpha, beta, phi, d_m]`` (M, 4)."""
    ideal = geometry.sensors.ideal_device_readings(np.atleast_2d(readings))
    position = device_position(
        ideal[:, 0],
        ideal[:, 1],
        geometry.device_length + ideal[:, 3],
        geometry.inclinometer_axes_angle,
    )
    return position, ideal[:, 2]


def _effect_free(result):
    """(24,) bool: ``result``'s free effect parameters (none when it has no ``effect_free``)."""
    free = getattr(result, 'effect_free', None)
    return np.zeros(NUM_EFFECT_PARAMETERS, bool) if free is None else np.asarray(free, bool)


def device_sensitivities(result, readings):
    """``(position (M, 3, p) m, phi (M, p) rad)``: what the device measures at ``readings``
    (M, 4) per unit error of each of ``result``'s free parameters then free effects (nonzero only
    for :data:`DEVICE_PARAMETERS`; eq 9 with the sensor errors)."""
    readings = np.atleast_2d(np.asarray(readings, dtype=float))
    geometry = result.geometry
    size = np.asarray(result.covariance).shape[0]
    position = np.zeros((len(readings), 3, size))
    phi = np.zeros((len(readings), size))
    ideal = geometry.sensors.ideal_device_readings(readings)
    gamma = geometry.inclinometer_axes_angle
    length = geometry.device_length + ideal[:, 3]
    unit = link_direction(ideal[:, 0], ideal[:, 1], gamma)
    d_alpha, d_beta, d_gamma = link_direction_derivatives(ideal[:, 0], ideal[:, 1], gamma)
    columns = {
        'D0': unit,
        'gamma': length[:, None] * d_gamma,
        'alpha0': -length[:, None] * d_alpha,  # the model's inclination is reading - alpha0
        'beta0': -length[:, None] * d_beta,
        'kDm': readings[:, 3, None] * unit,  # D grows by the raw LVDT reading per unit gain
    }
    for column, name in enumerate(np.asarray(ALL_PARAMETER_NAMES)[result.free]):
        if name in columns:
            position[:, :, column] = columns[name]
        elif name == 'phi0':
            phi[:, column] = -1.0
    return position, phi


def _effect_columns(result, poses, design):
    """(M, 6, count): ``[dp; d(psi, theta, phi)]`` of the reached pose per error of each free
    effect, its regressor at the rows' ``design`` (times, directions; None: a design with the
    geometry's payload only, for the groups that need neither)."""
    free = _effect_free(result)
    if not free.any():
        return np.zeros((len(poses), 6, 0))
    return effect_pose_derivatives(result.geometry, poses, free, design)


def _compensated(result):
    """(p,) bool: the columns the controller's pose moves with (the geometry's, and the effect
    groups it compensates by posture, :data:`~gsp_kinematics.estimation.prediction.POSTURE_EFFECT_GROUPS`)."""
    free = _effect_free(result)
    groups = np.repeat([g in POSTURE_EFFECT_GROUPS for g in EFFECT_GROUPS], 6)
    return np.concatenate([np.ones(int(np.sum(result.free)), bool), groups[free]])


def comparison_sensitivities(result, poses, readings, design=None):
    """``(controller (M, 4, p), comparison (M, 4, p))``: rows ``[dp (m); d phi (rad)]`` per unit
    error of each free parameter then free effect of ``result`` at ``poses`` (M, 6) with device
    ``readings`` (M, 4): of the pose the controller reaches and of the held-out comparison;
    ``design``: the rows' ``EffectDesign``."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    geometry_columns = pose_sensitivities(result.geometry, poses, result.free, euler=True)
    legs = np.concatenate([geometry_columns, _effect_columns(result, poses, design)], axis=2)
    legs = legs[:, [0, 1, 2, 5]]
    position, phi = device_sensitivities(result, readings)
    device = np.concatenate([position, phi[:, None]], axis=1)
    return legs * _compensated(result)[None, None], -(legs + device)


def comparison_variances(result, poses, readings, design=None, sensitivities=None):
    """``(controller, comparison)``, each ``(position (M,) m^2, the trace; phi (M,) rad^2)``:
    ``result``'s parameter covariance propagated through :func:`comparison_sensitivities`
    (``sensitivities``: theirs at these arguments, if computed; NaN where the covariance is not
    finite)."""
    covariance = np.asarray(result.covariance, dtype=float)
    count = np.atleast_2d(poses).shape[0]
    if not np.all(np.isfinite(covariance)):
        unknown = np.full(count, np.nan)
        return (unknown, unknown), (unknown, unknown)
    if sensitivities is None:
        sensitivities = comparison_sensitivities(result, poses, readings, design)
    return tuple(propagated_variances(sensitivity, covariance) for sensitivity in sensitivities)


def propagated_variances(sensitivity, covariance):
    """``(position (M,) m^2, the trace; phi (M,) rad^2)`` of rows ``[dp; d phi]``
    ``sensitivity`` (M, 4, p) over a parameter ``covariance`` (p, p)."""
    moments = np.einsum('miq,miq->mi', sensitivity @ covariance, sensitivity)
    return moments[:, :3].sum(axis=1), moments[:, 3]


def leverage_ratios(full, held_out, unmodelled=0.0):
    """(M,) in [0, 1]: the comparison's predicted variance under the full fit (``full`` (M,) m^2)
    over that under the fold's fit (``held_out``), each plus ``unmodelled`` (M,); 1 where a
    variance is unknown (docs/verdict.md)."""
    full = np.asarray(full, dtype=float) + unmodelled
    held_out = np.asarray(held_out, dtype=float) + unmodelled
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = full / held_out
    return np.where(np.isfinite(ratio) & (held_out > 0), np.clip(ratio, 0.0, 1.0), 1.0)


#: A held-out error whose square is up to this many times its predicted variance (the held-out
#: fit's there and the noise: 3 standard deviations) is what the model explains: its excess
#: over the noise is the fold's ignorance, which the leverage scales; beyond it, it is an error
#: no covariance explains (a model error), kept as measured.
LEVERAGE_EXPLAINS = 9.0


def explained_excess(errors, noise, held_out=None):
    """``(explained, kept)`` (M,): the excess ``e^2 - n`` of held-out error magnitudes ``errors``
    over their ``noise`` variance, split where ``e^2`` passes :data:`LEVERAGE_EXPLAINS` times
    ``held_out`` (M,) plus the noise (None: all explained)."""
    errors, noise = np.asarray(errors, dtype=float), np.asarray(noise, dtype=float)
    excess = errors**2 - noise
    if held_out is None:
        return excess, np.zeros_like(excess)
    cap = LEVERAGE_EXPLAINS * (np.asarray(held_out, dtype=float) + noise) - noise
    beyond = np.isfinite(cap) & (excess > cap)
    return np.where(beyond, cap, excess), np.where(beyond, excess - cap, 0.0)
