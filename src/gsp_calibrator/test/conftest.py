"""Keep DDS on loopback in a ROS domain of this session's own, claimed (docs/faults.md,
"ROS domains"); ``small_disk``: a small tmpfs the disk-full tests really fill (full_disk.py);
``GSP_TEST_SHARD`` (``systems`` or ``rest``): only the files of :data:`SYSTEM_FILES`, or only the
others, so that `make test` runs the two halves in processes side by side (Makefile)."""

import os
import sys
from pathlib import Path

# The tests' shared support (test_support/, never installed with the nodes) on the path.
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'test_support'))
import full_disk
import pytest
from gsp_testing import ros_context, use_loopback_domain  # noqa: F401

use_loopback_domain()

#: The files that run whole systems at full length (node processes, runs at the defaults): about
#: half of this package's test time (the junit times in build/gsp_calibrator/pytest.xml).
SYSTEM_FILES = frozenset(
    {
        'test_defaults_apply.py',
        'test_fault_processes.py',
        'test_noise_unknown.py',
        'test_upkeep_node.py',
        'test_serial_path.py',
    }
)


def pytest_collection_modifyitems(config, items):
    shard = os.environ.get('GSP_TEST_SHARD')
    if not shard:
        return
    if shard not in ('systems', 'rest'):
        raise pytest.UsageError(f'GSP_TEST_SHARD={shard!r}: systems or rest')
    chosen = [item for item in items if (item.path.name in SYSTEM_FILES) == (shard == 'systems')]
    config.hook.pytest_deselected(items=[item for item in items if item not in chosen])
    items[:] = chosen


@pytest.fixture
def small_disk(tmp_path):
    """A 4 MiB tmpfs mounted for the test (:class:`full_disk.SmallDisk`), unmounted after it."""
    yield from full_disk.small_disk(tmp_path / 'disk')
