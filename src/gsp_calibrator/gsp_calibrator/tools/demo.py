"""``gsp_demo``: the main job. A whole calibration of the simulated platform, end to end.
See docs/nodes.md#gsp_demo."""

import argparse
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gsp_calibrator.files.run_directory import SUMMARY_FILE, TRUE_GEOMETRY_FILE, RunDirectory
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.settings import (
    DEFAULTS,
    PARAMETER_SPECS,
    add_run_options,
    run_options_error,
)
from gsp_calibrator.tools import demo_commands, demo_summary
from gsp_calibrator.tools.processes import DemoError, NodeProcesses
from gsp_kinematics.estimation.noise_from_data import NOISE_SOURCES
from gsp_kinematics.model import motion
from gsp_kinematics.model.effects import PRESETS
from gsp_kinematics.model.geometry import default_geometry_path, geometry_from_yaml, load_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_msgs_py import ros_environment

#: ``--timeout`` (s) by backend: the physics' servos move 60 postures in ~15 min.
CALIBRATION_TIMEOUT_S = {'kinematic': 120.0, 'physics': 3600.0}


class Terminated(Exception):
    """SIGTERM arrived: stop the nodes and exit with 143."""


def _raise_terminated(signum, frame):
    raise Terminated()


def parse_arguments(argv=None):
    parser = argparse.ArgumentParser(
        prog='gsp_demo', description='End-to-end calibration demo of the simulated platform.'
    )
    add = parser.add_argument
    add('--output-root', default='runs', help='root of the run directories (default: runs)')
    add(
        '--true-geometry',
        default=default_geometry_path('true'),
        help='geometry of the simulated real platform (default: shipped true)',
    )
    add(
        '--nominal-geometry',
        default=default_geometry_path('nominal'),
        help='nominal geometry: controller start and identification start',
    )
    add_run_options(parser, seed_help='seed of the posture pool and the validation postures')
    add('--validation-postures', type=int, default=50, help='(50)')
    add(
        '--noise-source',
        choices=NOISE_SOURCES,
        default=DEFAULTS['noise_source'],
        help="the calibrator's noise_source: the weights from the noise estimated from the run "
        f'or from its configured sigma_* ({DEFAULTS["noise_source"]})',
    )
    add(
        '--sensor-rate',
        type=float,
        default=motion.DEFAULT_SENSOR_RATE_HZ,
        help=f'leg-length and device rate, Hz ({motion.DEFAULT_SENSOR_RATE_HZ:g})',
    )
    add('--settle-time', type=float, default=0.02, help="platform_sim's settle time, s (0.02)")
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
    add(
        '--sensor-dynamics',
        default='none',
        choices=tuple(demo_commands.SENSOR_DYNAMICS),
        help='none: an instant device with white noise; realistic: response and noise '
        "correlation times of typical parts, and the calibrator's rest look-back to match "
        '(docs/sensor_errors.md) (none)',
    )
    add(
        '--platform-effects',
        default='none',
        choices=tuple(PRESETS),
        help="platform_sim's real platform: none, rigid and ideal; realistic: 40 kg on 30 N/um "
        'legs, 4 um backlash, legs warming 1.5 K within 15 min, base joint axes 20 um apart '
        '(docs/platform_effects.md) (none)',
    )
    add('--startup-timeout', type=float, default=30.0, help='longest node start-up, s (30)')
    add(
        '--platform',
        default='sim',
        choices=('sim', 'ros2_control'),
        help='sim: platform_sim; ros2_control: platform_bridge + emulated controller (sim)',
    )
    _add_backend_option(add)
    add(
        '--device',
        default='sim',
        choices=('sim', 'serial'),
        help="sim: device_driver's sim backend; serial: gsp_fake_device on a pty (sim)",
    )
    _add_calibrator_param_option(add)
    args = parser.parse_args(argv)
    _check_arguments(parser, args)
    return args


