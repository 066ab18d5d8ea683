"""The bench's tests: gsp_bench (bench/) and the tests' shared support (test_support/) on the
path, DDS kept on loopback in a ROS domain of this session's own, claimed (docs/faults.md,
"ROS domains"); fixtures of the paper's exact geometry and its nominal sets."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'test_support'))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import numpy as np
import pytest
from gsp_testing import ros_context, use_loopback_domain  # noqa: F401

from gsp_bench.nominal_sets import drawing_geometry, nominal_set

use_loopback_domain()


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


@pytest.fixture(scope='session')
def exact():
    return drawing_geometry()


@pytest.fixture(scope='session')
def nominal_sets(exact):
    return {k: nominal_set(exact, k) for k in (1, 2, 3)}
