"""``gsp_demo``: the main job. A whole calibration of the simulated platform, end to end.

1. Starts ``platform_sim`` (true geometry, nominal controller), ``device_driver`` (true device)
   and ``calibrator`` (nominal geometry, ``apply_result``) as separate processes, with loopback
   discovery and a private random ``ROS_DOMAIN_ID`` (unless one is set).
2. Runs random validation postures through the system with the nominal controller (before).
3. Calls ``/gsp/calibrator/calibrate`` and prints its progress; the calibrator applies the result
   to the platform controller.
4. Runs the same validation postures again (after), comparing each commanded pose with
   ``/gsp/platform/true_pose``.
5. Prints a summary, writes ``true_geometry.yaml``, ``summary.json`` and the nodes' logs into the
   run directory, prints its path, stops every node (SIGINT, then SIGTERM, then SIGKILL) and
   exits 0 on success, 1 on failure.

The orchestration (commands, process handling, summary) is plain Python; :class:`DemoNode` is the
thin ROS part (a client of the suite's topics and service), driven from the main thread.
"""

import argparse
import contextlib
import ctypes
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gsp_kinematics.geometry import default_geometry_path, load_geometry, parameter_errors
from gsp_kinematics.kinematics import sample_valid_postures
from gsp_kinematics.validation import pose_errors, summarise

from . import calibration
from .run_directory import SUMMARY_FILE, TRUE_GEOMETRY_FILE, RunDirectory

#: The three nodes: executable (console script) and module (fallback: ``python -m``).
NODES = {
    'platform_sim': 'gsp_platform_sim.platform_sim_node',
    'device_driver': 'gsp_device_driver.device_driver_node',
    'calibrator': 'gsp_calibrator.calibrator_node',
}
SHUTDOWN_GRACE_S = 5.0  #: wait after SIGINT before SIGTERM, and after SIGTERM before SIGKILL
VALIDATION_KEYS = ('position_mm_mean', 'position_mm_max', 'orientation_deg_mean',
                   'orientation_deg_max')


class DemoError(RuntimeError):
    """The demo cannot go on; the message says why."""


class Terminated(Exception):
    """SIGTERM arrived: stop the nodes and exit with 143."""


def _raise_terminated(signum, frame):
    raise Terminated()


# --- pure parts ----------------------------------------------------------------------------------


