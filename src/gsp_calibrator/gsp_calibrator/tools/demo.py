"""``gsp_demo``: the main job. A whole calibration of the simulated platform, end to end.

1. Starts ``platform_sim`` (true geometry, nominal controller), ``device_driver`` (true device)
   and ``calibrator`` (nominal geometry, ``apply_result``) as separate processes, with loopback
   discovery and a private random ``ROS_DOMAIN_ID`` (unless one is set).
2. Runs random validation postures through the system with the nominal controller (before).
3. Calls ``/gsp/calibrator/calibrate`` and prints its progress; the calibrator applies the result
   to the platform controller.
4. Runs the same validation postures again (after), comparing each commanded pose with
   ``/gsp/platform/true_pose``.
5. Prints a summary, writes ``true_geometry.yaml``, ``summary.json`` (with the run directory's
   path and the calibrator's ``collection`` record) and the nodes' logs into the run directory,
   prints its path, stops every node (SIGINT, then SIGTERM, then SIGKILL) and
   exits 0 on success, 1 on failure.

The orchestration (commands, process handling, summary) is plain Python; :class:`DemoNode` is the
thin ROS part (a client of the suite's topics and service), driven from the main thread.
"""

import argparse
import dataclasses
import math
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gsp_calibrator.run.directory import SUMMARY_FILE, TRUE_GEOMETRY_FILE, RunDirectory
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.settings import add_run_options, run_options_error
from gsp_calibrator.tools.demo_summary import (  # noqa: F401 (the demo's figures)
    FIT_KEYS,
    VALIDATION_KEYS,
    DemoSummary,
    collection_record,
    fit_record,
    parameter_error_maxima,
    summary_text,
    validation_details,
    validation_summary,
)
from gsp_calibrator.tools.processes import DemoError, NodeProcesses
from gsp_kinematics.geometry import default_geometry_path, load_geometry
from gsp_kinematics.kinematics import sample_valid_postures
from gsp_msgs_py.ros_environment import (
    DomainInUseError,
    enter_private_domain,
    foreign_nodes_in_child,
    loopback_environment,
)

#: The three nodes: executable (console script) and module (fallback: ``python -m``).
NODES = {
    'platform_sim': 'gsp_platform_sim.platform_sim_node',
    'device_driver': 'gsp_device_driver.device_driver_node',
    'calibrator': 'gsp_calibrator.calibrator_node',
    # --platform ros2_control: the bridge and the emulated controller replace platform_sim.
    'controller_sim': 'gsp_platform_sim.controller_sim_node',
    'platform_bridge': 'gsp_platform_bridge.platform_bridge_node',
    # --device serial: the emulated device on a pty feeds device_driver's serial backend.
    'gsp_fake_device': 'gsp_device_driver.fake_device_node',
}
#: Leg speeds of the emulated controller and of the bridge's trajectories (m/s): fast, so that
#: the ros2_control mode spends its time like the direct one, in settling and sampling.
EMULATED_LEG_SPEED = 5.0
BRIDGE_LEG_SPEED = 2.5


class Terminated(Exception):
    """SIGTERM arrived: stop the nodes and exit with 143."""


def _raise_terminated(signum, frame):
    raise Terminated()


# --- pure parts ----------------------------------------------------------------------------------


def ros_environment(environ=None, rng=None):
    """The nodes' environment: :func:`~gsp_msgs_py.ros_environment.loopback_environment` (a
    random domain unless one is set) with unbuffered output, so their logs are complete."""
    env = loopback_environment(environ, rng=rng)
    env['PYTHONUNBUFFERED'] = '1'
    return env


def executable_command(name, which=shutil.which):
    """argv prefix of node ``name``: its console script from PATH, else ``python -m <module>``."""
    path = which(name)
    if path:
        return [path]
    return [sys.executable, '-m', NODES[name]]


#: The calibrator's settle_timeout when the legs move at their limits: longer than any move.
MOVING_SETTLE_TIMEOUT_S = 60.0


def motion_parameters(args):
    """platform_sim's leg limits of ``--max-leg-speed`` / ``--max-leg-acceleration`` (0: none)."""
    speed = float(getattr(args, 'max_leg_speed', 0.0))
    acceleration = float(getattr(args, 'max_leg_acceleration', 0.0))
    return ['-p', f'max_leg_speed:={speed!r}', '-p', f'max_leg_acceleration:={acceleration!r}']


