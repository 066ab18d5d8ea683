"""Shared fixtures of the core's tests: the paper's exact geometry, nominal sets, random postures.

The geometries are files in ``test/data`` (written by ``gsp_bench.nominal_sets``; the params
file keeps every float exactly), so the core's tests do not depend on the experiments package.
"""

import sys
from pathlib import Path

# The tests' shared support (test_support/, never installed with the nodes) on the path.
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'test_support'))
import math
from pathlib import Path

import numpy as np
import pytest

from gsp_kinematics.model.geometry import load_geometry
from gsp_kinematics.model.kinematics import Workspace, sample_valid_postures

DATA = Path(__file__).resolve().parent / 'data'


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


@pytest.fixture(scope='session')
def exact():
    """The paper's exact geometry (D0 = 850 mm, gamma = 90 deg)."""
    return load_geometry(DATA / 'paper_exact.yaml')


@pytest.fixture(scope='session')
def nominal_sets():
    """The paper's nominal sets 1-3 (Tables 1 and 2) of :func:`exact`."""
    return {k: load_geometry(DATA / f'paper_nominal_set_{k}.yaml') for k in (1, 2, 3)}


@pytest.fixture(scope='session')
def postures(exact):
    """400 random valid postures of the exact geometry over the paper's full range (+-40 deg)."""
    return sample_valid_postures(exact, 400, np.random.default_rng(7))


@pytest.fixture(scope='session')
def moderate_postures(exact):
    """60 valid postures within +-25 deg: FK converges under every nominal set from them."""
    workspace = Workspace(rotation_range=math.radians(25.0))
    return sample_valid_postures(exact, 60, np.random.default_rng(8), workspace)


def finite_difference(function, x, step):
    """Central differences of a vector function: array of shape ``function(x).shape + x.shape``."""
    x = np.asarray(x, dtype=float)
    columns = []
    for index in np.ndindex(x.shape):
        plus, minus = x.copy(), x.copy()
        plus[index] += step
        minus[index] -= step
        columns.append((np.asarray(function(plus)) - np.asarray(function(minus))) / (2.0 * step))
    return np.moveaxis(np.array(columns), 0, -1).reshape(np.shape(function(x)) + x.shape)


@pytest.fixture(scope='session')
def fd():
    """:func:`finite_difference` (a fixture, so test modules need not import conftest)."""
    return finite_difference


def pose_finite_difference(residual_of_poses, poses, step=1e-7):
    """Central differences (M, k, 6) of residuals whose row m depends on pose m only: coordinate
    j of every pose is perturbed at once."""
    columns = []
    for j in range(6):

        def of_coordinate(x, j=j):
            shifted = np.array(poses, dtype=float)
            shifted[:, j] += x[0]
            return residual_of_poses(shifted)

        columns.append(finite_difference(of_coordinate, [0.0], step)[..., 0])
    return np.stack(columns, axis=-1)


@pytest.fixture(scope='session')
def pose_fd():
    """:func:`pose_finite_difference` (a fixture)."""
    return pose_finite_difference
