"""``gsp_check_interfaces``: does a driver honour the suite's interface contract? (docs/hardware.md)"""

import argparse
import sys
import time

from .. import conversions, names, qos
from ..diagnostics import DiagnosticsListener
from ..node_tools import spin_until
from .rules import (
    SENSOR_TOPICS,
    Limits,
    Received,
    diagnostics_summary,
    topic_summary,
    validate_diagnostics,
    validate_topics,
)

NODE_NAME = 'gsp_check_interfaces'
NODE_LOOK_PERIOD_S = 0.1  #: between two looks at the graph's nodes (the queries are not free)


class PoseCommandProbe:
    """Commands poses on ``node`` and collects the platform's status answers to them."""

    def __init__(self, node):
        from diagnostic_msgs.msg import DiagnosticStatus
        from geometry_msgs.msg import PoseStamped

        self.node = node
        self.statuses = []  #: every status message received, in order
        self._subscription = node.create_subscription(
            DiagnosticStatus,
            names.TOPIC_PLATFORM_STATUS,
            self.statuses.append,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
        )
        self._publisher = node.create_publisher(
            PoseStamped, names.TOPIC_POSE_COMMAND, qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND]
        )

    def listened(self):
        """Whether anybody subscribes to the pose commands."""
        return self._publisher.get_subscription_count() > 0

    def send(self, pose, frame_id=names.FRAME_BASE):
        """Command ``pose`` (m, rad) in ``frame_id``, stamped now; returns its command id."""
        stamp = self.node.get_clock().now().to_msg()
        self._publisher.publish(conversions.pose_to_pose_stamped(pose, stamp, frame_id))
        return conversions.command_id_from_stamp(stamp)

    def answers(self, command_id):
        """The parsed statuses of ``command_id``, in order (unparsable ones skipped)."""
        answers = []
        for msg in self.statuses:
            try:
                status = conversions.parse_status(msg)
            except ValueError:
                continue
            if status.command_id == command_id:
                answers.append(status)
        return answers

    def final_status(self, command_id):
        """The first settled or rejected status of ``command_id``, or None."""
        final = [s for s in self.answers(command_id) if s.state != names.STATE_MOVING]
        return final[0] if final else None

    def problems(self, command_id):
        """What is wrong with the answers to the test command ``command_id``."""
        if not self.listened():
            return [f'{names.TOPIC_POSE_COMMAND}: nobody subscribes to pose commands']
        status = self.final_status(command_id)
        if status is None:
            return [
                f'{names.TOPIC_PLATFORM_STATUS}: the test command {command_id} was '
                + ('never settled or rejected' if self.answers(command_id) else 'not answered')
            ]
        if status.state == names.STATE_REJECTED:
            return [
                f'{names.TOPIC_PLATFORM_STATUS}: the test command was rejected: {status.reason}'
            ]
        return []


class InterfaceChecker:
    """Records the sensor topics on ``node`` and judges their publishers' types and QoS."""

    def __init__(self, node, limits=Limits()):
        from sensor_msgs.msg import JointState

        self.node = node
        self.limits = limits
        self.received = {topic: [] for topic in SENSOR_TOPICS}
        self.recording = True
        for topic in SENSOR_TOPICS:
            node.create_subscription(
                JointState,
                topic,
                lambda msg, t=topic: self._on_joint_state(t, msg),
                qos.TOPIC_QOS[topic],
            )

    def _on_joint_state(self, topic, msg):
        if self.recording:
            self.received[topic].append(
                Received(
                    self.node.get_clock().now().nanoseconds * 1e-9,
                    conversions.stamp_to_seconds(msg.header.stamp),
                    tuple(msg.name),
                    tuple(msg.position),
                )
            )

    def qos_problems(self):
        """Publishers of the sensor topics with another type or an incompatible QoS."""
        from rclpy.qos import QoSCompatibility, qos_check_compatible

        problems = []
        for topic in SENSOR_TOPICS:
            expected_type = names.TOPIC_TYPES[topic]
            for info in self.node.get_publishers_info_by_topic(topic):
                who = f'{info.node_namespace.rstrip("/")}/{info.node_name}'
                if info.topic_type != expected_type:
                    problems.append(
                        f'{topic}: {who} publishes {info.topic_type}, not {expected_type}'
                    )
                    continue
                compatibility, reason = qos_check_compatible(info.qos_profile, qos.TOPIC_QOS[topic])
                if compatibility == QoSCompatibility.ERROR:
                    problems.append(f'{topic}: QoS of {who} is incompatible: {reason}')
        return problems

    def summary_lines(self):
        lines = []
        for topic, received in self.received.items():
            summary = topic_summary(received)
            noise = ', '.join(f'{v:.3g}' for v in summary['noise_std']) or '-'
            lines.append(
                f'  {topic}: {summary["count"]} messages, {summary["rate_hz"]:.1f} Hz, '
                f'delay {summary["delay_s"] * 1e3:.2f} ms, noise std [{noise}]'
            )
        return lines