def calibrator_motion_parameters(args):
    """With leg limits, the calibrator plans its route with them and waits long enough for a
    move (``settle_timeout``); without, its defaults."""
    speed = float(getattr(args, 'max_leg_speed', 0.0))
    acceleration = float(getattr(args, 'max_leg_acceleration', 0.0))
    if not speed > 0:
        return []
    extra = [
        '-p',
        f'max_leg_speed:={speed!r}',
        '-p',
        f'settle_timeout:={MOVING_SETTLE_TIMEOUT_S!r}',
    ]
    if acceleration > 0:
        extra += ['-p', f'max_leg_acceleration:={acceleration!r}']
    return extra


def node_commands(args, output_root, which=shutil.which):
    """``{node name: argv}`` of the nodes for the parsed ``args``: platform_sim (or, with
    ``--platform ros2_control``, controller_sim and platform_bridge), device_driver (with
    ``--device serial``, its serial backend on ``args.device_port`` fed by gsp_fake_device) and
    the calibrator."""
    rate = float(args.sensor_rate)
    # The simulated noise is not seeded: a node restarted with a fixed seed would replay its
    # noise (node_tools.resolve_seed). ``--seed`` seeds the postures, as the calibrator's own.
    common = ['-p', f'publish_rate:={rate!r}']
    commands = {
        'platform_sim': executable_command('platform_sim', which)
        + [
            '--ros-args',
            '--params-file',
            str(args.nominal_geometry),
            '-p',
            f'true_geometry_file:={args.true_geometry}',
            '-p',
            f'settle_time:={float(args.settle_time)!r}',
            '-p',
            'publish_markers:=false',
            *motion_parameters(args),
            *common,
        ],
        'device_driver': executable_command('device_driver', which)
        + ['--ros-args', '-p', f'true_geometry_file:={args.true_geometry}', *common],
        'calibrator': executable_command('calibrator', which)
        + [
            '--ros-args',
            '-p',
            f'nominal_geometry_file:={args.nominal_geometry}',
            '-p',
            f'output_root:={output_root}',
            '-p',
            f'posture_count:={int(args.postures)}',
            '-p',
            f'pool_size:={max(int(args.pool_size), int(args.postures))}',
            '-p',
            f'samples_per_posture:={int(args.samples_per_posture)}',
            '-p',
            f'sync_tolerance:={0.5 / rate!r}',
            '-p',
            f'seed:={int(args.seed)}',
            '-p',
            f'formulation:={args.formulation}',
            '-p',
            f'free_parameters:=[{",".join(args.free)}]',
            '-p',
            'apply_result:=true',
            # On a truth the model describes exactly, the goodness-of-fit check still rejects 1
            # run in 100 (its significance level); the demo's validation against the true
            # platform is the stronger check, so it applies the result and prints the verdict.
            '-p',
            'apply_rejected_fit:=true',
            *calibrator_motion_parameters(args),
        ],
    }
    platform = getattr(args, 'platform', 'sim')
    device = getattr(args, 'device', 'sim')
    if platform == 'ros2_control':
        del commands['platform_sim']
        commands['controller_sim'] = executable_command('controller_sim', which) + [
            '--ros-args',
            '-p',
            f'true_geometry_file:={args.true_geometry}',
            '-p',
            f'max_leg_speed:={EMULATED_LEG_SPEED!r}',
            *common,
        ]
        commands['platform_bridge'] = executable_command('platform_bridge', which) + [
            '--ros-args',
            '--params-file',
            str(args.nominal_geometry),
            '-p',
            f'settle_time:={float(args.settle_time)!r}',
            '-p',
            f'max_leg_speed:={BRIDGE_LEG_SPEED!r}',
            '-p',
            'min_motion_duration:=0.02',
        ]
        commands['calibrator'] += ['-p', 'platform_node_name:=platform_bridge']
    if device == 'serial':
        commands['gsp_fake_device'] = executable_command('gsp_fake_device', which) + [
            '--port',
            str(args.device_port),
            '--rate',
            repr(rate),
            '--true-geometry',
            str(args.true_geometry),
        ]
        commands['device_driver'] = executable_command('device_driver', which) + [
            '--ros-args',
            '-p',
            'backend:=serial',
            '-p',
            f'serial.port:={args.device_port}',
            '-p',
            'serial.reconnect_interval:=0.1',
            '-p',
            f'publish_rate:={rate!r}',
        ]
    return commands


