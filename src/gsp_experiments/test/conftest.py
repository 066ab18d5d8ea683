"""Fixtures of the experiments' tests: the paper's exact geometry and its nominal sets."""

import sys
from pathlib import Path

# The tests' shared support (test_support/, never installed with the nodes) on the path.
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'test_support'))
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
