"""The demo's ROS side: it waits until the platform can take commands."""

import numpy as np
import pytest


class _NoProcesses:
    """The demo's node processes, none of which exits here."""

    def exited(self):
        return None


def test_the_demo_waits_for_the_platforms_first_leg_lengths(ros_context):
    """platform_bridge rejects every command until the controller's first /joint_states reached
    it (it then publishes leg lengths): the demo must not command before that."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger

    from gsp_calibrator.tools import demo_node
    from gsp_calibrator.tools.processes import DemoError
    from gsp_msgs_py import conversions, names, qos

    node = demo_node.DemoNode(_NoProcesses(), context=ros_context)
    platform = rclpy.create_node('fake_platform', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(platform)
    try:
        # Everything wait_for_system looked for before: the service, a command subscriber and
        # a status publisher; no leg lengths yet (the bridge has no joint states).
        platform.create_service(
            Trigger, names.SERVICE_CALIBRATE, lambda request, response: response
        )
        platform.create_subscription(
            PoseStamped,
            names.TOPIC_POSE_COMMAND,
            lambda msg: None,
            qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND],
        )
        platform.create_publisher(
            DiagnosticStatus,
            names.TOPIC_PLATFORM_STATUS,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
        )
        with pytest.raises(DemoError, match=names.TOPIC_LEG_LENGTHS):
            node.wait_for_system(2.0)
        legs = platform.create_publisher(
            JointState, names.TOPIC_LEG_LENGTHS, qos.TOPIC_QOS[names.TOPIC_LEG_LENGTHS]
        )
        platform.create_timer(
            0.01,
            lambda: legs.publish(
                conversions.leg_lengths_to_msg(
                    np.full(6, 0.5), platform.get_clock().now().to_msg(), names.FRAME_BASE
                )
            ),
        )
        node.wait_for_system(30.0)  # returns once the leg lengths come (30 s bounds a failure)
    finally:
        executor.shutdown()
        platform.destroy_node()
        node.destroy_node()


def test_the_demo_reads_the_true_pose_on_the_simulations_clock(ros_context):
    """--backend physics --real-time-factor 4: platform_sim stamps the true pose on its /clock,
    which a loaded machine leaves behind wall time; the demo's node runs on /clock too, or no
    true pose is ever stamped after the settled status it received (issue 34: exit 1 after a
    successful calibration)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock as ClockMessage

    from gsp_calibrator.tools import demo_node
    from gsp_msgs_py import conversions, names, qos

    node = demo_node.DemoNode(_NoProcesses(), sim_time=True, context=ros_context)
    platform = rclpy.create_node('fake_platform', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(platform)
    pose = np.array([0.01, 0.0, 1.0, 0.0, 0.0, 0.0])
    simulated_ns = [1000 * 10**9]  # the simulation's clock, far behind wall time
    commands = []

    def tick():
        simulated_ns[0] += 10**7
        stamp = conversions.seconds_to_stamp(simulated_ns[0] * 1e-9)
        clock.publish(ClockMessage(clock=stamp))
        true_pose.publish(conversions.pose_to_pose_stamped(pose, stamp))
        for command_id in commands:
            status.publish(conversions.make_status(command_id, names.STATE_SETTLED))

    def topic(name, message_type):
        return platform.create_publisher(message_type, name, qos.TOPIC_QOS[name])

    try:
        clock = platform.create_publisher(ClockMessage, '/clock', 10)
        true_pose = topic(names.TOPIC_TRUE_POSE, PoseStamped)
        status = topic(names.TOPIC_PLATFORM_STATUS, DiagnosticStatus)
        platform.create_subscription(
            PoseStamped,
            names.TOPIC_POSE_COMMAND,
            lambda msg: commands.append(conversions.command_id_from_stamp(msg.header.stamp)),
            qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND],
        )
        platform.create_timer(0.01, tick)
        node.spin_until(
            lambda: node.command_pub.get_subscription_count() > 0, 30.0, 'the fake platform'
        )
        reached = node.run_postures(pose[None, :], 5.0, 30.0)
        np.testing.assert_allclose(reached[0], pose, atol=1e-9)
    finally:
        executor.shutdown()
        platform.destroy_node()
        node.destroy_node()
