"""Keep DDS on loopback in a per-session random domain (set before rclpy creates a context)."""

from gsp_msgs_py.testing import ros_context, use_loopback_domain  # noqa: F401

use_loopback_domain()
