"""The profiles work end to end over loopback DDS: sensor data flows, results are latched."""

import numpy as np
from gsp_testing import spin_until
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from gsp_msgs_py import names, qos
from gsp_msgs_py.conversions import leg_lengths_to_msg, msg_to_leg_lengths

TIMEOUT_S = 10.0


def test_leg_lengths_and_latched_result(ros_context):
    import rclpy

    node = rclpy.create_node('gsp_msgs_py_test', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    try:
        # Latched result published before anyone subscribes.
        result_pub = node.create_publisher(String, names.TOPIC_CALIBRATION_RESULT, qos.RESULT_QOS)
        result_pub.publish(String(data='geometry: {}\n'))

        received = []
        node.create_subscription(
            JointState,
            names.TOPIC_LEG_LENGTHS,
            lambda msg: received.append(msg_to_leg_lengths(msg)),
            qos.SENSOR_QOS,
        )
        pub = node.create_publisher(JointState, names.TOPIC_LEG_LENGTHS, qos.SENSOR_QOS)
        q = np.linspace(0.0, 0.05, 6)
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0, TIMEOUT_S)
        assert spin_until(
            executor, lambda: (pub.publish(leg_lengths_to_msg(q)), received)[1], TIMEOUT_S
        )
        np.testing.assert_array_equal(received[0], q)

        results = []
        node.create_subscription(
            String,
            names.TOPIC_CALIBRATION_RESULT,
            lambda msg: results.append(msg.data),
            qos.RESULT_QOS,
        )
        assert spin_until(executor, lambda: results, TIMEOUT_S)
        assert results == ['geometry: {}\n']
    finally:
        executor.shutdown()
        node.destroy_node()
