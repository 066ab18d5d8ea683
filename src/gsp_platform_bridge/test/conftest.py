"""Keep DDS on loopback in a ROS domain of this session's own, claimed (docs/faults.md,
"ROS domains")."""

import sys
from pathlib import Path

# The tests' shared support (test_support/, never installed with the nodes) on the path.
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'test_support'))
from gsp_testing import ros_context, use_loopback_domain  # noqa: F401

use_loopback_domain()