def parse_arguments(argv=None):
    parser = argparse.ArgumentParser(
        prog='gsp_demo', description='End-to-end calibration demo of the simulated platform.'
    )
    parser.add_argument(
        '--output-root', default='runs', help='root of the run directories (default: runs)'
    )
    parser.add_argument(
        '--true-geometry',
        default=default_geometry_path('true'),
        help='geometry of the simulated real platform (default: shipped true)',
    )
    parser.add_argument(
        '--nominal-geometry',
        default=default_geometry_path('nominal'),
        help='nominal geometry: controller start and identification start',
    )
    add_run_options(parser, seed_help='seed of the posture pool and the validation postures')
    parser.add_argument('--validation-postures', type=int, default=50, help='(50)')
    add = parser.add_argument
    add('--sensor-rate', type=float, default=200.0, help='leg-length and device rate, Hz (200)')
    add('--settle-time', type=float, default=0.02, help="platform_sim's settle time, s (0.02)")
    add('--timeout', type=float, default=120.0, help='longest calibration wait, s (120)')
    add(
        '--max-leg-speed',
        type=float,
        default=0.0,
        help="platform_sim's leg speed limit, m/s (0: none, the platform jumps)",
    )
    add(
        '--max-leg-acceleration',
        type=float,
        default=0.0,
        help="platform_sim's leg acceleration limit, m/s^2 (0: none)",
    )
    add('--startup-timeout', type=float, default=30.0, help='longest node start-up, s (30)')
    add(
        '--platform',
        default='sim',
        choices=('sim', 'ros2_control'),
        help='sim: platform_sim; ros2_control: platform_bridge + emulated controller (sim)',
    )
    add(
        '--device',
        default='sim',
        choices=('sim', 'serial'),
        help="sim: device_driver's sim backend; serial: gsp_fake_device on a pty (sim)",
    )
    args = parser.parse_args(argv)
    reason = run_options_error(args)
    if reason:
        parser.error(reason)
    if args.validation_postures < 1:
        parser.error('--validation-postures must be >= 1')
    if not args.sensor_rate > 0 or not args.settle_time >= 0:
        parser.error('--sensor-rate must be > 0 and --settle-time >= 0')
    if not (args.max_leg_speed >= 0 and args.max_leg_acceleration >= 0):
        parser.error('--max-leg-speed and --max-leg-acceleration must be >= 0 (0: no limit)')
    args.true_geometry = os.path.abspath(args.true_geometry)
    args.nominal_geometry = os.path.abspath(args.nominal_geometry)
    return args


@dataclasses.dataclass
class Measured:
    """What the demo measured through the nodes; ``error`` says why it stopped early ('' if not)."""

    run_directory: object = None  #: the calibration's RunDirectory once it has answered
    error: str = ''
    calibrated: object = None  #: the calibrated Geometry
    identification_ms: float = math.nan
    calibration_s: float = math.nan
    before: dict | None = None  #: validation summaries before and after
    after: dict | None = None
    details_before: dict | None = None  #: per-posture validation errors before and after
    details_after: dict | None = None
    validated: int = 0  #: validation postures reached both times
    rejected: int = 0  #: validation postures the platform rejected


def _calibrate_and_validate(demo, args, validation_poses, measured):
    """Validate with the nominal controller, calibrate, validate again, into ``measured`` (a
    :class:`Measured`, filled as the demo goes: an interrupt leaves what was measured)."""
    from gsp_kinematics.geometry import geometry_from_yaml

    try:
        demo.wait_for_system(args.startup_timeout)
        settle_timeout = 5.0 + 10.0 * args.settle_time
        if args.max_leg_speed > 0:
            settle_timeout += MOVING_SETTLE_TIMEOUT_S
        print(
            f'validation before calibration: {len(validation_poses)} postures (nominal '
            'controller) ...',
            flush=True,
        )
        reached_before = demo.run_postures(validation_poses, settle_timeout, args.startup_timeout)
        print('calibrating (/gsp/calibrator/calibrate) ...', flush=True)
        calibration_started = time.monotonic()
        response = demo.calibrate(args.timeout)
        measured.calibration_s = time.monotonic() - calibration_started
        parsed = parse_response(response.message)
        if parsed.run_directory:
            measured.run_directory = RunDirectory(parsed.run_directory)
        if not response.success:
            raise DemoError(f'calibration failed:\n{parsed.summary}')
        print(parsed.summary, flush=True)
        measured.identification_ms = parsed.identification_ms
        measured.calibrated = geometry_from_yaml(parsed.geometry_yaml, source='calibrate response')
        print(f'validation after calibration: {len(validation_poses)} postures ...', flush=True)
        reached_after = demo.run_postures(validation_poses, settle_timeout, args.startup_timeout)
    except DemoError as error:
        measured.error = str(error)
        return
    both = np.all(np.isfinite(reached_before), axis=1) & np.all(np.isfinite(reached_after), axis=1)
    if not both.any():
        measured.error = 'every validation posture was rejected by the platform'
        return
    measured.before = validation_summary(validation_poses[both], reached_before[both])
    measured.after = validation_summary(validation_poses[both], reached_after[both])
    measured.details_before = validation_details(validation_poses[both], reached_before[both])
    measured.details_after = validation_details(validation_poses[both], reached_after[both])
    measured.validated, measured.rejected = int(both.sum()), int((~both).sum())