def ros_environment(environ=None, rng=random):
    """A copy of ``environ`` with loopback discovery and a domain id (random 1..101 if unset)."""
    env = dict(os.environ if environ is None else environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if not env.get('ROS_DOMAIN_ID', '').strip():
        env['ROS_DOMAIN_ID'] = str(rng.randint(1, 101))
    env['PYTHONUNBUFFERED'] = '1'
    return env


def executable_command(name, which=shutil.which):
    """argv prefix of node ``name``: its console script from PATH, else ``python -m <module>``."""
    path = which(name)
    if path:
        return [path]
    return [sys.executable, '-m', NODES[name]]


def node_commands(args, output_root, which=shutil.which):
    """``{node name: argv}`` of the three nodes for the parsed ``args``."""
    rate = float(args.sensor_rate)
    common = ['-p', f'publish_rate:={rate!r}', '-p', f'seed:={int(args.seed)}']
    return {
        'platform_sim': executable_command('platform_sim', which) + [
            '--ros-args', '--params-file', str(args.nominal_geometry),
            '-p', f'true_geometry_file:={args.true_geometry}',
            '-p', f'settle_time:={float(args.settle_time)!r}',
            '-p', 'publish_markers:=false', *common],
        'device_driver': executable_command('device_driver', which) + [
            '--ros-args', '-p', f'true_geometry_file:={args.true_geometry}', *common],
        'calibrator': executable_command('calibrator', which) + [
            '--ros-args',
            '-p', f'nominal_geometry_file:={args.nominal_geometry}',
            '-p', f'output_root:={output_root}',
            '-p', f'posture_count:={int(args.postures)}',
            '-p', f'pool_size:={max(int(args.pool_size), int(args.postures))}',
            '-p', f'samples_per_posture:={int(args.samples_per_posture)}',
            '-p', f'sync_tolerance:={0.5 / rate!r}',
            '-p', f'seed:={int(args.seed)}',
            '-p', f'formulation:={args.formulation}',
            '-p', 'apply_result:=true'],
    }


def validation_summary(commanded, reached):
    """Mean and max errors (mm, deg) over the rows of ``reached`` without NaN."""
    commanded, reached = np.asarray(commanded), np.asarray(reached)
    keep = np.all(np.isfinite(reached), axis=1)
    if not keep.any():
        return {key: math.nan for key in VALIDATION_KEYS}
    position_mm, orientation_deg = pose_errors(commanded[keep], reached[keep])
    return summarise(position_mm, orientation_deg)


def validation_details(commanded, reached):
    """:func:`validation_summary` plus the per-posture errors ``position_mm`` and
    ``orientation_deg`` (lists, rows of ``reached`` without NaN), for the run's report."""
    commanded, reached = np.asarray(commanded), np.asarray(reached)
    details = dict(validation_summary(commanded, reached))
    keep = np.all(np.isfinite(reached), axis=1)
    if keep.any():
        position_mm, orientation_deg = pose_errors(commanded[keep], reached[keep])
        details['position_mm'] = np.asarray(position_mm, dtype=float).tolist()
        details['orientation_deg'] = np.asarray(orientation_deg, dtype=float).tolist()
    details['postures'] = int(keep.sum())
    return details


def parameter_error_maxima(calibrated, true):
    """``(max |error| of the 43 lengths in mm, |gamma error| in deg)``."""
    errors = parameter_errors(calibrated, true)
    return float(np.max(np.abs(errors[:43]))), float(abs(errors[43]))


def make_summary(before, after, calibrated, true, identification_ms, calibration_s, total_s):
    """The ``summary.json`` document (keys as in issue 3)."""
    max_mm, max_deg = parameter_error_maxima(calibrated, true)
    return {
        'validation': {'before': dict(before), 'after': dict(after)},
        'max_param_error_mm': max_mm,
        'max_param_error_deg': max_deg,
        'identification_ms': float(identification_ms),
        'calibration_s': float(calibration_s),
        'total_s': float(total_s),
    }


def summary_text(summary, validated, rejected):
    """Human-readable lines of ``summary``."""
    before, after = summary['validation']['before'], summary['validation']['after']
    lines = [
        f'validation over {validated} postures ({rejected} rejected by the platform):',
        '                    position mm (mean / max)   orientation deg (mean / max)',
    ]
    for label, values in (('before (nominal)', before), ('after (calibrated)', after)):
        lines.append(
            f'  {label:<18}{values["position_mm_mean"]:>10.4f} / {values["position_mm_max"]:<10.4f}'
            f'{values["orientation_deg_mean"]:>14.5f} / {values["orientation_deg_max"]:.5f}')
    lines += [
        f'parameter errors vs the true geometry: max {summary["max_param_error_mm"]:.4f} mm, '
        f'gamma {summary["max_param_error_deg"]:.5f} deg',
        f'identification time: {summary["identification_ms"]:.0f} ms; calibration '
        f'{summary["calibration_s"]:.1f} s; total {summary["total_s"]:.1f} s',
    ]
    return '\n'.join(lines)


# --- child processes -----------------------------------------------------------------------------


def _load_libc():
    if not sys.platform.startswith('linux'):
        return None
    try:
        return ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None


_LIBC = _load_libc()  # loaded in the parent: the child must not dlopen between fork and exec
_PR_SET_PDEATHSIG = 1


def _die_with_parent():
    """In the child before exec: get SIGTERM if the demo dies, even by SIGKILL (Linux)."""
    if _LIBC is not None:
        _LIBC.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)


