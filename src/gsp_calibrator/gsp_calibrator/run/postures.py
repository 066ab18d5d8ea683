"""The postures of a calibration run: a seeded pool of postures reachable under the nominal
geometry, then the core's condition-number selection (pure; the node caches selections by
:func:`selection_key`)."""

import dataclasses
import time

import numpy as np

from gsp_kinematics.estimation.identifiability import posture_information
from gsp_kinematics.estimation.identification import DEFAULT_FORMULATION, resolve_free
from gsp_kinematics.model.effect_groups import effect_groups_of, split_auto
from gsp_kinematics.model.effects import EFFECT_GROUPS
from gsp_kinematics.model.kinematics import (
    ForwardKinematicsError,
    Workspace,
    home_pose,
    pose_from_leg_readings,
    sample_valid_postures,
)
from gsp_kinematics.model.motion import DEFAULT_SENSOR_RATE_HZ, posture_leg_lengths
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.planning.effect_plan import augment_route
from gsp_kinematics.planning.route import path_time, plan_route, travel_time_matrix
from gsp_kinematics.planning.selection import best_addition, select_postures

#: Leg distance (m) within which the platform already holds a posture (commanded first, the
#: collection's previous-posture check would skip it).
HELD_TOLERANCE = 1e-4

#: The plain model (the pure functions' default; the calibrator's is its parameter table's).
DEFAULT_FREE = ('extended',)
#: The effect groups whose identification needs more of the route than the selection: thermal
#: (reference revisits) and backlash (both approach directions).
ROUTE_GROUPS = ('thermal', 'backlash')
#: gsp_plan's timing of a posture: the settle time (s) and the rate (Hz) of the synchronised
#: samples (the calibrator's: the rate it heard the streams at).
PLAN_SETTLE_S = 0.02
PLAN_SENSOR_RATE_HZ = DEFAULT_SENSOR_RATE_HZ


class CalibrationError(RuntimeError):
    """The calibration cannot go on; the message says why."""


@dataclasses.dataclass(frozen=True)
class PostureSelection:
    """Postures chosen for a calibration."""

    poses: np.ndarray  #: (count, 6) commanded postures [x, y, z, psi, theta, phi], m and rad
    pool_indices: np.ndarray  #: (count,) their indices in the pool
    condition_number: float  #: scaled condition number of the selected set's information
    pool_size: int
    seed: int
    duration_s: float  #: wall time of the selection, s


def posture_pool(nominal, pool_size, seed, workspace=Workspace()):
    """``pool_size`` random postures (N, 6), reachable under ``nominal``, from ``seed``."""
    rng = np.random.default_rng(int(seed))
    return sample_valid_postures(nominal, int(pool_size), rng, workspace)


def selection_formulation(formulation):
    """The information model of the selection for an identification ``formulation``."""
    return 'implicit' if formulation == 'implicit' else 'fk'


def choose_postures(
    nominal,
    count,
    pool_size,
    seed,
    sigmas=DEFAULT_SENSOR_NOISE,
    free=DEFAULT_FREE,
    formulation=DEFAULT_FORMULATION,
    workspace=Workspace(),
):
    """Select ``count`` postures from a seeded pool of ``pool_size`` (:class:`PostureSelection`)."""
    count, pool_size = int(count), int(pool_size)
    if count < 1:
        raise CalibrationError(f'posture count must be >= 1, got {count}')
    if pool_size < count:
        raise CalibrationError(f'pool_size ({pool_size}) must be >= posture_count ({count})')
    started = time.perf_counter()
    pool = posture_pool(nominal, pool_size, seed, workspace)
    indices, condition = select_postures(
        nominal,
        pool,
        count,
        sigmas,
        free=resolve_free(free),
        formulation=selection_formulation(formulation),
    )
    return PostureSelection(
        poses=pool[indices],
        pool_indices=np.asarray(indices),
        condition_number=float(condition),
        pool_size=pool_size,
        seed=int(seed),
        duration_s=time.perf_counter() - started,
    )