def parse_arguments(argv=None):
    parser = argparse.ArgumentParser(
        prog='gsp_check_interfaces', description=__doc__.split('\n')[0]
    )
    parser.add_argument('--duration', type=float, default=5.0, help='listening time, s (5)')
    parser.add_argument(
        '--send-test-command',
        action='store_true',
        help='command the home pose (the platform moves) and expect a status answer',
    )
    parser.add_argument('--command-timeout', type=float, default=10.0, help='s (10)')
    parser.add_argument(
        '--diagnostics-period',
        type=float,
        default=1.0,
        help="the nodes' diagnostics_period, s (1): a suite node seen for two without a status "
        'on /diagnostics is a problem',
    )
    parser.add_argument(
        '--min-rate', type=float, default=Limits().min_rate_hz, help='least rate of each topic, Hz'
    )
    args, ros_args = parser.parse_known_args(argv)
    if not min(args.duration, args.command_timeout, args.min_rate, args.diagnostics_period) > 0:
        parser.error(
            '--duration, --command-timeout, --min-rate and --diagnostics-period must be > 0'
        )
    return args, ros_args


def run_check(node, executor, args):
    """Listen, optionally command; returns ``(problems, summary lines)``."""
    checker = InterfaceChecker(node, Limits(min_rate_hz=args.min_rate))
    diagnostics = DiagnosticsListener(node)
    probe = PoseCommandProbe(node) if args.send_test_command else None
    first_seen_s = {}

    def seen_for_s():
        """``{name: s since first seen}`` of the nodes in the graph now (monotonic clock)."""
        now_s = time.monotonic()
        present = [name for name, _ in node.get_node_names_and_namespaces()]
        return {name: now_s - first_seen_s.setdefault(name, now_s) for name in present}

    seen_for_s()
    node.create_timer(NODE_LOOK_PERIOD_S, seen_for_s)
    deadline = time.monotonic() + args.duration
    spin_until(executor, lambda: time.monotonic() >= deadline, args.duration + 1.0)
    checker.recording = False
    problems = checker.qos_problems() + validate_topics(checker.received, checker.limits)
    seen, grace_s = seen_for_s(), 2.0 * args.diagnostics_period
    problems += validate_diagnostics(diagnostics.reports, seen, grace_s)
    problems += [f'{names.TOPIC_DIAGNOSTICS}: {why}' for why in diagnostics.malformed[:1]]
    if probe is not None:
        from gsp_kinematics.model.kinematics import home_pose

        spin_until(executor, probe.listened, args.command_timeout)
        command_id = None
        if probe.listened():
            command_id = probe.send(home_pose())
            answered = lambda: probe.final_status(command_id) is not None  # noqa: E731
            spin_until(executor, answered, args.command_timeout)
        problems += probe.problems(command_id)
    lines = checker.summary_lines() + [f'  {names.TOPIC_DIAGNOSTICS}:']
    heard = diagnostics_summary(diagnostics.reports, seen, grace_s)
    return problems, lines + (heard or ['    (none heard)'])


def main(argv=None):
    """Console script ``gsp_check_interfaces``: 0 if the interfaces conform, else 1."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    args, ros_args = parse_arguments(sys.argv[1:] if argv is None else argv)
    rclpy.init(args=['gsp_check_interfaces', *ros_args])
    node = rclpy.create_node(NODE_NAME)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        problems, lines = run_check(node, executor, args)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    print(f'gsp_check_interfaces: listened {args.duration:g} s')
    print('\n'.join(lines))
    for problem in problems:
        print(f'PROBLEM: {problem}')
    print('conforms' if not problems else f'{len(problems)} problem(s)')
    return 1 if problems else 0


if __name__ == '__main__':
    sys.exit(main())
