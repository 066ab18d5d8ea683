"""platform_sim on the physics backend with device_driver's ``physics`` backend, in one process
(docs/physics.md): the same protocol as the kinematic backend, a command settles when the
encoders are in position, the device's readings come from the physics."""

import gsp_testing
import numpy as np
import pytest
from rclpy.parameter import Parameter

from gsp_device_driver.device_driver_node import DeviceDriverNode
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import home_pose
from gsp_msgs_py import conversions, names, qos
from gsp_msgs_py.parameter_specs import ConfigurationError
from gsp_platform_sim.platform_sim_node import PlatformSimNode

TRUE = default_geometry('true')
POSE = home_pose() + [0.01, -0.01, 0.01, 0.01, 0.0, 0.02]
TIMEOUT_S = 60.0  # generous: the machine may be loaded; tests finish as soon as they can
NO_NOISE = [
    Parameter(name, value=0.0)
    for name in ('inclinometer_noise_std', 'encoder_noise_std', 'lvdt_noise_std')
]


class Harness(gsp_testing.NodeHarness):
    """platform_sim (physics) and device_driver (physics), and a test node listening."""

    def __init__(self, context, overrides=()):
        backend = [Parameter('backend', value='physics'), Parameter('publish_rate', value=100.0)]
        self.sim = PlatformSimNode(
            context=context,
            parameter_overrides=backend + [Parameter('publish_markers', value=False)],
        )
        self.device = DeviceDriverNode(context=context, parameter_overrides=backend + NO_NOISE)
        super().__init__(context, self.sim, 'physics_test', TIMEOUT_S)
        self.executor.add_node(self.device)
        self.statuses, self.true_poses, self.inclinometer, self.lvdt = [], [], [], []
        self.subscribe(
            names.TOPIC_PLATFORM_STATUS, lambda m: self.statuses.append(conversions.parse_status(m))
        )
        self.subscribe(names.TOPIC_TRUE_POSE, self.true_poses.append)
        self.subscribe(names.TOPIC_INCLINOMETER, self.inclinometer.append)
        self.subscribe(names.TOPIC_LVDT, self.lvdt.append)
        self.command_pub = self.publisher(names.TOPIC_POSE_COMMAND)
        assert self.spin_until(
            lambda: self.command_pub.get_subscription_count() > 0 and self.lvdt
        ), 'no discovery'

    def command(self, pose):
        stamp = self.node.get_clock().now().to_msg()
        self.command_pub.publish(conversions.pose_to_pose_stamped(pose, stamp, names.FRAME_BASE))
        return conversions.command_id_from_stamp(stamp)

    def wait_final(self, command_id):
        def states():
            return [s for s in self.statuses if s.command_id == command_id]

        assert self.spin_until(lambda: any(s.settled or s.rejected for s in states()))
        return states()

    def close(self):
        self.device.destroy_node()
        super().close()


harness = gsp_testing.harness_fixture(Harness)


def by_stamp(messages, read):
    return {conversions.stamp_to_nanoseconds(m.header.stamp): read(m) for m in list(messages)}


def test_a_command_settles_in_position_and_the_device_reads_the_physics(harness):
    command_id = harness.command(POSE)
    assert [s.state for s in harness.wait_final(command_id)] == ['moving', 'settled']
    settled_ns = harness.node.get_clock().now().nanoseconds
    assert harness.spin_until(
        lambda: max(by_stamp(harness.lvdt, conversions.msg_to_lvdt), default=0) > settled_ns + 5e8
    )
    poses = by_stamp(harness.true_poses, conversions.pose_stamped_to_pose)
    angles = by_stamp(harness.inclinometer, conversions.msg_to_inclinometer)
    common = sorted(set(poses) & set(angles))
    assert common, 'the device readings carry the simulation stamps of the true poses'
    stamp = common[-1]
    # m: the platform went there (its controller has the nominal geometry, mm off the truth)
    assert np.linalg.norm(poses[stamp][:3] - POSE[:3]) < 0.02
    expected = TRUE.sensors.device_readings(device_readings(TRUE, poses[stamp][None])[0])
    np.testing.assert_allclose(angles[stamp], expected[:2], rtol=0.0, atol=1e-6)  # rad, at rest


def test_an_unreachable_command_is_rejected_with_the_reason(harness):
    states = harness.wait_final(harness.command(home_pose() + [0.0, 0.0, 2.0, 0.0, 0.0, 0.0]))
    assert [s.state for s in states] == ['rejected']
    assert 'stroke' in states[0].reason


def test_effects_are_refused_on_the_physics_backend(ros_context):
    with pytest.raises(ConfigurationError, match='kinematic backend'):
        PlatformSimNode(
            context=ros_context,
            parameter_overrides=[
                Parameter('backend', value='physics'),
                Parameter('effects.backlash', value=[4e-6] * 6),
            ],
        )


def test_faster_than_real_time_the_simulation_is_the_clock(ros_context):
    """real_time_factor 4: platform_sim publishes the simulated instant on /clock, runs on it
    and stamps its samples with it, one publish period apart: a loaded machine slows the
    simulation (and every clock on it), it leaves no gap."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock

    sim = PlatformSimNode(
        context=ros_context,
        parameter_overrides=[
            Parameter('backend', value='physics'),
            Parameter('publish_rate', value=100.0),
            Parameter('publish_markers', value=False),
            Parameter('real_time_factor', value=4.0),
        ],
    )
    node = rclpy.create_node('real_time_factor_test', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(sim)
    executor.add_node(node)
    clocks, stamps = [], []
    node.create_subscription(
        Clock, '/clock', lambda m: clocks.append(conversions.stamp_to_nanoseconds(m.clock)), 10
    )
    node.create_subscription(
        names.interface_type(names.TOPIC_TYPES[names.TOPIC_LEG_LENGTHS]),
        names.TOPIC_LEG_LENGTHS,
        lambda m: stamps.append(conversions.stamp_to_nanoseconds(m.header.stamp)),
        qos.TOPIC_QOS[names.TOPIC_LEG_LENGTHS],
    )
    try:
        assert gsp_testing.spin_until(executor, lambda: len(stamps) >= 60, TIMEOUT_S)
        assert sim.get_clock().ros_time_is_active  # platform_sim runs on its own /clock
        assert len(set(stamps) & set(clocks)) >= 50  # ns: each sample at a /clock instant
        np.testing.assert_allclose(np.diff(sorted(stamps[5:])), 1e7, rtol=0.0, atol=1e3)  # ns
    finally:
        gsp_testing.shutdown_executor(executor)
        node.destroy_node()
        sim.destroy_node()


def test_real_time_factor_is_refused_on_the_kinematic_backend(ros_context):
    with pytest.raises(ConfigurationError, match='real_time_factor is for the physics'):
        PlatformSimNode(
            context=ros_context, parameter_overrides=[Parameter('real_time_factor', value=2.0)]
        )
