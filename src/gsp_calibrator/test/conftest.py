"""Keep DDS on loopback in a ROS domain of this session's own, claimed (docs/faults.md,
"ROS domains"); ``small_disk``: a small tmpfs the disk-full tests really fill (full_disk.py)."""

import sys
from pathlib import Path

# The tests' shared support (test_support/, never installed with the nodes) on the path.
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'test_support'))
import full_disk
import pytest
from gsp_testing import ros_context, use_loopback_domain  # noqa: F401

use_loopback_domain()


@pytest.fixture
def small_disk(tmp_path):
    """A 4 MiB tmpfs mounted for the test (:class:`full_disk.SmallDisk`), unmounted after it."""
    yield from full_disk.small_disk(tmp_path / 'disk')
