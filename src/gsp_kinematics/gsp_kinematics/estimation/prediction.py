"""Predicted accuracy of a calibrated platform from the parameter covariance (Cramér-Rao)."""

import dataclasses
import math

import numpy as np

from ..model.device import device_readings, link_direction_derivatives
from ..model.effect_groups import EffectDesign, EffectTerms
from ..model.effects import EFFECT_GROUPS, NUM_EFFECT_PARAMETERS
from ..model.geometry import NUM_ALL_PARAMETERS, NUM_PARAMETERS, PARAMETER_INDEX
from ..model.kinematics import (
    Workspace,
    expand_leg_parameters,
    inverse_kinematics_jacobians,
    leg_vectors,
    reachable_mask,
    sample_valid_postures,
)
from ..rotation import euler_to_matrix, euler_to_matrix_derivatives

#: Leg parameters (A, B, L_off) that move the platform; the rest are the device's.
LEG_PARAMETERS = 42
#: Standard normal draws that integrate E|v| over a 3-D Gaussian (fixed: the result is repeatable).
_NORMAL_DRAWS = np.random.default_rng(20240611).standard_normal((2048, 3))
#: Effect groups whose regressor depends on the posture only: their estimates' errors move the
#: compensated pose through :func:`effect_pose_sensitivities`.
POSTURE_EFFECT_GROUPS = ('compliance', 'joint_offsets')


def body_angular_jacobian(euler):
    """``E`` (M, 3, 3) with ``w = E d(psi, theta, phi)``: the rotation vector of ``R^T R(e + de)``."""
    rotation = euler_to_matrix(euler)
    derivatives = euler_to_matrix_derivatives(euler)  # (M, 3 euler, 3, 3)
    skew = np.einsum('mji,majk->maik', rotation, derivatives)  # R^T dR/de_a
    # vee of each skew matrix, one column per Euler angle.
    return np.stack([skew[:, :, 2, 1], skew[:, :, 0, 2], skew[:, :, 1, 0]], axis=1)


def pose_sensitivities(geometry, poses, free=None, euler=False, effect_free=None):
    """``S`` (M, 6, n_free): ``[dp (m); dw (rad)]`` of the reached pose per parameter error
    (``euler``: ``d(psi, theta, phi)`` (rad) in place of ``dw``); ``free``: a bool mask over the
    parameter vector (None: the 44). The device's parameters' columns are zero. ``effect_free``
    (24,): the free effects' columns (:func:`effect_pose_sensitivities`) follow."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    articular, d_q_d_pose, d_q_d_leg = inverse_kinematics_jacobians(geometry, poses)
    d_q_d_u = expand_leg_parameters(d_q_d_leg)
    # IK(u, X) = IK(u_hat, X_c)  =>  dq/dX dX = dq/du (u_hat - u). A leg gain error moves the leg
    # too: the real articular variable is (1 + kq) times the reading the controller commands, so
    # dq/dX dX = ... - q_i (kq_hat_i - kq_i) on leg i.
    d_q_d_gain = -articular[:, :, None] * np.eye(6)[None]
    sensitivity = np.linalg.solve(d_q_d_pose, np.concatenate([d_q_d_u, d_q_d_gain], axis=2))
    if not euler:
        sensitivity[:, 3:] = body_angular_jacobian(poses[:, 3:]) @ sensitivity[:, 3:]
    size = NUM_PARAMETERS if free is None else len(free)
    full = np.zeros((poses.shape[0], 6, max(size, NUM_ALL_PARAMETERS)))
    full[:, :, :LEG_PARAMETERS] = sensitivity[:, :, :LEG_PARAMETERS]
    first_gain = PARAMETER_INDEX['kq1']
    full[:, :, first_gain : first_gain + 6] = sensitivity[:, :, LEG_PARAMETERS:]
    full = full[:, :, :size]
    full = full if free is None else full[:, :, np.asarray(free, dtype=bool)]
    if effect_free is None or not np.any(effect_free):
        return full
    effects = effect_pose_sensitivities(geometry, poses, effect_free)
    return np.concatenate([full, effects], axis=2)


def effect_pose_derivatives(geometry, poses, mask, design=None):
    """(M, 6, count): ``[dp (m); d(psi, theta, phi) (rad)]`` of the reached pose per error of
    each effect parameter of ``mask`` (24,), its regressor at the rows' ``design`` (None: the
    geometry's load only, for the groups that need neither times nor directions)."""
    if design is None:
        effects = geometry.effects
        design = EffectDesign(
            payload_mass=effects.payload_mass,
            centre_of_mass=effects.centre_of_mass,
            leg_mass=effects.leg_mass,
        )
    regressors = EffectTerms(geometry, design, mask, len(poses)).regressors(poses, geometry)
    _, d_q_d_pose, _ = inverse_kinematics_jacobians(geometry, poses)
    return np.linalg.solve(d_q_d_pose, regressors)