#: The random stream of the workspace postures beside the pool's (one seed gives both).
WORKSPACE_STREAM = 23


def workspace_poses(settings):
    """The run's ``workspace_postures`` (K, 6): reachable postures drawn at random (seeded by
    ``seed``, a stream apart from the pool's), the same for any calibrator of the same settings
    (the rows are recognised by their commanded pose: ``run.identify.workspace_rows``)."""
    return workspace_poses_of(settings.nominal, settings.workspace_postures, settings.seed)


def workspace_poses_of(nominal, count, seed):
    """:func:`workspace_poses` of a run's ``nominal``, ``workspace_postures`` and ``seed``."""
    count = int(count or 0)
    if count <= 0:
        return np.zeros((0, 6))
    rng = np.random.default_rng([int(seed), WORKSPACE_STREAM])
    return sample_valid_postures(nominal, count, rng)


def with_workspace_poses(settings, poses):
    """The selected ``poses`` (N, 6) and the run's :func:`workspace_poses` after them."""
    return np.vstack([np.asarray(poses, dtype=float).reshape(-1, 6), workspace_poses(settings)])


def route_start(nominal, leg_readings):
    """``(pose (6,), reason)``: the posture (FK of ``nominal``) of a platform whose legs read
    ``leg_readings`` (6,) m; the home pose when unknown, ``reason`` saying why (else '')."""
    if leg_readings is None:
        return home_pose(), 'no leg lengths received'
    try:
        return pose_from_leg_readings(nominal, leg_readings), ''
    except (ForwardKinematicsError, ValueError) as error:
        return home_pose(), f'no forward kinematics of the latest leg lengths: {error}'


def posture_route(settings, poses, start_pose):
    """The route (``plan_route``) through ``poses`` from ``start_pose`` at the run's leg limits;
    a posture the platform already holds (:func:`held_last`) comes last, not first."""
    route = plan_route(settings.nominal, start_pose, poses, settings.motion_limits)
    order = held_last(settings, poses, start_pose, route.order)
    if order is not route.order:
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        legs = posture_leg_lengths(
            settings.nominal, np.vstack([np.asarray(start_pose)[None], poses])
        )
        times = travel_time_matrix(legs, settings.motion_limits)
        route = dataclasses.replace(
            route, order=order, travel_s=path_time(times, np.r_[0, order + 1])
        )
    return route


