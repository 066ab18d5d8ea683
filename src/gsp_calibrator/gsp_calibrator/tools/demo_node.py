"""The ROS part of ``gsp_demo``: a client node of the suite, spun from the main thread."""

import contextlib

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from gsp_calibrator.tools.processes import DemoError, NodeExited
from gsp_msgs_py import conversions, names, qos
from gsp_msgs_py.node_tools import spin_until


class DemoNode(Node):
    """Client of the suite: progress printing, the calibrate call, validation postures; spun by
    its single-threaded executor while it waits, which stops as soon as one of the
    ``processes`` (:class:`~gsp_calibrator.tools.processes.NodeProcesses`) exits."""

    def __init__(self, processes, sim_time=False, **kwargs):
        """``sim_time``: on the simulation's /clock, as the other nodes are (the true poses'
        stamps are compared with this node's clock); ``**kwargs`` go to ``Node`` (``context=``)."""
        overrides = [Parameter('use_sim_time', value=sim_time)]
        super().__init__('gsp_demo', parameter_overrides=overrides, **kwargs)
        self.processes = processes
        self.statuses = {}  # command_id -> PlatformStatus
        self.settled_at = {}  # command_id -> receive time (ns) of its settled status
        self.true_poses = []  # [(stamp_ns, pose)], recent only
        self._last_phase = None
        self.leg_lengths_seen = False
        self.calibrate_client = self.create_client(Trigger, names.SERVICE_CALIBRATE)
        self.command_pub = self.create_publisher(
            PoseStamped, names.TOPIC_POSE_COMMAND, qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND]
        )
        self._subscribe(names.TOPIC_PLATFORM_STATUS, DiagnosticStatus, self._on_status)
        self._subscribe(names.TOPIC_CALIBRATION_PROGRESS, DiagnosticStatus, self._on_progress)

    def _subscribe(self, topic, message_type, callback):
        return self.create_subscription(message_type, topic, callback, qos.TOPIC_QOS[topic])

    def _on_status(self, msg):
        try:
            status = conversions.parse_status(msg)
        except ValueError:
            return
        self.statuses[status.command_id] = status
        if status.settled:
            self.settled_at[status.command_id] = self.get_clock().now().nanoseconds

    @contextlib.contextmanager
    def _watching(self, topic, message_type, callback):
        """Subscribed to ``topic`` within the block: a subscription held only while needed (the
        true pose while validating, 200 Hz; the leg lengths while waiting for the platform)."""
        subscription = self._subscribe(topic, message_type, callback)
        try:
            yield
        finally:
            self.destroy_subscription(subscription)

    def _on_leg_lengths(self, msg):
        self.leg_lengths_seen = True

    def _on_true_pose(self, msg):
        try:
            pose = conversions.pose_stamped_to_pose(msg)
        except ValueError:
            return
        self.true_poses.append((conversions.stamp_to_nanoseconds(msg.header.stamp), pose))
        del self.true_poses[:-400]

    def _on_progress(self, msg):
        try:
            progress = conversions.parse_progress(msg)
        except ValueError:
            return
        k, m, phase = progress.posture_index, progress.posture_count, progress.phase
        per_posture = phase in (names.PHASE_MOVING, names.PHASE_COLLECTING)
        show = (
            (not per_posture and phase != self._last_phase)
            or 'skipped' in progress.extra
            or (
                phase == names.PHASE_COLLECTING
                and 'averaged' in progress.message
                and (k % 10 == 0 or k == m)
            )
        )
        self._last_phase = phase
        if show:
            line = f'  [{phase}] {k}/{m}: {progress.message.splitlines()[0]}'
            print(line, flush=True)

    def command(self, pose):
        stamp = self.get_clock().now()
        command_id = conversions.command_id_from_stamp(stamp)
        self.command_pub.publish(conversions.pose_to_pose_stamped(pose, stamp.to_msg()))
        return command_id

    def reached_pose(self, command_id):
        """True pose stamped after the settled status of ``command_id`` (None if not yet)."""
        start = self.settled_at.get(command_id)
        if start is None:
            return None
        for stamp, pose in self.true_poses:
            if stamp >= start:
                return pose
        return None

    def spin_until(self, condition, timeout, what):
        """Spin until ``condition()``; DemoError after ``timeout`` (s), NodeExited as soon as a
        node process exits."""

        def done():
            exited = self.processes.exited()
            if exited:
                name, code = exited
                log = self.processes.log_tail(name)
                raise NodeExited(f'{name} exited with code {code}:\n{log}')
            return condition()

        if not spin_until(self.executor, done, timeout):
            raise DemoError(f'timed out after {timeout:g} s waiting for {what}')

    def wait_for_system(self, timeout):
        for condition, what in (
            (self.calibrate_client.service_is_ready, f'the {names.SERVICE_CALIBRATE} service'),
            (
                lambda: self.command_pub.get_subscription_count() > 0,
                f'platform_sim to subscribe to {names.TOPIC_POSE_COMMAND}',
            ),
            (
                lambda: self.count_publishers(names.TOPIC_PLATFORM_STATUS) > 0,
                f'platform_sim to publish {names.TOPIC_PLATFORM_STATUS}',
            ),
        ):
            self.spin_until(condition, timeout, what)
        # The platform takes commands only once it knows where the legs are: platform_bridge
        # rejects every command until the controller's first /joint_states reached it, and it
        # publishes leg lengths from them.
        self.leg_lengths_seen = False
        with self._watching(names.TOPIC_LEG_LENGTHS, JointState, self._on_leg_lengths):
            self.spin_until(
                lambda: self.leg_lengths_seen,
                timeout,
                f"the platform's first {names.TOPIC_LEG_LENGTHS} (platform_bridge: the "
                "controller's /joint_states)",
            )

    def run_postures(self, poses, settle_timeout, startup_timeout):
        """Command each pose, wait until settled; reached poses (NaN rows where rejected)."""
        self.true_poses.clear()
        with self._watching(names.TOPIC_TRUE_POSE, PoseStamped, self._on_true_pose):
            self.spin_until(
                lambda: len(self.true_poses) > 0,
                startup_timeout,
                f'{names.TOPIC_TRUE_POSE} messages',
            )
            reached = np.full((len(poses), 6), np.nan)
            for m, pose in enumerate(poses):
                command_id = self.command(pose)

                def finished(command_id=command_id):
                    status = self.statuses.get(command_id)
                    return status is not None and (status.rejected or status.settled)

                self.spin_until(finished, settle_timeout, f'validation posture {m + 1} to settle')
                if self.statuses[command_id].rejected:
                    continue
                self.spin_until(
                    lambda c=command_id: self.reached_pose(c) is not None,
                    settle_timeout,
                    f'the true pose of validation posture {m + 1}',
                )
                reached[m] = self.reached_pose(command_id)
            return reached

    def calibrate(self, timeout):
        future = self.calibrate_client.call_async(Trigger.Request())
        self.spin_until(future.done, timeout, 'the calibration service to answer')
        return future.result()