def effect_pose_sensitivities(geometry, poses, effect_free):
    """``S`` (M, 6, count): ``[dp (m); dw (rad)]`` of the reached pose per error of each free
    effect parameter (``effect_free`` (24,)) the controller compensates; zero outside
    :data:`POSTURE_EFFECT_GROUPS`."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    free = np.asarray(effect_free, dtype=bool).reshape(NUM_EFFECT_PARAMETERS)
    posture = free & np.repeat([g in POSTURE_EFFECT_GROUPS for g in EFFECT_GROUPS], 6)
    columns = np.zeros((poses.shape[0], 6, NUM_EFFECT_PARAMETERS))
    if posture.any():
        d_pose = effect_pose_derivatives(geometry, poses, posture)
        angular = body_angular_jacobian(poses[:, 3:])
        columns[:, :, posture] = np.concatenate([d_pose[:, :3], angular @ d_pose[:, 3:]], axis=1)
    return columns[:, :, free]


def expected_norm(covariances):
    """``E|v|`` for ``v ~ N(0, C)`` of each 3x3 covariance in ``covariances`` (..., 3, 3)."""
    eigenvalues = np.clip(np.linalg.eigvalsh(covariances), 0.0, None)
    flat = eigenvalues.reshape(-1, 3)
    norms = np.sqrt(flat @ (_NORMAL_DRAWS**2).T)  # (K, draws)
    return norms.mean(axis=1).reshape(eigenvalues.shape[:-1])


def reading_pose_covariance(geometry, poses, readings, stds):
    """``(position (M, 3, 3) m^2, euler (M, 3, 3) rad^2)``: the covariance of the pose the legs
    give (FK) against the pose the device gives at ``poses`` (M, 6) with ``readings`` (M, 4),
    from independent reading errors of standard deviations ``stds`` (a ``SensorNoise``)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    _, d_q_d_pose, _ = inverse_kinematics_jacobians(geometry, poses)
    gains = np.broadcast_to(np.diag(1.0 + geometry.sensors.leg_gain_errors), d_q_d_pose.shape)
    d_pose_d_legs = np.linalg.solve(d_q_d_pose, gains)
    legs = stds.leg_lengths**2 * d_pose_d_legs @ np.swapaxes(d_pose_d_legs, 1, 2)
    ideal = geometry.sensors.ideal_device_readings(np.atleast_2d(readings))
    d_alpha, d_beta, _ = link_direction_derivatives(
        ideal[:, 0], ideal[:, 1], geometry.inclinometer_axes_angle
    )
    length = geometry.device_length + ideal[:, 3]
    direction = poses[:, :3] / np.linalg.norm(poses[:, :3], axis=1)[:, None]
    slope = (1.0 + geometry.sensors.lvdt_gain_error) * stds.lvdt
    outer = np.einsum('mi,mj->mij', d_alpha, d_alpha) + np.einsum('mi,mj->mij', d_beta, d_beta)
    position = legs[:, :3, :3] + (length**2 * stds.inclinometer**2)[:, None, None] * outer
    position = position + slope**2 * np.einsum('mi,mj->mij', direction, direction)
    euler = legs[:, 3:, 3:].copy()
    euler[:, 2, 2] += stds.encoder**2
    return position, euler


def thermal_strain_rms(strain_rates, design):
    """Per leg (6,): the rms over the run's rows of the thermal strain relative to the reference
    instant, ``|strain_rate_i| rms_t(w(t) - w(t_ref))`` (dimensionless), from the identified
    ``strain_rates`` (6,) 1/s and the run's ``EffectDesign`` (its times, clock and reference)."""
    times = np.asarray(design.times_s, dtype=float)
    elapsed = design.thermal_clock(times) - design.thermal_clock(design.reference_time_s)
    spread = math.sqrt(float(np.mean(elapsed**2))) if elapsed.size else 0.0
    return np.abs(np.asarray(strain_rates, dtype=float)) * spread