def _add_calibrator_param_option(add):
    add(
        '--calibrator-param',
        action='append',
        default=[],
        metavar='NAME:=VALUE',
        help="one of the calibrator's parameters (docs/parameters.md#calibrator), as ros2 run's "
        "'-p NAME:=VALUE', after the demo's own (repeatable; e.g. rest_sigmas:=.inf turns the "
        'rest rule off)',
    )


def _add_backend_option(add):
    add(
        '--backend',
        default='kinematic',
        choices=('kinematic', 'physics'),
        help="platform_sim's backend: kinematic (fast) or physics (MuJoCo, the realistic preset "
        f"{demo_commands.PHYSICS_PRESET}, with device_driver's physics backend; the legs' "
        'realistic limits unless given) (docs/physics.md) (kinematic)',
    )
    add(
        '--real-time-factor',
        type=float,
        default=1.0,
        help="--backend physics: platform_sim's real_time_factor (the simulation as the clock, "
        'this many times faster than wall time; the other nodes on its /clock) (1)',
    )
    add(
        '--timeout',
        type=float,
        help='longest calibration wait, s ('
        + ', '.join(f'{backend}: {s:g}' for backend, s in CALIBRATION_TIMEOUT_S.items())
        + ')',
    )


def _check_arguments(parser, args):
    """Exit through ``parser.error`` naming the first bad argument; make the paths absolute."""
    reason = run_options_error(args)
    if reason:
        parser.error(reason)
    if args.validation_postures < 1:
        parser.error('--validation-postures must be >= 1')
    if not args.sensor_rate > 0 or not args.settle_time >= 0:
        parser.error('--sensor-rate must be > 0 and --settle-time >= 0')
    if args.platform_effects != 'none' and args.platform != 'sim':
        parser.error('--platform-effects needs --platform sim (controller_sim has no effects)')
    if not (args.max_leg_speed >= 0 and args.max_leg_acceleration >= 0):
        parser.error('--max-leg-speed and --max-leg-acceleration must be >= 0 (0: no limit)')
    if args.backend == 'physics':
        if args.platform != 'sim' or args.device != 'sim' or args.platform_effects != 'none':
            parser.error(
                '--backend physics needs --platform sim, --device sim and no --platform-effects'
            )
        if not args.real_time_factor > 0:
            parser.error('--real-time-factor must be > 0')
        # A servo does not jump: the realistic leg limits, known to the calibrator's plan.
        args.max_leg_speed = args.max_leg_speed or motion.REALISTIC_MAX_SPEED
        args.max_leg_acceleration = args.max_leg_acceleration or motion.REALISTIC_MAX_ACCELERATION
    for assignment in args.calibrator_param:
        name, separator, _ = assignment.partition(':=')
        if not separator or name not in PARAMETER_SPECS:
            parser.error(
                f'--calibrator-param {assignment!r}: give NAME:=VALUE with NAME one of the '
                "calibrator's parameters (docs/parameters.md#calibrator)"
            )
    if args.timeout is None:
        args.timeout = CALIBRATION_TIMEOUT_S[args.backend]
    args.true_geometry = os.path.abspath(args.true_geometry)
    args.nominal_geometry = os.path.abspath(args.nominal_geometry)