def held_last(settings, poses, start_pose, order=None):
    """``order`` (indices into ``poses``; default the given order) with its first posture moved
    last when the platform at ``start_pose`` already holds it (:data:`HELD_TOLERANCE`)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    order = np.arange(len(poses)) if order is None else np.asarray(order)
    if len(order) < 2:
        return order
    start = np.asarray(start_pose, dtype=float)[None]
    legs = posture_leg_lengths(settings.nominal, np.vstack([start, poses[order[:1]]]))
    if np.max(np.abs(legs[1] - legs[0])) < HELD_TOLERANCE:
        return np.r_[order[1:], order[0]]
    return order


def route_effect_groups(free):
    """The :data:`ROUTE_GROUPS` among ``free`` (``auto``: every group it may try)."""
    plain, auto = split_auto(free)
    groups = list(EFFECT_GROUPS) if auto else effect_groups_of(plain)
    return [group for group in groups if group in ROUTE_GROUPS]


def sample_rate(heard_hz):
    """``heard_hz`` (Hz), else (None, not positive) :data:`PLAN_SENSOR_RATE_HZ`."""
    return float(heard_hz) if heard_hz is not None and heard_hz > 0 else PLAN_SENSOR_RATE_HZ


def effect_route(settings, poses, start_pose, sample_rate_hz=None):
    """The route through ``poses`` (in commanded order) from ``start_pose`` with what the
    :func:`route_effect_groups` need (``augment_route``), timed at ``sample_rate_hz``; None
    without such a group (docs/platform_effects.md)."""
    groups = route_effect_groups(settings.free_parameters)
    if not groups or settings.formulation != 'implicit':  # auto there: the plain model
        return None
    dwell_s = PLAN_SETTLE_S + settings.pairs_per_posture / sample_rate(sample_rate_hz)
    return augment_route(
        settings.nominal,
        poses,
        groups,
        start_pose=start_pose,
        dwell_s=dwell_s,
        limits=settings.motion_limits,
    )


def route_additions(route, groups, sample_rate_hz=None):
    """``state.json``'s and ``result.json``'s record of what ``route`` (:func:`effect_route`)
    added for ``groups``, and the sample rate (Hz) it was timed at."""
    summary = route.to_dict()
    return {
        'groups': list(groups),
        **{k: summary[k] for k in summary if k != 'order'},
        'sample_rate_hz': sample_rate(sample_rate_hz),
    }


def route_additions_line(additions):
    """One line saying what the route additions cost (and the legs still arriving one way)."""
    one_way = additions['one_way_legs']
    return (
        f'route for the effects ({", ".join(additions["groups"])}): {additions["added_postures"]} '
        f'postures added ({additions["reference_revisits"]} reference revisits, '
        f'{additions["approach_insertions"]} for the approach directions), '
        f'+{additions["added_s"]:.1f} s predicted ({additions["plain_s"]:.1f} -> '
        f'{additions["total_s"]:.1f} s'
        + (f', samples at {rate:g} Hz)' if (rate := additions.get('sample_rate_hz')) else ')')
        + (f'; legs {one_way} still arrive from one direction only' if one_way else '')
    )


def commanded_count(settings, state):
    """The postures a run plans to command: selected, workspace and added to the route
    (``state``: its ``RunState``, None before it has one)."""
    additions = {} if state is None else state.route_additions or {}
    return settings.commanded_posture_count + int(additions.get('added_postures', 0))


class PostureReplacer:
    """The replacement of a posture the platform rejected: the best remaining posture of the
    run's pool by the selection's criterion (``best_addition``)."""

    def __init__(self, settings):
        self.pool = posture_pool(settings.nominal, settings.pool_size, settings.seed)
        self.information = posture_information(
            settings.nominal,
            self.pool,
            settings.sigmas,
            resolve_free(list(settings.free_parameters)),
            selection_formulation(settings.formulation),
        )

    def _pool_indices(self, poses):
        poses = np.asarray(poses, dtype=float).reshape(-1, 6)
        distance = np.max(np.abs(poses[:, None, :] - self.pool[None, :, :]), axis=2)
        nearest = np.argmin(distance, axis=1)
        return [
            int(i)
            for i, d in zip(nearest, distance[np.arange(len(poses)), nearest], strict=True)
            if d < 1e-9
        ]

    def __call__(self, poses, rejected):
        poses = np.asarray(poses, dtype=float).reshape(-1, 6)
        rejected_rows = [k - 1 for k in rejected]
        kept = [m for m in range(len(poses)) if m not in rejected_rows]
        chosen = self._pool_indices(poses[kept])
        excluded = self._pool_indices(poses[rejected_rows]) if rejected_rows else []
        try:
            index = best_addition(self.information, chosen, excluded)
        except ValueError:
            return None
        return self.pool[index].copy()


def selection_arguments(settings):
    """The arguments of :func:`choose_postures` and :func:`selection_key` for ``settings``."""
    return (
        settings.nominal,
        settings.posture_count,
        settings.pool_size,
        settings.seed,
        settings.sigmas,
        list(settings.free_parameters),
        settings.formulation,
    )


def selection_key(nominal, count, pool_size, seed, sigmas, free, formulation):
    """A hashable key of everything :func:`choose_postures` depends on (for caching)."""
    return (
        tuple(np.round(nominal.to_full_vector(), 15)),
        nominal.limits,
        int(count),
        int(pool_size),
        int(seed),
        sigmas,
        tuple(resolve_free(free)),
        selection_formulation(formulation),
    )
