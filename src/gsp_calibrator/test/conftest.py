"""Keep DDS on loopback in a per-session random domain (set before rclpy creates a context)."""

import os
import random

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
if not os.environ.get('ROS_DOMAIN_ID'):
    os.environ['ROS_DOMAIN_ID'] = str(random.randint(1, 101))


@pytest.fixture
def ros_context():
    """A fresh, initialised ``rclpy.Context``, shut down after the test."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
