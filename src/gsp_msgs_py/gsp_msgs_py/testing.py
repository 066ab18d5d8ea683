"""Pytest helpers shared by the ROS packages' test suites.

Call :func:`use_loopback_domain` from a ``conftest.py`` before anything creates an rclpy
context, and re-export the :func:`ros_context` fixture. rclpy is imported lazily, so importing
this module does not load ROS.
"""

import os

import pytest

from .ros_environment import loopback_environment


def use_loopback_domain():
    """Keep DDS on loopback, in a random ROS domain unless one is already set."""
    env = loopback_environment()
    for key in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID'):
        os.environ[key] = env[key]


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


def spin_until(executor, predicate, timeout):
    """Spin ``executor`` until ``predicate()`` holds; False if ``timeout`` (s) passes first."""
    import time

    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.01)
    return True