class NodeProcesses:
    """The nodes as child processes; :meth:`stop` ends all of them (idempotent)."""

    def __init__(self, commands, env, log_directory):
        self.commands = commands
        self.env = env
        self.log_directory = Path(log_directory)
        self.processes = {}
        self._logs = {}

    def start(self):
        for name, argv in self.commands.items():
            log = open(self.log_directory / f'{name}.log', 'wb')  # closed in stop()
            self._logs[name] = log
            self.processes[name] = subprocess.Popen(
                argv, env=self.env, stdin=subprocess.DEVNULL, stdout=log,
                stderr=subprocess.STDOUT, start_new_session=True,
                preexec_fn=_die_with_parent if _LIBC is not None else None)

    def check_alive(self):
        """DemoError naming a node that has exited, with the end of its log."""
        for name, process in self.processes.items():
            code = process.poll()
            if code is not None:
                raise DemoError(f'{name} exited with code {code}:\n{self.log_tail(name)}')

    def log_tail(self, name, lines=15):
        path = self.log_directory / f'{name}.log'
        try:
            text = path.read_text(errors='replace')
        except OSError:
            return ''
        return '\n'.join(f'  | {line}' for line in text.splitlines()[-lines:])

    def _signal_all(self, sig):
        for process in self.processes.values():
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    process.send_signal(sig)

    def _wait_all(self, timeout):
        deadline = time.monotonic() + timeout
        for process in self.processes.values():
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=max(0.0, deadline - time.monotonic()))
        return all(p.poll() is not None for p in self.processes.values())

    def stop(self, grace=SHUTDOWN_GRACE_S):
        """SIGINT, wait; SIGTERM, wait; SIGKILL. Returns ``{name: exit code}``."""
        if not self._wait_all(0.0):
            self._signal_all(signal.SIGINT)
            if not self._wait_all(grace):
                self._signal_all(signal.SIGTERM)
                if not self._wait_all(grace):
                    self._signal_all(signal.SIGKILL)
                    self._wait_all(grace)
        for log in self._logs.values():
            log.close()
        return {name: p.returncode for name, p in self.processes.items()}


# --- the ROS part --------------------------------------------------------------------------------


