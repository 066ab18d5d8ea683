"""platform_bridge with the emulated controller (controller_sim), in one process."""

import gsp_testing
import numpy as np
import pytest
from rclpy.parameter import Parameter

from gsp_kinematics.model.geometry import (
    default_geometry,
    geometry_from_parameters,
    geometry_to_parameters,
)
from gsp_kinematics.model.kinematics import forward_kinematics_masked, home_pose, inverse_kinematics
from gsp_msgs_py import conversions, names
from gsp_msgs_py.health import ERROR, OK, WARN
from gsp_platform_bridge.platform_bridge_node import PlatformBridgeNode
from gsp_platform_sim.controller_sim_node import ControllerSimNode

TIMEOUT_S = 15.0
NOMINAL, TRUE = default_geometry('nominal'), default_geometry('true')
POSE = home_pose() + np.array([0.02, -0.01, 0.01, 0.03, -0.02, 0.05])


class Harness(gsp_testing.NodeHarness):
    """The bridge, (optionally) the emulated controller, and a test node commanding poses."""

    def __init__(self, context, overrides=()):
        bridge_overrides = [p for p in overrides if not p.name.startswith('controller_sim.')]
        sim_overrides = [
            Parameter(p.name.split('.', 1)[1], value=p.value)
            for p in overrides
            if p.name.startswith('controller_sim.')
        ]
        self.bridge = PlatformBridgeNode(context=context, parameter_overrides=bridge_overrides)
        super().__init__(context, self.bridge, 'bridge_test', TIMEOUT_S)
        self.controller = None
        if not any(p.name == 'controller_sim.absent' for p in overrides):
            sim_overrides = [p for p in sim_overrides if p.name != 'absent']
            self.controller = ControllerSimNode(context=context, parameter_overrides=sim_overrides)
            self.executor.add_node(self.controller)
        self.statuses, self.legs, self.true_poses = [], [], []
        self.subscribe(names.TOPIC_PLATFORM_STATUS, lambda m: self.statuses.append(m))
        self.subscribe(names.TOPIC_LEG_LENGTHS, lambda m: self.legs.append(m))
        self.subscribe(names.TOPIC_TRUE_POSE, lambda m: self.true_poses.append(m))
        self.command_pub = self.publisher(names.TOPIC_POSE_COMMAND)
        assert self.spin_until(lambda: self.command_pub.get_subscription_count() > 0)

    def command(self, pose):
        """Send ``pose``; returns its final status (parsed) once settled or rejected."""
        msg = conversions.pose_to_pose_stamped(
            pose, self.node.get_clock().now().to_msg(), names.FRAME_BASE
        )
        command_id = conversions.command_id_from_stamp(msg.header.stamp)
        self.command_pub.publish(msg)

        def final():
            for status in self.statuses:
                parsed = conversions.parse_status(status)
                if parsed.command_id == command_id and parsed.state != names.STATE_MOVING:
                    return parsed
            return None

        assert self.spin_until(lambda: final() is not None), 'no final status'
        return final()

    def close(self):
        if self.controller is not None:
            self.executor.remove_node(self.controller)
            self.controller.destroy_node()
        super().close()


harness = gsp_testing.harness_fixture(Harness)


def test_a_command_settles_where_the_true_hexapod_puts_the_legs(harness):
    assert harness.spin_until(lambda: len(harness.legs) > 0)
    status = harness.command(POSE)
    assert status.state == names.STATE_SETTLED, status
    # The joints are leg sensor readings (gain errors applied: docs/sensor_errors.md).
    target = NOMINAL.sensors.leg_readings(inverse_kinematics(NOMINAL, POSE[None]))[0]
    harness.legs.clear()
    harness.true_poses.clear()
    assert harness.spin_until(lambda: len(harness.legs) >= 3 and len(harness.true_poses) >= 3)
    legs = conversions.msg_to_leg_lengths(harness.legs[-1])
    np.testing.assert_allclose(legs, target, atol=1e-5)
    articular = TRUE.sensors.true_leg_lengths(target[None])
    expected, _ = forward_kinematics_masked(TRUE, articular, POSE[None])
    reached = conversions.pose_stamped_to_pose(harness.true_poses[-1])
    np.testing.assert_allclose(reached, expected[0], atol=1e-9)


def test_unreachable_commands_are_rejected_before_anything_moves(harness):
    assert harness.spin_until(lambda: len(harness.legs) > 0)
    status = harness.command(home_pose() + np.array([0, 0, 5.0, 0, 0, 0]))
    assert status.state == names.STATE_REJECTED and 'unreachable' in status.reason


