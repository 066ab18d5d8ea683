"""``controller_sim`` node: an emulated ros2_control hexapod for the bridge (docs/hardware.md)."""

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from gsp_kinematics.channels import LEG_LENGTHS
from gsp_kinematics.model.geometry import (
    GeometryError,
    default_geometry,
    load_geometry,
)
from gsp_kinematics.model.kinematics import forward_kinematics_masked, home_pose, inverse_kinematics
from gsp_kinematics.model.motion import MotionLimits
from gsp_msgs_py import conversions, names, node_tools, parameter_specs, qos

from .trajectory_follower import TrajectoryFollower

NODE_NAME = 'controller_sim'
#: Random stream of this node's leg noise (platform_sim uses 1, the device 2).
RNG_STREAM = 3
#: Steps a leg change is split into when FK from the last pose does not converge at once.
FK_CONTINUATION_STEPS = (1, 8, 64)

PARAMETERS = (
    parameter_specs.true_geometry_file_spec(
        'Geometry params file of the emulated hexapod (its true pose is FK of this geometry)'
    ),
    parameter_specs.controller_name_spec(
        'Emulated controller: goals on /<controller_name>/joint_trajectory'
    ),
    parameter_specs.joint_names_spec('Joint names of legs 1..6 on /joint_states'),
    # A speed limit alone by default (0: no acceleration limit), as before the motion model.
    *parameter_specs.motion_limit_specs(0.1, 0.0, read_only=True),
    parameter_specs.publish_rate_spec('/joint_states and true_pose'),
    parameter_specs.true_noise_spec(
        LEG_LENGTHS, 'Standard deviation of the leg position noise on /joint_states'
    ),
    parameter_specs.seed_spec(),
    parameter_specs.frame_id_spec('Frame of the published true pose'),
)


class ControllerSimNode(Node):
    """The emulated controller; ``**kwargs`` go to ``Node``."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        values = parameter_specs.declare_parameters(self, PARAMETERS)
        try:
            self._true = load_geometry(values['true_geometry_file'])
        except GeometryError as error:
            raise parameter_specs.ConfigurationError(f'true_geometry_file: {error}') from None
        self._joint_names = list(values['joint_names'])
        self._frame_id = values['frame_id']
        self._noise_std = values['leg_lengths_noise_std']
        seed = parameter_specs.resolve_seed(values['seed'])
        self._rng = np.random.default_rng([seed, RNG_STREAM])
        # Powered up where a nominal controller put the home pose.
        nominal = default_geometry('nominal')
        start = nominal.sensors.leg_readings(inverse_kinematics(nominal, home_pose()[None]))[0]
        self._follower = TrajectoryFollower(
            start,
            MotionLimits.from_parameters(values['max_leg_speed'], values['max_leg_acceleration']),
        )
        pose, converged = forward_kinematics_masked(
            self._true, self._true.sensors.true_leg_lengths(start[None]), home_pose()[None]
        )
        if not converged[0]:
            raise parameter_specs.ConfigurationError(
                'true_geometry_file: no forward kinematics at the power-up leg strokes'
            )
        self._pose, self._pose_legs = pose[0], start
        parameter_specs.watch_parameters(self, PARAMETERS, apply=self._apply)
        topic = f'/{values["controller_name"].strip("/")}/joint_trajectory'
        self.create_subscription(JointTrajectory, topic, self._on_trajectory, 10)
        self._joint_pub = self.create_publisher(JointState, '/joint_states', qos.SENSOR_QOS)
        (self._pose_pub,) = node_tools.create_publishers(self, [names.TOPIC_TRUE_POSE]).values()
        self.create_timer(1.0 / values['publish_rate'], self._tick)
        self.get_logger().info(f'controller_sim ready: goals on {topic}, seed {seed}')

    def _apply(self, changes):
        if 'leg_lengths_noise_std' in changes:
            self._noise_std = changes['leg_lengths_noise_std']

    def _now_s(self):
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_trajectory(self, msg):
        try:
            order = [list(msg.joint_names).index(name) for name in self._joint_names]
        except ValueError:
            self.get_logger().error(
                f'trajectory joints {list(msg.joint_names)} do not name {self._joint_names}: ignored'
            )
            return
        points = [
            (
                p.time_from_start.sec + p.time_from_start.nanosec * 1e-9,
                [p.positions[i] for i in order] if len(p.positions) == len(order) else [],
            )
            for p in msg.points
        ]
        try:
            self._follower.set_trajectory(points, self._now_s())
        except ValueError as error:
            self.get_logger().error(f'trajectory refused: {error}')

    def _tick(self):
        legs = self._follower.step(self._now_s())
        if not np.array_equal(legs, self._pose_legs):
            pose = self._track_pose(legs)
            if pose is None:
                # The real hexapod cannot be assembled there (it would jam): the axes stop at
                # the last reachable strokes and the trajectory is aborted, so the bridge's goal
                # times out, as platform_sim rejects such a command.
                self.get_logger().error(
                    f'the hexapod cannot reach leg strokes {legs.round(6).tolist()}: '
                    'trajectory aborted'
                )
                self._follower.abort(self._pose_legs)
                legs = self._pose_legs.copy()
            else:
                self._pose, self._pose_legs = pose, legs
        stamp = self.get_clock().now().to_msg()
        measured = legs + self._rng.normal(0.0, self._noise_std, size=6)
        joints = JointState(name=self._joint_names, position=measured.tolist())
        joints.header.stamp = stamp  # no frame, like joint_state_broadcaster
        self._joint_pub.publish(joints)
        self._pose_pub.publish(conversions.pose_to_pose_stamped(self._pose, stamp, self._frame_id))

    def _track_pose(self, legs):
        """FK of the true hexapod at ``legs``, continued from the last pose: the leg change is
        split into more and more steps until each converges (None if none does)."""
        for steps in FK_CONTINUATION_STEPS:
            pose = self._pose
            for k in range(1, steps + 1):
                q = self._pose_legs + (legs - self._pose_legs) * (k / steps)
                # The joints are leg sensor readings; the real legs are (1 + kq) times longer.
                articular = self._true.sensors.true_leg_lengths(q[None])
                reached, converged = forward_kinematics_masked(self._true, articular, pose[None])
                if not converged[0]:
                    break
                pose = reached[0]
            else:
                return pose
        return None


def main(args=None):
    """Console script ``controller_sim``."""
    return node_tools.run_node(ControllerSimNode, args, logger_name=NODE_NAME)


if __name__ == '__main__':
    raise SystemExit(main())