def _calibrate_and_validate(demo, args, validation_poses, measured):
    """Validate with the nominal controller, calibrate, validate again, into ``measured`` (a
    ``demo_summary.Measured``, filled as the demo goes: an interrupt leaves what was measured)."""
    demo.wait_for_system(args.startup_timeout)
    settle_timeout = 5.0 + 10.0 * args.settle_time
    if args.max_leg_speed > 0:
        settle_timeout += demo_commands.MOVING_SETTLE_TIMEOUT_S
    print(
        f'validation before calibration: {len(validation_poses)} postures (nominal controller) ...',
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
    both = np.all(np.isfinite(reached_before), axis=1) & np.all(np.isfinite(reached_after), axis=1)
    if not both.any():
        raise DemoError('every validation posture was rejected by the platform')
    measured.before = demo_summary.validation_details(validation_poses[both], reached_before[both])
    measured.after = demo_summary.validation_details(validation_poses[both], reached_after[both])


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
        for log in log_directory.glob('*.log'):  # the nodes' (NodeProcesses)
            run_directory.write_bytes(log.name, log.read_bytes())
        shutil.rmtree(log_directory, ignore_errors=True)
    else:
        print(f"gsp_demo: the nodes' logs are in {log_directory}", file=sys.stderr)
    return exit_code


def _run_nodes(args, validation_poses, processes, log_directory, measured):
    """Start the nodes, validate, calibrate and validate again into ``measured``; stop the nodes
    whatever happens. The exit code so far (0, 1, 130 interrupted, 143 terminated)."""
    # The children first, before rclpy starts its middleware threads (preexec_fn runs between
    # fork and exec).
    processes.start()
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    context = node = executor = None
    exit_code = 1
    try:
        context = rclpy.Context()
        # Ctrl-C (KeyboardInterrupt) and SIGTERM (Terminated) reach this thread; the finally
        # below stops the nodes.
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
        from gsp_calibrator.tools import demo_node  # rclpy only after the environment is set

        sim_time = demo_commands.uses_sim_time(args)
        node = demo_node.DemoNode(processes, sim_time=sim_time, context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        print(f'starting {", ".join(processes.commands)} ...', flush=True)
        _calibrate_and_validate(node, args, validation_poses, measured)
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
        exit_code = _shut_down(
            executor, node, context, processes, measured.run_directory, log_directory, exit_code
        )
    return exit_code


def _write_results(args, measured, true_geometry, elapsed_s):
    """Write the truth and ``summary.json`` into the run directory, refresh its report against
    the truth and print the summary; ``elapsed_s``: the demo's duration so far (s)."""
    run_directory = measured.run_directory
    summary = demo_summary.summary_document(
        measured, true_geometry, elapsed_s, demo_summary.result_record(run_directory.path)
    )
    run_directory.write_text(TRUE_GEOMETRY_FILE, Path(args.true_geometry).read_text())
    run_directory.write_json(SUMMARY_FILE, summary)
    try:  # the calibrator's report, now against the truth and with the validation distributions
        from gsp_calibrator.tools.reidentify import refresh_report

        refresh_report(
            run_directory.path,
            truth=true_geometry,
            validation_before=measured.before,
            validation_after=measured.after,
        )
    except Exception as error:  # noqa: BLE001 (the demo itself succeeded)
        print(f'gsp_demo: report not refreshed: {error}', file=sys.stderr, flush=True)
    validated = measured.before['postures']  # reached both times; the others were rejected
    rejected = args.validation_postures - validated
    print(demo_summary.summary_text(summary, validated, rejected), flush=True)
    print(f'run directory: {run_directory.path}', flush=True)


def run(args):
    """The demo; returns the exit code."""
    started = time.monotonic()
    true_geometry = load_geometry(args.true_geometry)
    nominal = load_geometry(args.nominal_geometry)
    output_root = os.path.abspath(args.output_root)
    try:
        # A domain of the demo's own (claimed, or the given one checked), probed for
        # nodes by a child: this process forks its nodes before it starts DDS threads itself.
        ros_environment.enter_private_domain(probe=ros_environment.foreign_nodes_in_child)
    except ros_environment.DomainInUseError as error:
        print(f'gsp_demo: {error}', file=sys.stderr, flush=True)
        return 1
    env = demo_commands.ros_environment()
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
    processes = NodeProcesses(demo_commands.node_commands(args, output_root), env, log_directory)
    measured = demo_summary.Measured()
    exit_code = _run_nodes(args, validation_poses, processes, log_directory, measured)
    if exit_code != 0:
        if measured.run_directory is not None:
            print(f'run directory: {measured.run_directory.path}', flush=True)
        return exit_code
    _write_results(args, measured, true_geometry, time.monotonic() - started)
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
