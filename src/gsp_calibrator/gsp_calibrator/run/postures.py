"""The postures of a calibration run: a seeded pool of postures reachable under the nominal
geometry, then the core's condition-number selection (pure; the node caches selections by
:func:`selection_key`)."""

import dataclasses
import time

import numpy as np

from gsp_kinematics.identification import (
    resolve_free,
)
from gsp_kinematics.kinematics import Workspace, sample_valid_postures
from gsp_kinematics.noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.selection import select_postures

#: Free parameters of the calibrator: the 44 and the identifiable sensor errors.
DEFAULT_FREE = ('extended',)


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
    formulation='implicit',
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


def selection_arguments(settings):
    """The positional arguments of :func:`choose_postures` and :func:`selection_key` for a run's
    ``CalibratorSettings``."""
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
