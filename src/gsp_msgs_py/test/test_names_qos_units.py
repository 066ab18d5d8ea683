"""Interface names, their types and QoS profiles, unit helpers."""

import math

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

from gsp_msgs_py import names, qos, units


def test_every_topic_has_an_importable_type_and_a_qos():
    assert set(qos.TOPIC_QOS) == set(names.TOPIC_TYPES)
    for topic, type_name in names.TOPIC_TYPES.items():
        assert topic.startswith('/gsp/')
        assert hasattr(names.interface_type(type_name), 'get_fields_and_field_types')
    for service, type_name in names.SERVICE_TYPES.items():
        assert service.startswith('/gsp/')
        assert hasattr(names.interface_type(type_name), 'Request')


def test_joint_names_and_frames():
    assert names.LEG_JOINT_NAMES == tuple(f'leg_{i}' for i in range(1, 7))
    assert names.INCLINOMETER_JOINT_NAMES == ('alpha', 'beta')
    assert names.ENCODER_JOINT_NAMES == ('phi',)
    assert names.LVDT_JOINT_NAMES == ('d_m',)
    assert (names.FRAME_BASE, names.FRAME_PLATFORM) == ('gsp_base', 'gsp_platform')
    assert set(names.STATES) == {'moving', 'settled', 'rejected'}


def test_qos_profiles():
    assert qos.SENSOR_QOS.reliability == ReliabilityPolicy.BEST_EFFORT
    assert qos.SENSOR_QOS.history == HistoryPolicy.KEEP_LAST
    assert qos.SENSOR_QOS.depth >= 50
    for profile in (qos.COMMAND_QOS, qos.STATUS_QOS, qos.RESULT_QOS, qos.PROGRESS_QOS):
        assert profile.reliability == ReliabilityPolicy.RELIABLE
        assert profile.history == HistoryPolicy.KEEP_LAST
    assert qos.COMMAND_QOS.depth == 10
    assert qos.STATUS_QOS.depth == 50
    assert qos.RESULT_QOS.depth == 1
    assert qos.RESULT_QOS.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert qos.TOPIC_QOS[names.TOPIC_CALIBRATION_RESULT] is qos.RESULT_QOS


def test_units():
    assert units.M_TO_MM == 1000.0
    assert units.m_to_mm(0.0015) == 1.5
    assert units.mm_to_m(1.5) == 0.0015
    assert math.isclose(units.rad_to_deg(math.pi), 180.0)
    assert math.isclose(units.deg_to_rad(90.0), math.pi / 2)
    np.testing.assert_allclose(units.rad_to_deg([0.0, math.pi / 2]), [0.0, 90.0])
    assert isinstance(units.m_to_mm(1), float)
    assert units.RAD_TO_DEG * units.DEG_TO_RAD == 1.0