def _shut_down(executor, node, context, processes, run_directory, log_directory, exit_code):
    """Stop the demo's node and the suite's processes, keep their logs; the exit code (1 when a
    process could not be stopped). Nothing interrupts it (it is bounded: SIGINT, SIGTERM,
    SIGKILL)."""
    import rclpy

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
        print(f"gsp_demo: the nodes' logs are in {log_directory}", file=sys.stderr)
    return exit_code


def run(args):
    """The demo; returns the exit code."""
    started = time.monotonic()
    true_geometry = load_geometry(args.true_geometry)
    nominal = load_geometry(args.nominal_geometry)
    output_root = os.path.abspath(args.output_root)
    try:
        # A domain of the demo's own (claimed by lock, or the given one checked), probed for
        # nodes by a child: this process forks its nodes before it starts DDS threads itself.
        enter_private_domain(probe=foreign_nodes_in_child)
    except DomainInUseError as error:
        print(f'gsp_demo: {error}', file=sys.stderr, flush=True)
        return 1
    env = ros_environment()
    print(
        f'gsp_demo: ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]} (loopback only), output under '
        f'{output_root}',
        flush=True,
    )
    validation_poses = sample_valid_postures(
        nominal, args.validation_postures, np.random.default_rng(args.seed + 1_000_003)
    )

    log_directory = Path(tempfile.mkdtemp(prefix='gsp_demo_logs_'))
    args.device_port = str(log_directory / 'gsp_device')  # the pty link of --device serial
    processes = NodeProcesses(node_commands(args, output_root), env, log_directory)
    # The children first, before rclpy starts its middleware threads (preexec_fn runs between
    # fork and exec).
    processes.start()
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    context = node = executor = None
    measured = Measured()
    exit_code = 1
    try:
        context = rclpy.Context()
        # Ctrl-C (KeyboardInterrupt) and SIGTERM (Terminated) reach this thread; the finally
        # below stops the nodes.
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
        from gsp_calibrator.tools import demo_node  # rclpy only after the environment is set

        node = demo_node.DemoNode(context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        demo = demo_node.Demo(node, executor, processes)
        print(f'starting {", ".join(processes.commands)} ...', flush=True)
        _calibrate_and_validate(demo, args, validation_poses, measured)
        if measured.error:
            raise DemoError(measured.error)
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
        run_directory = measured.run_directory
        exit_code = _shut_down(
            executor, node, context, processes, run_directory, log_directory, exit_code
        )

    if exit_code != 0:
        if run_directory is not None:
            print(f'run directory: {run_directory.path}', flush=True)
        return exit_code
    summary = DemoSummary(
        measured.before,
        measured.after,
        measured.calibrated,
        true_geometry,
        measured.identification_ms,
        measured.calibration_s,
        time.monotonic() - started,
        run_directory.path,
        collection_record(run_directory.path),
        fit_record(run_directory.path),
    ).document()
    run_directory.write_text(TRUE_GEOMETRY_FILE, Path(args.true_geometry).read_text())
    run_directory.write_json(SUMMARY_FILE, summary)
    try:  # the calibrator's report, now against the truth and with the validation distributions
        from gsp_calibrator.tools import reidentify as offline

        offline.refresh_report(
            run_directory.path,
            truth=true_geometry,
            validation_before=measured.details_before,
            validation_after=measured.details_after,
        )
    except Exception as error:  # noqa: BLE001 (the demo itself succeeded)
        print(f'gsp_demo: report not refreshed: {error}', file=sys.stderr, flush=True)
    print(summary_text(summary, measured.validated, measured.rejected), flush=True)
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
