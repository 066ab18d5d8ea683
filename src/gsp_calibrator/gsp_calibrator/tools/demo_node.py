"""The ROS part of ``gsp_demo``: a client node of the suite, driven from the main thread."""

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
    """Client of the suite: progress printing, the calibrate call, validation postures."""

    def __init__(self, sim_time=False, **kwargs):
        """``sim_time``: on the simulation's /clock, as the other nodes are (the true poses'
        stamps are compared with this node's clock); ``**kwargs`` go to ``Node`` (``context=``)."""
        overrides = [Parameter('use_sim_time', value=sim_time)]
        super().__init__('gsp_demo', parameter_overrides=overrides, **kwargs)
        self.statuses = {}  # command_id -> PlatformStatus
        self.settled_at = {}  # command_id -> receive time (ns) of its settled status
        self.true_poses = []  # [(stamp_ns, pose)], recent only
        self.progress_lines = []
        self._last_phase = None
        self.calibrate_client = self.create_client(Trigger, names.SERVICE_CALIBRATE)
        self.command_pub = self.create_publisher(
            PoseStamped, names.TOPIC_POSE_COMMAND, qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND]
        )
        self.create_subscription(
            DiagnosticStatus,
            names.TOPIC_PLATFORM_STATUS,
            self._on_status,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
        )
        # Subscriptions held only while needed: the true pose while validating (200 Hz), the
        # leg lengths while waiting for the platform.
        self._watched = {}
        self.leg_lengths_seen = False
        self.create_subscription(
            DiagnosticStatus,
            names.TOPIC_CALIBRATION_PROGRESS,
            self._on_progress,
            qos.TOPIC_QOS[names.TOPIC_CALIBRATION_PROGRESS],
        )

    def _on_status(self, msg):
        try:
            status = conversions.parse_status(msg)
        except ValueError:
            return
        self.statuses[status.command_id] = status
        if status.settled:
            self.settled_at[status.command_id] = self.get_clock().now().nanoseconds

    def _watch(self, topic, message_type, callback, on):
        """Subscribe to ``topic`` (or unsubscribe) while it is needed; True when it starts."""
        subscription = self._watched.get(topic)
        if on and subscription is None:
            self._watched[topic] = self.create_subscription(
                message_type, topic, callback, qos.TOPIC_QOS[topic]
            )
            return True
        if not on and subscription is not None:
            self.destroy_subscription(self._watched.pop(topic))
        return False

    def watch_true_pose(self, on):
        """Subscribe to (or unsubscribe from) the ground truth."""
        if self._watch(names.TOPIC_TRUE_POSE, PoseStamped, self._on_true_pose, on):
            self.true_poses.clear()

    def watch_leg_lengths(self, on):
        """Subscribe to (or unsubscribe from) the platform's leg lengths."""
        if self._watch(names.TOPIC_LEG_LENGTHS, JointState, self._on_leg_lengths, on):
            self.leg_lengths_seen = False

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
            self.progress_lines.append(line)
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


class Demo:
    """Drives the demo node from the main thread (spinning a single-threaded executor)."""

    def __init__(self, node, executor, processes):
        self.node = node
        self.executor = executor
        self.processes = processes

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
        node = self.node
        self.spin_until(
            node.calibrate_client.service_is_ready,
            timeout,
            f'the {names.SERVICE_CALIBRATE} service',
        )
        self.spin_until(
            lambda: node.command_pub.get_subscription_count() > 0,
            timeout,
            f'platform_sim to subscribe to {names.TOPIC_POSE_COMMAND}',
        )
        self.spin_until(
            lambda: node.count_publishers(names.TOPIC_PLATFORM_STATUS) > 0,
            timeout,
            f'platform_sim to publish {names.TOPIC_PLATFORM_STATUS}',
        )
        # The platform takes commands only once it knows where the legs are: platform_bridge
        # rejects every command until the controller's first /joint_states reached it, and it
        # publishes leg lengths from them.
        node.watch_leg_lengths(True)
        try:
            self.spin_until(
                lambda: node.leg_lengths_seen,
                timeout,
                f"the platform's first {names.TOPIC_LEG_LENGTHS} (platform_bridge: the "
                "controller's /joint_states)",
            )
        finally:
            node.watch_leg_lengths(False)

    def run_postures(self, poses, settle_timeout, startup_timeout):
        """Command each pose, wait until settled; reached poses (NaN rows where rejected)."""
        node = self.node
        node.watch_true_pose(True)
        try:
            self.spin_until(
                lambda: len(node.true_poses) > 0,
                startup_timeout,
                f'{names.TOPIC_TRUE_POSE} messages',
            )
            return self._run_postures(poses, settle_timeout)
        finally:
            node.watch_true_pose(False)

    def _run_postures(self, poses, settle_timeout):
        node = self.node
        reached = np.full((len(poses), 6), np.nan)
        for m, pose in enumerate(poses):
            command_id = node.command(pose)

            def finished(command_id=command_id):
                status = node.statuses.get(command_id)
                return status is not None and (status.rejected or status.settled)

            self.spin_until(finished, settle_timeout, f'validation posture {m + 1} to settle')
            if node.statuses[command_id].rejected:
                continue
            self.spin_until(
                lambda c=command_id: node.reached_pose(c) is not None,
                settle_timeout,
                f'the true pose of validation posture {m + 1}',
            )
            reached[m] = node.reached_pose(command_id)
        return reached

    def calibrate(self, timeout):
        future = self.node.calibrate_client.call_async(Trigger.Request())
        self.spin_until(future.done, timeout, 'the calibration service to answer')
        return future.result()
