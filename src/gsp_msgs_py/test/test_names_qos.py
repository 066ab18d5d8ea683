"""Interface names, their types and QoS profiles."""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

from gsp_msgs_py import names, qos


def test_every_topic_has_an_importable_type_and_a_qos():
    assert set(qos.TOPIC_QOS) == set(names.TOPIC_TYPES)
    for topic, type_name in names.TOPIC_TYPES.items():
        assert topic.startswith('/gsp/')
        assert hasattr(names.interface_type(type_name), 'get_fields_and_field_types')


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
