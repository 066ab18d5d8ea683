"""gsp_check_interfaces against the suite's own nodes and deliberately wrong publishers."""

import argparse

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from gsp_device_driver.device_driver_node import DeviceDriverNode
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import inverse_kinematics
from gsp_msgs_py import conversions, names, node_tools
from gsp_msgs_py.interfaces.check_tool import run_check
from gsp_platform_sim.platform_sim_node import PlatformSimNode

TRUE = default_geometry('true')
POSE = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])
READINGS = device_readings(TRUE, POSE[None])[0]
LEGS = inverse_kinematics(TRUE, POSE[None])[0]


def arguments(duration=1.5, send_test_command=False, diagnostics_period=1.0):
    # The least rate is 1 Hz: these tests are of what the checker finds wrong, not of how fast a
    # loaded machine runs the nodes (a 100 Hz node measured below 50 Hz is a busy CI, not a bug).
    # The listening time is a fixed window (the checker's semantics, not a wait on an event):
    # long enough for in-process discovery and the 10 messages of the noise check, no longer.
    return argparse.Namespace(
        duration=duration,
        send_test_command=send_test_command,
        command_timeout=10.0,
        min_rate=1.0,
        diagnostics_period=diagnostics_period,
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
    # Reports every 0.2 s, so that the checker judges them within its 1.5 s.
    fast = [Parameter('diagnostics_period', value=0.2)]
    platform = PlatformSimNode(context=ros_context, parameter_overrides=fast)
    driver = DeviceDriverNode(context=ros_context, parameter_overrides=fast)
    checker = rclpy.create_node('gsp_check_interfaces', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (platform, driver, checker):
        executor.add_node(node)
    try:
        problems, lines = run_check(
            checker, executor, arguments(send_test_command=True, diagnostics_period=0.2)
        )
    finally:
        executor.shutdown()
        for node in (checker, driver, platform):
            node.destroy_node()
    assert problems == [], '\n'.join(problems + lines)
    # What /diagnostics said, one line per status: level, message, number of keys.
    assert any(line.startswith('    device_driver: device: OK ') for line in lines), lines
    assert any(line.startswith('    platform_sim: commands: OK ') for line in lines), lines


def test_a_suite_node_without_diagnostics_and_a_status_at_error_are_problems(ros_context):
    from diagnostic_msgs.msg import DiagnosticArray

    from gsp_msgs_py import qos
    from gsp_msgs_py.diagnostics import health_to_status
    from gsp_msgs_py.health import ERROR, Health

    driver = WrongDriver(ros_context, fault=None)
    silent = rclpy.create_node(names.NODE_DEVICE_DRIVER, context=ros_context)  # reports nothing
    bridge = rclpy.create_node(names.NODE_PLATFORM_BRIDGE, context=ros_context)
    publisher = bridge.create_publisher(DiagnosticArray, '/diagnostics', qos.DIAGNOSTICS_QOS)
    broken = Health(ERROR, 'no /joint_states received from the controller', {'goal_active': 0})
    bridge.create_timer(
        0.1,
        lambda: publisher.publish(
            DiagnosticArray(status=[health_to_status(broken, 'platform_bridge: controller', 'c')])
        ),
    )
    checker = rclpy.create_node('gsp_check_interfaces', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (driver.node, silent, bridge, checker):
        executor.add_node(node)
    try:
        # The silent node is there from the start: seen for 1.5 s, over two periods of 0.5 s.
        problems, lines = run_check(
            checker, executor, arguments(duration=1.5, diagnostics_period=0.5)
        )
    finally:
        executor.shutdown()
        for node in (checker, bridge, silent, driver.node):
            node.destroy_node()
    assert len(problems) == 2, '\n'.join(problems + lines)
    assert problems[0].startswith('/diagnostics: device_driver is running but published no status')
    assert problems[1] == (
        '/diagnostics: platform_bridge: controller is ERROR: no /joint_states received from the '
        'controller'
    )
    expected = (
        '    platform_bridge: controller: ERROR no /joint_states received from the controller '
        '(1 keys)'
    )
    assert expected in lines, lines
