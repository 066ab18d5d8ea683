"""``gsp_calibrate_client``: run a calibration (or, with ``--check``, the one-minute check of
docs/upkeep.md: exit code 0 within tolerance, 3 recalibrate) without the ``ros2`` CLI."""

import argparse
import math
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.srv import SetParameters
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from gsp_calibrator.run.response import parse_response, residual_summary
from gsp_kinematics.estimation.noise_from_data import NOISE_SOURCES
from gsp_msgs_py import conversions, names
from gsp_msgs_py.node_tools import spin_until
from gsp_msgs_py.qos import PROGRESS_QOS

EXIT_OK = 0
EXIT_FAILED = 1
#: ``--check``: the check ran and says recalibrate.
EXIT_RECALIBRATE = 3
EXIT_INTERRUPTED = 130
#: How a check's response starts when it says recalibrate (upkeep.check_run.check_summary).
RECALIBRATE_PREFIX = 'check: RECALIBRATE'

NODE_NAME = 'gsp_calibrate_client'
BAR_WIDTH = 30
#: Longest progress message shown on the bar (the full text comes with the response).
MESSAGE_WIDTH = 100


class ProgressBar:
    """Renders calibration progress on a stream: one redrawn line on a terminal, else a line per
    phase change and about every tenth posture (logs stay short)."""

    def __init__(self, stream, width=BAR_WIDTH, interactive=None):
        self.stream = stream
        self.width = int(width)
        self.interactive = stream.isatty() if interactive is None else bool(interactive)
        self._last = None
        self._drawn = False

    def line(self, progress):
        """Text of one progress update (no newline)."""
        count = max(progress.posture_count, 0)
        index = min(max(progress.posture_index, 0), count) if count else 0
        filled = int(round(self.width * index / count)) if count else 0
        bar = '#' * filled + '-' * (self.width - filled)
        text = f'[{bar}] {index}/{count} {progress.phase}'
        residuals = progress.residuals
        if isinstance(residuals, dict) and residuals:
            try:
                text += f'  residuals: {residual_summary(residuals)}'
            except (TypeError, ValueError):
                pass
        message = ' '.join(str(progress.message).split())  # one line
        if message and message != f'{progress.phase} {index}/{count}':
            if len(message) > MESSAGE_WIDTH:
                message = message[: MESSAGE_WIDTH - 3] + '...'
            text += f'  ({message})'
        return text

    def update(self, progress):
        text = self.line(progress)
        if self.interactive:
            self.stream.write('\r\x1b[2K' + text)
            self._drawn = True
        else:
            key = (progress.phase, progress.posture_index)
            step = max(1, progress.posture_count // 10)
            last_phase = self._last[0] if self._last else None
            if key != self._last and (
                progress.phase != last_phase
                or progress.posture_index % step == 0
                or progress.posture_index == progress.posture_count
            ):
                self.stream.write(text + '\n')
            self._last = key
        self.stream.flush()

    def finish(self):
        if self.interactive and self._drawn:
            self.stream.write('\n')
            self.stream.flush()
            self._drawn = False


class CalibrateClient(Node):
    """Calls the calibrate service and follows the progress topic (keyword arguments go to Node)."""

    def __init__(self, service=names.SERVICE_CALIBRATE, progress=None, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.client = self.create_client(Trigger, service)
        self.progress = progress
        self.bad_progress = 0
        self.create_subscription(
            DiagnosticStatus, names.TOPIC_CALIBRATION_PROGRESS, self._on_progress, PROGRESS_QOS
        )

    def _on_progress(self, msg):
        try:
            progress = conversions.parse_progress(msg)
        except ValueError as error:
            self.bad_progress += 1
            if self.bad_progress == 1:
                self.get_logger().warning(f'ignoring a malformed progress message: {error}')
            return
        if self.progress is not None:
            self.progress.update(progress)

    def set_parameter(self, executor, node_name, name, value, timeout):
        """Set parameter ``name`` of ``/<node_name>``; ``''`` or why it was not set."""
        service = f'/{node_name.lstrip("/")}/set_parameters'
        client = self.create_client(SetParameters, service)
        deadline = time.monotonic() + timeout
        try:
            if not spin_until(executor, client.service_is_ready, timeout):
                return f'{service} not available after {timeout:g} s'
            request = SetParameters.Request()
            request.parameters = [Parameter(name, value=value).to_parameter_msg()]
            future = client.call_async(request)
            if not spin_until(executor, future.done, deadline - time.monotonic()):
                client.remove_pending_request(future)
                return f'{service}: no answer within {timeout:g} s'
            result = future.result().results[0]
            return '' if result.successful else f'{name} rejected: {result.reason}'
        finally:
            self.destroy_client(client)

    def call(self, executor, timeout):
        """Call the service, spinning (progress updates) until the response; None on timeout."""
        future = self.client.call_async(Trigger.Request())
        if not spin_until(executor, future.done, timeout):
            self.client.remove_pending_request(future)
            return None
        return future.result()


def build_parser():
    parser = argparse.ArgumentParser(
        prog='gsp_calibrate_client',
        description='Call the calibrator service, show its progress, print the summary and the '
        'run directory (for installs without the ros2 CLI).',
    )
    parser.add_argument(
        '--service',
        default=names.SERVICE_CALIBRATE,
        help='Trigger service to call (default %(default)s)',
    )
    parser.add_argument(
        '--check',
        action='store_true',
        help=f'run the one-minute check ({names.SERVICE_CHECK}) instead of a calibration: exit '
        f'status 0 within tolerance, {EXIT_RECALIBRATE} recalibrate (docs/upkeep.md)',
    )
    parser.add_argument(
        '--wait-timeout',
        type=float,
        default=10.0,
        metavar='S',
        help='longest wait for the service to appear, s (default %(default)g; 0: forever)',
    )
    parser.add_argument(
        '--timeout',
        type=float,
        default=0.0,
        metavar='S',
        help='longest wait for the response, s (default: 0, forever)',
    )
    parser.add_argument(
        '--noise-source',
        choices=NOISE_SOURCES,
        default=None,
        help="set the calibrator's noise_source parameter first: the weights from the noise "
        'estimated from the run or from the configured sigma_* (default: leave it as it is)',
    )
    parser.add_argument(
        '--calibrator',
        default=names.NODE_CALIBRATOR,
        help='the calibrator node whose parameter --noise-source sets (default %(default)s)',
    )
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    parser.add_argument(
        '--geometry',
        action='store_true',
        help='also print the calibrated geometry (ROS 2 parameters YAML)',
    )
    return parser


def run(args, context=None, out=None, err=None):
    """Run the client for parsed ``args`` in an initialised ``context``; returns the exit code."""
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    progress = None if args.no_progress else ProgressBar(err)
    if args.check and args.service == names.SERVICE_CALIBRATE:
        args.service = names.SERVICE_CHECK
    node = CalibrateClient(service=args.service, progress=progress, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        wait = args.wait_timeout if args.wait_timeout > 0 else math.inf
        if not spin_until(executor, node.client.service_is_ready, wait):
            print(
                f'gsp_calibrate_client: service {args.service} not available after '
                f'{args.wait_timeout:g} s (is the calibrator running, in this ROS_DOMAIN_ID?)',
                file=err,
            )
            return EXIT_FAILED
        if args.noise_source is not None:
            why = node.set_parameter(
                executor, args.calibrator, 'noise_source', args.noise_source, wait
            )
            if why:
                print(f'gsp_calibrate_client: noise_source not set: {why}', file=err)
                return EXIT_FAILED
        print(f'calling {args.service} ...', file=err)
        response = node.call(executor, args.timeout if args.timeout > 0 else math.inf)
        if progress is not None:
            progress.finish()
        if response is None:
            print(
                f'gsp_calibrate_client: no response from {args.service} within {args.timeout:g} s',
                file=err,
            )
            return EXIT_FAILED
        parsed = parse_response(response.message)
        print(parsed.summary, file=out)
        if args.geometry and parsed.geometry_yaml:
            print(
                parsed.geometry_yaml,
                file=out,
                end='' if parsed.geometry_yaml.endswith('\n') else '\n',
            )
        if not response.success:
            print(
                f'gsp_calibrate_client: {"check" if args.check else "calibration"} failed', file=err
            )
            return EXIT_FAILED
        if args.check and response.message.startswith(RECALIBRATE_PREFIX):
            return EXIT_RECALIBRATE
        return EXIT_OK
    finally:
        if progress is not None:
            progress.finish()
        executor.remove_node(node)
        executor.shutdown()
        node.destroy_node()


def main(argv=None):
    from rclpy.utilities import remove_ros_args

    argv = sys.argv if argv is None else [sys.argv[0], *argv]
    args = build_parser().parse_args(remove_ros_args(argv)[1:])
    rclpy.init(args=argv)
    try:
        return run(args)
    except (KeyboardInterrupt, ExternalShutdownException):
        print('\ngsp_calibrate_client: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
