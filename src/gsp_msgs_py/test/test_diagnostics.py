"""Health on /diagnostics: the status conversion and the periodic publisher of a node."""

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from gsp_testing import spin_until
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

from gsp_msgs_py import names
from gsp_msgs_py.diagnostics import (
    Component,
    DiagnosticsListener,
    DiagnosticsPublisher,
    health_to_status,
    node_of_status,
    status_name,
    status_to_health,
)
from gsp_msgs_py.health import ERROR, OK, WARN, Health
from gsp_msgs_py.parameter_specs import diagnostics_period_spec

TIMEOUT_S = 10.0


def test_a_health_becomes_a_status_and_back():
    health = Health(WARN, '3 line(s) dropped', {'dropped_checksum': 3, 'units': 'rad/m'})
    name = status_name('device_driver', 'device')
    msg = health_to_status(health, name, '/dev/ttyACM0')
    assert msg.level == DiagnosticStatus.WARN  # one byte, as diagnostic_msgs defines it
    assert msg.name == 'device_driver: device' and node_of_status(msg.name) == 'device_driver'
    assert msg.hardware_id == '/dev/ttyACM0' and msg.message == '3 line(s) dropped'
    assert [(kv.key, kv.value) for kv in msg.values] == [
        ('dropped_checksum', '3'),
        ('units', 'rad/m'),
    ]
    assert status_to_health(msg) == (name, '/dev/ttyACM0', health)
    msg.level = bytes([7])
    with pytest.raises(ValueError, match="'device_driver: device': unknown level 7"):
        status_to_health(msg)
    assert node_of_status('no separator') == ''


def test_the_diagnostics_period_is_a_documented_parameter():
    spec = diagnostics_period_spec()
    assert spec.name == 'diagnostics_period' and spec.default == 1.0 and spec.unit == 's'
    assert spec.reason(0.0) and not spec.reason(0.5)


def test_a_node_publishes_each_component_and_a_failing_report_is_an_error(ros_context):
    node = rclpy.create_node('diagnosed', context=ros_context)
    listener_node = rclpy.create_node('diagnostics_test', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    for each in (node, listener_node):
        executor.add_node(each)

    def broken():
        raise RuntimeError('counter lost')

    try:
        publisher = DiagnosticsPublisher(
            node,
            0.05,
            [
                Component('good', 'hw-1', lambda: Health(OK, 'fine', {'a': 1})),
                Component('broken', 'hw-2', broken),
            ],
        )
        listener = DiagnosticsListener(listener_node)
        assert spin_until(executor, lambda: len(listener.reports) == 2, TIMEOUT_S), listener
        assert listener.reports['diagnosed: good'] == Health(OK, 'fine', {'a': '1'})
        assert listener.hardware_ids['diagnosed: good'] == 'hw-1'
        failed = listener.reports['diagnosed: broken']
        assert failed.level == ERROR and 'counter lost' in failed.message
        assert listener.hardware_ids['diagnosed: broken'] == 'hw-2'
        # The profile diagnostic_updater publishes with: reliable and volatile.
        (info,) = listener_node.get_publishers_info_by_topic(names.TOPIC_DIAGNOSTICS)
        assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert info.qos_profile.durability == DurabilityPolicy.VOLATILE
        assert len(publisher.statuses()) == 2
    finally:
        executor.shutdown()
        node.destroy_node()
        listener_node.destroy_node()
