"""Shared fixtures of the core's tests: the paper's exact geometry, nominal sets, random postures."""

import math

import numpy as np
import pytest

from gsp_kinematics.kinematics import Workspace, sample_valid_postures
from gsp_kinematics.nominal_sets import drawing_geometry, nominal_set


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


@pytest.fixture(scope="session")
def exact():
    return drawing_geometry()


@pytest.fixture(scope="session")
def nominal_sets(exact):
    return {k: nominal_set(exact, k) for k in (1, 2, 3)}


@pytest.fixture(scope="session")
def postures(exact):
    """400 random valid postures of the exact geometry over the paper's full range (+-40 deg)."""
    return sample_valid_postures(exact, 400, np.random.default_rng(7))


@pytest.fixture(scope="session")
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


@pytest.fixture(scope="session")
def fd():
    """:func:`finite_difference` (a fixture, so test modules need not import conftest)."""
    return finite_difference