def _make_demo_node(context):
    """The demo's node (imports rclpy only here, after the environment is set)."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node
    from std_srvs.srv import Trigger

    from gsp_msgs_py import conversions, names, qos

    class DemoNode(Node):
        """Client of the suite: progress printing, the calibrate call, validation postures."""

        def __init__(self, **kwargs):
            super().__init__('gsp_demo', **kwargs)
            self.statuses = {}  # command_id -> PlatformStatus
            self.settled_at = {}  # command_id -> receive time (ns) of its settled status
            self.true_poses = []  # [(stamp_ns, pose)], recent only
            self.progress_lines = []
            self._last_phase = None
            self.calibrate_client = self.create_client(Trigger, names.SERVICE_CALIBRATE)
            self.command_pub = self.create_publisher(
                PoseStamped, names.TOPIC_POSE_COMMAND, qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND])
            self.create_subscription(
                DiagnosticStatus, names.TOPIC_PLATFORM_STATUS, self._on_status,
                qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS])
            self._true_pose_subscription = None  # only while validating (200 Hz)
            self.create_subscription(
                DiagnosticStatus, names.TOPIC_CALIBRATION_PROGRESS, self._on_progress,
                qos.TOPIC_QOS[names.TOPIC_CALIBRATION_PROGRESS])

        def _on_status(self, msg):
            try:
                status = conversions.parse_status(msg)
            except ValueError:
                return
            self.statuses[status.command_id] = status
            if status.settled:
                self.settled_at[status.command_id] = self.get_clock().now().nanoseconds

        def watch_true_pose(self, on):
            """Subscribe to (or unsubscribe from) the ground truth."""
            if on and self._true_pose_subscription is None:
                self.true_poses.clear()
                self._true_pose_subscription = self.create_subscription(
                    PoseStamped, names.TOPIC_TRUE_POSE, self._on_true_pose,
                    qos.TOPIC_QOS[names.TOPIC_TRUE_POSE])
            elif not on and self._true_pose_subscription is not None:
                self.destroy_subscription(self._true_pose_subscription)
                self._true_pose_subscription = None

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
            show = ((not per_posture and phase != self._last_phase) or 'skipped' in progress.extra
                    or (phase == names.PHASE_COLLECTING and 'averaged' in progress.message
                        and (k % 10 == 0 or k == m)))
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

    return DemoNode(context=context)


class Demo:
    """Drives the demo node from the main thread (spinning a single-threaded executor)."""

    def __init__(self, node, executor, processes):
        self.node = node
        self.executor = executor
        self.processes = processes

    def spin_until(self, condition, timeout, what):
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise DemoError(f'timed out after {timeout:g} s waiting for {what}')
            self.processes.check_alive()
            self.executor.spin_once(timeout_sec=0.02)

    def wait_for_system(self, timeout):
        from gsp_msgs_py import names

        node = self.node
        self.spin_until(node.calibrate_client.service_is_ready, timeout,
                        f'the {names.SERVICE_CALIBRATE} service')
        self.spin_until(lambda: node.command_pub.get_subscription_count() > 0, timeout,
                        f'platform_sim to subscribe to {names.TOPIC_POSE_COMMAND}')
        self.spin_until(lambda: node.count_publishers(names.TOPIC_PLATFORM_STATUS) > 0, timeout,
                        f'platform_sim to publish {names.TOPIC_PLATFORM_STATUS}')

    def run_postures(self, poses, settle_timeout, startup_timeout):
        """Command each pose, wait until settled; reached poses (NaN rows where rejected)."""
        from gsp_msgs_py import names

        node = self.node
        node.watch_true_pose(True)
        try:
            self.spin_until(lambda: len(node.true_poses) > 0, startup_timeout,
                            f'{names.TOPIC_TRUE_POSE} messages')
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
            self.spin_until(lambda c=command_id: node.reached_pose(c) is not None, settle_timeout,
                            f'the true pose of validation posture {m + 1}')
            reached[m] = node.reached_pose(command_id)
        return reached

    def calibrate(self, timeout):
        from std_srvs.srv import Trigger

        future = self.node.calibrate_client.call_async(Trigger.Request())
        self.spin_until(future.done, timeout, 'the calibration service to answer')
        return future.result()


# --- main ----------------------------------------------------------------------------------------


def parse_arguments(argv=None):
    parser = argparse.ArgumentParser(
        prog='gsp_demo', description='End-to-end calibration demo of the simulated platform.')
    parser.add_argument('--output-root', default='runs',
                        help='root of the run directories (default: runs)')
    parser.add_argument('--true-geometry', default=default_geometry_path('true'),
                        help='geometry of the simulated real platform (default: shipped true)')
    parser.add_argument('--nominal-geometry', default=default_geometry_path('nominal'),
                        help='nominal geometry: controller start and identification start')
    parser.add_argument('--postures', type=int, default=60, help='calibration postures (60)')
    parser.add_argument('--pool-size', type=int, default=600, help='selection pool (600)')
    parser.add_argument('--samples-per-posture', type=int, default=10, help='(10)')
    parser.add_argument('--validation-postures', type=int, default=50, help='(50)')
    parser.add_argument('--formulation', default='implicit', choices=('implicit', 'fk', 'paper'))
    parser.add_argument('--seed', type=int, default=0, help='seed of postures and noise (0)')
    parser.add_argument('--sensor-rate', type=float, default=200.0,
                        help='leg-length and device rate, Hz (200)')
    parser.add_argument('--settle-time', type=float, default=0.02,
                        help="platform_sim's moving-to-settled time, s (0.02)")
    parser.add_argument('--timeout', type=float, default=120.0,
                        help='longest wait for the calibration, s (120)')
    parser.add_argument('--startup-timeout', type=float, default=30.0,
                        help='longest wait for the nodes to come up, s (30)')
    args = parser.parse_args(argv)
    for name in ('postures', 'pool_size', 'samples_per_posture', 'validation_postures'):
        if getattr(args, name) < 1:
            parser.error(f'--{name.replace("_", "-")} must be >= 1')
    if not args.sensor_rate > 0 or not args.settle_time >= 0:
        parser.error('--sensor-rate must be > 0 and --settle-time >= 0')
    args.true_geometry = os.path.abspath(args.true_geometry)
    args.nominal_geometry = os.path.abspath(args.nominal_geometry)
    return args


def run(args):
    """The demo; returns the exit code."""
    started = time.monotonic()
    true_geometry = load_geometry(args.true_geometry)
    nominal = load_geometry(args.nominal_geometry)
    output_root = os.path.abspath(args.output_root)
    env = ros_environment()
    os.environ.update({k: env[k] for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID')})
    print(f'gsp_demo: ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]} (loopback only), output under '
          f'{output_root}', flush=True)
    validation_poses = sample_valid_postures(
        nominal, args.validation_postures, np.random.default_rng(args.seed + 1_000_003))

    log_directory = Path(tempfile.mkdtemp(prefix='gsp_demo_logs_'))
    processes = NodeProcesses(node_commands(args, output_root), env, log_directory)
    # The children first, before rclpy starts its middleware threads (preexec_fn runs between
    # fork and exec).
    processes.start()
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    context = node = executor = None
    run_directory = None
    exit_code = 1
    try:
        context = rclpy.Context()
        # Ctrl-C (KeyboardInterrupt) and SIGTERM (Terminated) reach this thread; the finally
        # below stops the nodes.
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
        node = _make_demo_node(context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        demo = Demo(node, executor, processes)
        print('starting platform_sim, device_driver and calibrator ...', flush=True)
        demo.wait_for_system(args.startup_timeout)
        settle_timeout = 5.0 + 10.0 * args.settle_time

        print(f'validation before calibration: {len(validation_poses)} postures (nominal '
              'controller) ...', flush=True)
        reached_before = demo.run_postures(validation_poses, settle_timeout,
                                           args.startup_timeout)

        print('calibrating (/gsp/calibrator/calibrate) ...', flush=True)
        calibration_started = time.monotonic()
        response = demo.calibrate(args.timeout)
        calibration_s = time.monotonic() - calibration_started
        parsed = calibration.parse_response(response.message)
        if parsed.run_directory:
            run_directory = RunDirectory(parsed.run_directory)
        if not response.success:
            raise DemoError(f'calibration failed:\n{parsed.summary}')
        print(parsed.summary, flush=True)
        from gsp_kinematics.geometry import geometry_from_yaml

        calibrated = geometry_from_yaml(parsed.geometry_yaml, source='calibrate response')

        print(f'validation after calibration: {len(validation_poses)} postures ...', flush=True)
        reached_after = demo.run_postures(validation_poses, settle_timeout, args.startup_timeout)
        both = np.all(np.isfinite(reached_before), axis=1) & np.all(np.isfinite(reached_after),
                                                                     axis=1)
        if not both.any():
            raise DemoError('every validation posture was rejected by the platform')
        before = validation_summary(validation_poses[both], reached_before[both])
        after = validation_summary(validation_poses[both], reached_after[both])
        details_before = validation_details(validation_poses[both], reached_before[both])
        details_after = validation_details(validation_poses[both], reached_after[both])
        exit_code = 0
    except DemoError as error:
        print(f'gsp_demo: FAILED: {error}', file=sys.stderr, flush=True)
    except (KeyboardInterrupt, ExternalShutdownException):
        print('gsp_demo: interrupted', file=sys.stderr, flush=True)
        exit_code = 130
    except Terminated:
        print('gsp_demo: terminated', file=sys.stderr, flush=True)
        exit_code = 143
    finally:
        # Nothing interrupts the clean-up (it is bounded: SIGINT, SIGTERM, SIGKILL).
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        if context is not None:
            rclpy.try_shutdown(context=context)
        codes = processes.stop()
        left = [name for name, code in codes.items() if code is None]
        if left:
            print(f'gsp_demo: could not stop {left}', file=sys.stderr)
            exit_code = exit_code or 1
        if run_directory is not None:
            for name in NODES:
                log = log_directory / f'{name}.log'
                if log.exists():
                    run_directory.write_bytes(f'{name}.log', log.read_bytes())
            shutil.rmtree(log_directory, ignore_errors=True)
        else:
            print(f'gsp_demo: the nodes\' logs are in {log_directory}', file=sys.stderr)

    if exit_code != 0:
        if run_directory is not None:
            print(f'run directory: {run_directory.path}', flush=True)
        return exit_code
    summary = make_summary(before, after, calibrated, true_geometry, parsed.identification_ms,
                           calibration_s, time.monotonic() - started)
    run_directory.write_text(TRUE_GEOMETRY_FILE, Path(args.true_geometry).read_text())
    run_directory.write_json(SUMMARY_FILE, summary)
    try:  # the calibrator's report, now against the truth and with the validation distributions
        from . import offline

        offline.refresh_report(run_directory.path, truth=true_geometry,
                               validation_before=details_before, validation_after=details_after)
    except Exception as error:  # noqa: BLE001 (the demo itself succeeded)
        print(f'gsp_demo: report not refreshed: {error}', file=sys.stderr, flush=True)
    print(summary_text(summary, int(both.sum()), int((~both).sum())), flush=True)
    print(f'run directory: {run_directory.path}', flush=True)
    return 0


def main(argv=None):
    """Console script ``gsp_demo``."""
    args = parse_arguments(argv)
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        return run(args)
    except KeyboardInterrupt:
        return 130
    except Terminated:
        return 143


if __name__ == '__main__':
    sys.exit(main())