def thermal_pose_covariance(geometry, poses, strain_rms):
    """``(position (M, 3, 3) m^2, rotation (M, 3, 3) rad^2)``: the second moment of the pose
    error at ``poses`` (M, 6) of leg growths ``strain_rms`` (6,) x each leg's length (all legs
    grow together, in one time: a rank-one covariance per pose)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    _, d_q_d_pose, _ = inverse_kinematics_jacobians(geometry, poses)
    vectors, _ = leg_vectors(geometry, poses)
    growth = np.linalg.norm(vectors, axis=2) * np.asarray(strain_rms, dtype=float)[None]
    d_pose = np.linalg.solve(d_q_d_pose, growth[..., None])[..., 0]  # (M, 6)
    angular = body_angular_jacobian(poses[:, 3:])
    rotation = np.einsum('mij,mj->mi', angular, d_pose[:, 3:])
    outer = np.einsum('mi,mj->mij', d_pose[:, :3], d_pose[:, :3])
    return outer, np.einsum('mi,mj->mij', rotation, rotation)


def parameter_pose_covariance(geometry, covariance, poses, free=None, effect_free=None):
    """``(position (M, 3, 3) m^2, rotation (M, 3, 3) rad^2)``: the parameters' ``covariance``
    (the free parameters, then the free effects; ``free``, ``effect_free`` as in
    :func:`predicted_errors`) propagated to the reached pose at ``poses`` (M, 6)."""
    sensitivity = pose_sensitivities(geometry, poses, free, effect_free=effect_free)
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape != (sensitivity.shape[2],) * 2:
        raise ValueError(
            f'covariance must be {sensitivity.shape[2]}x{sensitivity.shape[2]} (the free '
            f'parameters, then the free effects), got {covariance.shape}'
        )
    pose_covariance = sensitivity @ covariance @ np.swapaxes(sensitivity, 1, 2)
    return pose_covariance[:, :3, :3], pose_covariance[:, 3:, 3:]


def predicted_errors(
    geometry, covariance, poses, free=None, unmodelled=None, thermal_strain=None, effect_free=None
):
    """Predicted error magnitudes ``(position_mm, orientation_deg)`` (M,) each at ``poses`` (M, 6).

    ``covariance``: (n_free, n_free) of the free parameters (m, rad) then of the free effect
    parameters; ``free`` their mask (None: all), ``effect_free`` the effects' (24,; None: none).
    ``unmodelled``: a ``SensorNoise`` of what the model leaves unexplained (None: nothing);
    ``thermal_strain`` (6,): each leg's uncompensated thermal strain rms (None: none)."""
    position, rotation = parameter_pose_covariance(geometry, covariance, poses, free, effect_free)
    if unmodelled is not None:
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        extra_position, euler = reading_pose_covariance(
            geometry, poses, device_readings(geometry, poses), unmodelled
        )
        angular = body_angular_jacobian(poses[:, 3:])
        position = position + extra_position
        rotation = rotation + angular @ euler @ np.swapaxes(angular, 1, 2)
    if thermal_strain is not None:
        extra_position, extra_rotation = thermal_pose_covariance(geometry, poses, thermal_strain)
        position, rotation = position + extra_position, rotation + extra_rotation
    return 1000.0 * expected_norm(position), np.degrees(expected_norm(rotation))


@dataclasses.dataclass(frozen=True)
class MapLayout:
    """The grid of an accuracy map: x-y at several heights level, and at mid height tilted."""

    cells: int = 21  #: per side in x and y
    heights: int = 3  #: level panels from z_min to z_max
    tilts_deg: tuple = (('psi', 20.0), ('theta', 20.0))  #: tilted panels at mid height


def map_panels(workspace=Workspace(), layout=MapLayout()):
    """``[(title, poses (cells*cells, 6))]``: the panels of an accuracy map (not yet checked)."""
    axis = np.linspace(-workspace.xy_range, workspace.xy_range, layout.cells)
    x, y = np.meshgrid(axis, axis)
    panels = []

    def panel(z, psi=0.0, theta=0.0):
        poses = np.zeros((x.size, 6))
        poses[:, 0], poses[:, 1], poses[:, 2] = x.ravel(), y.ravel(), z
        poses[:, 3], poses[:, 4] = psi, theta
        return poses

    for z in np.linspace(workspace.z_min, workspace.z_max, layout.heights):
        panels.append((f'z = {1000 * z:.0f} mm, level', panel(z)))
    middle = 0.5 * (workspace.z_min + workspace.z_max)
    for name, degrees in layout.tilts_deg:
        tilt = math.radians(degrees)
        angles = {'psi': (tilt, 0.0), 'theta': (0.0, tilt)}[name]
        panels.append(
            (f'z = {1000 * middle:.0f} mm, {name} = {degrees:g} deg', panel(middle, *angles))
        )
    return panels


