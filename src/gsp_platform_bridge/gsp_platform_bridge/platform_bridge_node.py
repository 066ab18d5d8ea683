"""``platform_bridge`` node: the suite's platform protocol over ros2_control (docs/hardware.md)."""

import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from gsp_kinematics.model.effect_groups import commanded_leg_readings
from gsp_kinematics.model.kinematics import check_reachable, forward_kinematics_masked, home_pose
from gsp_kinematics.model.motion import REALISTIC_MAX_SPEED, MotionLimits
from gsp_msgs_py import conversions, names, node_tools, parameter_specs, qos
from gsp_msgs_py.diagnostics import Component, DiagnosticsPublisher
from gsp_msgs_py.geometry_parameters import (
    CONTROLLER_GEOMETRY_SPECS,
    GEOMETRY_PARAMETER_NAMES,
    controller_geometry,
    controller_geometry_error,
    validate_geometry_change,
)
from gsp_msgs_py.parameter_specs import ParameterSpec, at_least, not_blank, positive_spec
from gsp_msgs_py.pose_commands import PoseCommandServer

from .goal_monitor import GoalMonitor, pose_path, waypoint_times

NODE_NAME = names.NODE_PLATFORM_BRIDGE
CHECK_RATE_HZ = 50.0  #: deadline and staleness checks between joint states
DEFAULT_MAX_CONDITION = 100.0  #: as platform_sim

PARAMETERS = (
    *CONTROLLER_GEOMETRY_SPECS,
    parameter_specs.controller_name_spec(
        'joint_trajectory_controller whose /<controller_name>/joint_trajectory takes the goals'
    ),
    parameter_specs.joint_names_spec('The controller joints of legs 1..6, in leg order'),
    ParameterSpec(
        'joint_states_topic',
        '/joint_states',
        'JointState topic of the controller (joint_state_broadcaster)',
        read_only=True,
        check=not_blank('a topic'),
    ),
    # The trajectory's times (docs/planning.md): the speed of a positioning hexapod, the
    # acceleration unlimited by default as before (set both to the platform's).
    *parameter_specs.motion_limit_specs(REALISTIC_MAX_SPEED, 0.0),
    parameter_specs.non_negative_spec(
        'min_motion_duration',
        0.1,
        'Shortest trajectory duration (time_from_start of its point)',
        's',
    ),
    positive_spec(
        'path_position_step',
        0.01,
        'Longest position step between the waypoints of a move (the legs follow the straight '
        'Cartesian path, checked for reachability before anything moves)',
        'm',
    ),
    positive_spec(
        'path_angle_step', 0.02, 'Longest orientation step between the waypoints of a move', 'rad'
    ),
    positive_spec(
        'position_tolerance', 5e-5, 'A leg has arrived within this distance of its target', 'm'
    ),
    parameter_specs.settle_time_spec('a goal, counted once every leg is within position_tolerance'),
    positive_spec(
        'goal_timeout',
        2.0,
        'Time allowed beyond the trajectory duration before the goal is rejected',
        's',
    ),
    positive_spec(
        'state_timeout', 0.5, 'Joint states older than this are stale: commands are rejected', 's'
    ),
    ParameterSpec(
        'max_condition',
        DEFAULT_MAX_CONDITION,
        'Commands whose dq/dX condition number is not below this are rejected',
        float_range=(1.0, 1e12),
        check=at_least(1.0),
    ),
    parameter_specs.frame_id_spec('Base frame: required of pose commands, and of leg_lengths'),
    parameter_specs.diagnostics_period_spec(),
)


def _check_start_up(values):
    reason = controller_geometry_error(values)
    return f'controller geometry: {reason}' if reason else ''