@pytest.mark.parametrize(
    'harness', [[Parameter('controller_sim.absent', value=True)]], indirect=True
)
def test_without_joint_states_a_command_is_rejected(harness):
    status = harness.command(POSE)
    assert status.state == names.STATE_REJECTED and 'no /joint_states' in status.reason


@pytest.mark.parametrize(
    'harness',
    [
        [
            Parameter(
                'controller_sim.joint_names',
                value=['leg_1', 'leg_2', 'leg_3', 'leg_4', 'leg_5', 'leg_x'],
            )
        ]
    ],
    indirect=True,
)
def test_a_missing_joint_is_named(harness):
    assert harness.spin_until(lambda: harness.bridge._monitor.last_state_s is not None)
    status = harness.command(POSE)
    assert status.state == names.STATE_REJECTED and 'leg_6 missing' in status.reason


@pytest.mark.parametrize(
    'harness',
    [
        [
            Parameter('controller_sim.max_leg_speed', value=0.001),
            Parameter('goal_timeout', value=0.2),
        ]
    ],
    indirect=True,
)
def test_a_goal_not_reached_in_time_is_rejected(harness):
    assert harness.spin_until(lambda: len(harness.legs) > 0)
    status = harness.command(POSE)
    assert status.state == names.STATE_REJECTED and 'not reached in time' in status.reason


def test_the_bridge_takes_a_calibrated_geometry_like_platform_sim(harness):
    # The calibrator's apply_result sets the whole geometry.* set at once. The true geometry
    # stands for a calibrated one: it moves the legs at POSE by up to 4 mm from the nominal
    # model's, far outside the 10 um tolerance, so a geometry accepted but not applied fails.
    sent = geometry_to_parameters(TRUE)
    result = harness.bridge.set_parameters_atomically(
        [Parameter(name, value=value) for name, value in sent.items()]
    )
    assert result.successful, result.reason
    # The expectation comes from the geometry sent, independently of the bridge's state.
    calibrated = geometry_from_parameters(sent)
    target = calibrated.sensors.leg_readings(inverse_kinematics(calibrated, POSE[None]))[0]
    nominal = NOMINAL.sensors.leg_readings(inverse_kinematics(NOMINAL, POSE[None]))[0]
    assert np.max(np.abs(target - nominal)) > 1e-3
    assert harness.spin_until(lambda: len(harness.legs) > 0)
    assert harness.command(POSE).state == names.STATE_SETTLED
    harness.legs.clear()
    assert harness.spin_until(lambda: len(harness.legs) >= 3)
    np.testing.assert_allclose(
        conversions.msg_to_leg_lengths(harness.legs[-1]), target, rtol=0, atol=1e-5
    )


FAST_DIAGNOSTICS = Parameter('diagnostics_period', value=0.05)


@pytest.mark.parametrize('harness', [[FAST_DIAGNOSTICS]], indirect=True)
def test_diagnostics_count_commands_and_report_the_controller(harness):
    controller = harness.wait_health('platform_bridge: controller', lambda h: h.level == OK)
    assert float(controller.values['joint_states_age_s']) < 5.0
    assert harness.diagnostics.hardware_ids['platform_bridge: controller'] == (
        'joint_trajectory_controller'
    )
    assert harness.command(POSE).settled
    commands = harness.wait_health(
        'platform_bridge: commands', lambda h: h.values['settled'] == '1'
    )
    assert commands.level == OK and float(commands.values['settle_time_last_s']) > 0
    rejected = harness.command(home_pose() + np.array([0, 0, 5.0, 0, 0, 0]))
    assert rejected.rejected
    commands = harness.wait_health(
        'platform_bridge: commands', lambda h: h.values['refused'] == '1'
    )
    assert commands.level == WARN and 'unreachable' in commands.values['last_rejection']
    assert commands.values['rejected'] == '1' and commands.values['commands'] == '2'


@pytest.mark.parametrize(
    'harness', [[Parameter('controller_sim.absent', value=True), FAST_DIAGNOSTICS]], indirect=True
)
def test_diagnostics_report_a_missing_controller_as_an_error(harness):
    controller = harness.wait_health('platform_bridge: controller')
    assert controller.level == ERROR and 'no /joint_states' in controller.message
    assert controller.values['joint_states_age_s'] == ''
