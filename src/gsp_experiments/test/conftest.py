"""Fixtures of the experiments' tests: the paper's exact geometry and its nominal sets."""

import numpy as np
import pytest

from gsp_experiments.nominal_sets import drawing_geometry, nominal_set


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


@pytest.fixture(scope='session')
def exact():
    return drawing_geometry()


@pytest.fixture(scope='session')
def nominal_sets(exact):
    return {k: nominal_set(exact, k) for k in (1, 2, 3)}