class PlatformBridgeNode(Node):
    """The bridge; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        values = parameter_specs.declare_parameters(self, PARAMETERS, validate=_check_start_up)
        self._values = values
        self._last_pose = None  # last commanded pose: the guess of FK at the joint states
        self._geometry = controller_geometry(values)
        self._frame_id = values['frame_id']
        self._monitor = GoalMonitor(
            values['joint_names'],
            values['position_tolerance'],
            values['settle_time'],
            values['state_timeout'],
        )
        parameter_specs.watch_parameters(
            self, PARAMETERS, apply=self._apply_parameters, validate=validate_geometry_change
        )
        self._trajectory_topic = f'/{values["controller_name"].strip("/")}/joint_trajectory'
        self._trajectory_pub = self.create_publisher(JointTrajectory, self._trajectory_topic, 10)
        (self._legs_pub,) = node_tools.create_publishers(self, [names.TOPIC_LEG_LENGTHS]).values()
        self.create_subscription(
            JointState, values['joint_states_topic'], self._on_joint_state, qos.SENSOR_QOS
        )
        self._commands = PoseCommandServer(self, self._frame_id, None, self._move)
        self.create_timer(1.0 / CHECK_RATE_HZ, self._check_goal)
        self._diagnostics = DiagnosticsPublisher(
            self,
            values['diagnostics_period'],
            [
                Component('commands', names.STATUS_HARDWARE_ID, self._commands.health),
                Component(
                    'controller',
                    values['controller_name'],
                    lambda: self._monitor.health(self._now_s()),
                ),
            ],
        )
        self.get_logger().info(
            f'platform_bridge ready: goals on {self._trajectory_topic}, joint states on '
            f'{values["joint_states_topic"]}, joints {list(values["joint_names"])}'
        )

    def _now_s(self):
        return self.get_clock().now().nanoseconds * 1e-9

    def _apply_parameters(self, changes):
        self._values.update(changes)
        for name in ('position_tolerance', 'settle_time', 'state_timeout'):
            if name in changes:
                setattr(self._monitor, name, float(changes[name]))
        if any(name in GEOMETRY_PARAMETER_NAMES for name in changes):
            self._geometry = controller_geometry(self._values)
            self.get_logger().info('controller geometry updated; applies from the next command')

    def _move(self, command_id, pose):
        """PoseCommandServer callback: '' when the goal is sent, else why it is rejected."""
        problem = self._monitor.state_problem(self._now_s())
        if problem:
            return problem
        max_condition = self._values['max_condition']
        ok, reasons = check_reachable(self._geometry, pose[None], max_condition=max_condition)
        if not ok[0]:
            return f'unreachable: {reasons[0]}'
        path, reason = self._path_to(pose)
        if reason:
            return reason
        # The joints are the leg sensors: command what they must read (their gain errors applied,
        # the identified effects compensated along the path from where the legs are).
        waypoints = commanded_leg_readings(self._geometry, path, self._monitor.positions)
        limits = MotionLimits.from_parameters(
            self._values['max_leg_speed'], self._values['max_leg_acceleration']
        )
        times = waypoint_times(
            self._monitor.positions, waypoints, limits, self._values['min_motion_duration']
        )
        points = [
            JointTrajectoryPoint(positions=q.tolist(), time_from_start=Duration(seconds=t).to_msg())
            for q, t in zip(waypoints, times, strict=True)
        ]
        points[-1].velocities = [0.0] * 6
        # A zero header stamp: the controller starts the trajectory on receipt.
        self._trajectory_pub.publish(
            JointTrajectory(joint_names=list(self._monitor.joint_names), points=points)
        )
        self._last_pose = pose.copy()
        self._monitor.start(waypoints[-1], self._now_s() + times[-1] + self._values['goal_timeout'])
        self.get_logger().debug(
            f'goal {command_id}: {len(points)} waypoints, q = {waypoints[-1].round(6).tolist()} '
            f'in {times[-1]:.3f} s'
        )
        return ''

    def _path_to(self, pose):
        """``(poses (N, 6), '')``: the waypoints from the current pose (FK of the controller
        geometry at the joint states) to ``pose`` on a straight line, or through the home pose
        when the line leaves the workspace; ``(None, reason)`` when neither path is reachable.
        Just ``pose`` when the current pose is unknown."""
        guess = self._last_pose if self._last_pose is not None else pose
        articular = self._geometry.sensors.true_leg_lengths(self._monitor.positions[None])
        current, converged = forward_kinematics_masked(self._geometry, articular, guess[None])
        if not converged[0]:
            return pose[None], ''
        steps = (self._values['path_position_step'], self._values['path_angle_step'])
        max_condition = self._values['max_condition']
        straight = pose_path(current[0], pose, *steps)
        ok, reasons = check_reachable(self._geometry, straight, max_condition=max_condition)
        if ok.all():
            return straight, ''
        k = int(np.argmin(ok))
        home = home_pose()
        detour = np.vstack([pose_path(current[0], home, *steps), pose_path(home, pose, *steps)])
        if check_reachable(self._geometry, detour, max_condition=max_condition)[0].all():
            return detour, ''
        return None, (
            f'unreachable on the way (straight, and through the home pose): at step {k + 1} of '
            f'{len(straight)}, {reasons[k]}'
        )

    def _on_joint_state(self, msg):
        legs = self._monitor.observe(msg.name, msg.position, self._now_s())
        if legs is not None:
            stamp = msg.header.stamp
            if stamp.sec == 0 and stamp.nanosec == 0:
                stamp = self.get_clock().now().to_msg()
            self._legs_pub.publish(conversions.leg_lengths_to_msg(legs, stamp, self._frame_id))
        self._check_goal()

    def _check_goal(self):
        verdict = self._monitor.check(self._now_s())
        if verdict is None:
            return
        state, reason = verdict
        command_id = self._commands.moving
        if state == names.STATE_SETTLED and command_id is not None:
            self._commands.settled(command_id)
        elif state == names.STATE_REJECTED:
            self._commands.reject_moving(reason)


def main(args=None):
    """Console script ``platform_bridge``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(PlatformBridgeNode, args, logger_name=NODE_NAME)


if __name__ == '__main__':
    raise SystemExit(main())