def mean_p95_max(values):
    """``{mean, p95, max}`` of ``values``."""
    values = np.asarray(values, dtype=float)
    return {
        'mean': float(np.mean(values)),
        'p95': float(np.percentile(values, 95)),
        'max': float(np.max(values)),
    }


def predict_accuracy(
    geometry,
    covariance,
    free=None,
    workspace=Workspace(),
    postures=500,
    seed=0,
    layout=MapLayout(),
    unmodelled=None,
    thermal_strain=None,
    effect_free=None,
):
    """Predicted accuracy (mm, deg; arguments as in :func:`predicted_errors`) over ``postures``
    seeded random reachable postures (``random``), the worst grid cell and the ``maps`` per panel
    (NaN: unreachable): a JSON-ready dict (docs/data.md)."""
    random_poses = sample_valid_postures(
        geometry, int(postures), np.random.default_rng(int(seed)), workspace
    )

    def errors(poses):
        return predicted_errors(
            geometry, covariance, poses, free, unmodelled, thermal_strain, effect_free
        )

    position, orientation = errors(random_poses)
    maps = []
    worst = None
    for title, poses in map_panels(workspace, layout):
        reachable = reachable_mask(geometry, poses, workspace.max_condition)
        cell_position = np.full(poses.shape[0], np.nan)
        cell_orientation = np.full(poses.shape[0], np.nan)
        if reachable.any():
            found = errors(poses[reachable])
            cell_position[reachable], cell_orientation[reachable] = found
            index = int(np.nanargmax(cell_position))
            if worst is None or cell_position[index] > worst['position_mm']:
                worst = {
                    'panel': title,
                    'pose': poses[index].tolist(),
                    'position_mm': float(cell_position[index]),
                    'orientation_deg': float(cell_orientation[index]),
                }
        shape = (layout.cells, layout.cells)
        maps.append(
            {
                'title': title,
                'z_m': float(poses[0, 2]),
                'tilt_rad': poses[0, 3:5].tolist(),
                'x_m': poses[: layout.cells, 0].tolist(),
                'y_m': poses[:: layout.cells, 1].tolist(),
                'position_mm': cell_position.reshape(shape).tolist(),
                'orientation_deg': cell_orientation.reshape(shape).tolist(),
            }
        )
    return {
        'statistic': 'expected error magnitude E|dX| from the parameter covariance (1 sigma)'
        + ('' if unmodelled is None else ' and the unmodelled error')
        + ('' if thermal_strain is None else ' and the uncompensated thermal growth'),
        'assumes': assumption(unmodelled, thermal_strain),
        'units': {'position': 'mm', 'orientation': 'deg', 'pose': 'm, rad'},
        'random': {
            'position_mm': mean_p95_max(position),
            'orientation_deg': mean_p95_max(orientation),
            'postures': int(random_poses.shape[0]),
            'seed': int(seed),
        },
        'worst_cell': worst,
        'maps': maps,
    }


def assumption(unmodelled, thermal_strain=None):
    """What a prediction assumes about the model error (plain text)."""
    thermal = ''
    if thermal_strain is not None and np.any(np.asarray(thermal_strain) > 0.0):
        thermal = (
            f'; the uncompensated thermal growth ({1e6 * float(np.mean(thermal_strain)):.3g} '
            'ppm rms of the leg lengths over the run, relative to the reference instant) is '
            'added: the controllers do not compensate it'
        )
    if unmodelled is None or not any(unmodelled.channels().values()):
        return (
            'the platform is exactly the model (no unmodelled error): on a real platform the '
            "accuracy is worse by the model's unexplained part (docs/verdict.md)" + thermal
        )
    return (
        f'the model leaves {1e6 * unmodelled.leg_lengths:.3g} um rms unexplained in the legs, '
        f'{1e6 * unmodelled.inclinometer:.3g} urad in the inclinations, '
        f'{1e6 * unmodelled.encoder:.3g} urad in phi and {1e6 * unmodelled.lvdt:.3g} um in d_m '
        '(estimated from the run), added at every pose' + thermal
    )


def accuracy_summary(prediction):
    """The headline of :func:`predict_accuracy`: mean and p95 over random postures, worst cell."""
    random = prediction['random']
    worst = prediction['worst_cell'] or {}
    return {
        'position_mm_mean': random['position_mm']['mean'],
        'position_mm_p95': random['position_mm']['p95'],
        'orientation_deg_mean': random['orientation_deg']['mean'],
        'orientation_deg_p95': random['orientation_deg']['p95'],
        'worst_cell_position_mm': worst.get('position_mm'),
        'worst_cell_orientation_deg': worst.get('orientation_deg'),
    }
