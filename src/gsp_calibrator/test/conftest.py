"""Keep DDS on loopback in a ROS domain of this session's own, claimed by lock (docs/faults.md)."""

from gsp_msgs_py.testing import ros_context, use_loopback_domain  # noqa: F401

use_loopback_domain()
