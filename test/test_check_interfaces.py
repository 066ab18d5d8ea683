"""gsp_check_interfaces against the suite's own nodes and deliberately wrong publishers."""

import argparse

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor

from gsp_device_driver.device_driver_node import DeviceDriverNode
from gsp_kinematics.device import device_readings
from gsp_kinematics.geometry import default_geometry
from gsp_kinematics.kinematics import inverse_kinematics
from gsp_msgs_py import conversions, names, node_tools
from gsp_msgs_py.interfaces.check_tool import run_check
from gsp_platform_sim.platform_sim_node import PlatformSimNode

TRUE = default_geometry('true')
POSE = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])
READINGS = device_readings(TRUE, POSE[None])[0]
LEGS = inverse_kinematics(TRUE, POSE[None])[0]


def arguments(duration=1.5, send_test_command=False):
    # The least rate is 1 Hz: these tests are of what the checker finds wrong, not of how fast a
    # loaded machine runs the nodes (a 100 Hz node measured below 50 Hz is a busy CI, not a bug).
    # The listening time is a fixed window (the checker's semantics, not a wait on an event):
    # long enough for in-process discovery and the 10 messages of the noise check, no longer.
    return argparse.Namespace(
        duration=duration, send_test_command=send_test_command, command_timeout=10.0, min_rate=1.0
    )


class WrongDriver:
    """A driver with one deliberate ``fault``: degrees, mm, stamps or joint_name (100 Hz)."""

    def __init__(self, context, fault):
        self.node = rclpy.create_node('wrong_driver', context=context)
        self.fault = fault
        self.pubs = node_tools.create_publishers(
            self.node, (names.TOPIC_LEG_LENGTHS, *node_tools.DEVICE_TOPICS)
        )
        self.rng = np.random.default_rng(0)
        self.node.create_timer(0.01, self.publish)

    def publish(self):
        now = self.node.get_clock().now()
        stamp = now.to_msg()
        readings = READINGS + self.rng.normal(0, 1e-5, 4)
        legs = LEGS + self.rng.normal(0, 1e-6, 6)
        if self.fault == 'degrees':
            readings[:3] = np.degrees(readings[:3])
        if self.fault == 'mm':
            readings[3] *= 1e3
            legs = legs * 1e3
        legs_msg = conversions.leg_lengths_to_msg(legs, stamp)
        if self.fault == 'joint_name':
            legs_msg.name[5] = 'leg_six'
        self.pubs[names.TOPIC_LEG_LENGTHS].publish(legs_msg)
        for topic, msg in node_tools.device_messages(readings, stamp, names.FRAME_BASE).items():
            if self.fault == 'stamps' and topic == names.TOPIC_ENCODER:
                msg.header.stamp = conversions.seconds_to_stamp(now.nanoseconds * 1e-9 + 0.002)
            self.pubs[topic].publish(msg)


@pytest.mark.parametrize(
    'fault, words',
    [
        ('degrees', '/gsp/device/inclinometer: tilts up to'),
        ('mm', '/gsp/device/lvdt: d_m up to'),
        ('stamps', 'device readings of one instant do not share one stamp'),
        ('joint_name', "/gsp/platform/leg_lengths: joint names ['leg_1'"),
    ],
)
def test_each_wrong_publisher_is_named(ros_context, fault, words):
    driver = WrongDriver(ros_context, fault)
    checker = rclpy.create_node('gsp_check_interfaces', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (driver.node, checker):
        executor.add_node(node)
    try:
        problems, _ = run_check(checker, executor, arguments())
    finally:
        executor.shutdown()
        checker.destroy_node()
        driver.node.destroy_node()
    assert any(words in problem for problem in problems), problems
    if fault == 'mm':
        assert any('leg_lengths: leg strokes up to' in p for p in problems), problems
    if fault == 'degrees':
        assert any('degrees instead of radians' in p for p in problems), problems


def test_the_suites_own_nodes_conform_and_answer_a_test_command(ros_context):
    platform = PlatformSimNode(context=ros_context)
    driver = DeviceDriverNode(context=ros_context)
    checker = rclpy.create_node('gsp_check_interfaces', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (platform, driver, checker):
        executor.add_node(node)
    try:
        problems, lines = run_check(checker, executor, arguments(send_test_command=True))
    finally:
        executor.shutdown()
        for node in (checker, driver, platform):
            node.destroy_node()
    assert problems == [], '\n'.join(problems + lines)
