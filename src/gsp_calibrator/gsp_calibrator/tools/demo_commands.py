"""The command lines of ``gsp_demo``'s nodes, and their environment (pure, no rclpy)."""

import os
import shutil
import sys

from gsp_kinematics.fileio import yaml_float
from gsp_kinematics.model.effects import PRESETS
from gsp_msgs_py.ros_environment import loopback_environment

#: The three nodes: executable (console script) and module (fallback: ``python -m``).
NODES = {
    'platform_sim': 'gsp_platform_sim.platform_sim_node',
    'device_driver': 'gsp_device_driver.device_driver_node',
    'calibrator': 'gsp_calibrator.node.calibrator_node',
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
#: ``--backend physics``: platform_sim's realistic preset (gsp_platform_sim/config).
PHYSICS_PRESET = 'physics_realistic.yaml'
#: The demo's wait for a validation posture when the legs move at their limits (s).
MOVING_SETTLE_TIMEOUT_S = 60.0

#: ``gsp_demo --sensor-dynamics``: the simulated device's response and noise correlation
#: times (s) per sensor (docs/sensor_errors.md: typical values of real parts). The calibrator
#: keeps its default rest look-back (0.25 s: five times the realistic inclinometer's 0.05 s).
SENSOR_DYNAMICS = {
    'none': {'device': {}},
    'realistic': {
        'device': {
            'inclinometer_response_time': 0.05,
            'inclinometer_noise_correlation_time': 0.05,
            'encoder_response_time': 0.0,
            'encoder_noise_correlation_time': 0.0,
            'lvdt_response_time': 0.001,
            'lvdt_noise_correlation_time': 0.001,
        },
    },
}


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


def physics_preset_path():
    """The installed :data:`PHYSICS_PRESET` (gsp_platform_sim's share directory)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        share = get_package_share_directory('gsp_platform_sim')
    except (ImportError, LookupError, ValueError, OSError):  # not in an ament index
        share = os.path.join(sys.prefix, 'share', 'gsp_platform_sim')
    return os.path.join(share, 'config', PHYSICS_PRESET)


def _parameter_text(value):
    """A ``-p`` value: floats with a decimal point (``4e-06`` would not read as a double)."""
    if isinstance(value, list):
        return '[' + ', '.join(_parameter_text(item) for item in value) + ']'
    if isinstance(value, bool):
        return str(value).lower()
    return yaml_float(value) if isinstance(value, float) else str(value)


def ros_command(name, which, parameters, params_files=()):
    """argv of node ``name``: its :func:`executable_command`, ``--params-file`` of each of
    ``params_files`` and ``-p name:=value`` of each of ``parameters``."""
    files = [a for path in params_files for a in ('--params-file', str(path))]
    values = [a for key, v in parameters.items() for a in ('-p', f'{key}:={_parameter_text(v)}')]
    return [*executable_command(name, which), '--ros-args', *files, *values]


def _calibrator_parameters(args, output_root, sim_time):
    """The calibrator's parameters: the run of ``args``, applied to the platform."""
    parameters = {
        'nominal_geometry_file': args.nominal_geometry,
        'output_root': output_root,
        'posture_count': args.posture_count,
        'pool_size': max(args.pool_size, args.posture_count),
        'workspace_postures': args.workspace_postures,
        'pairs_per_posture': args.pairs_per_posture,
        'sync_tolerance': 0.5 / float(args.sensor_rate),
        'seed': args.seed,
        'formulation': args.formulation,
        'noise_source': args.noise_source,
        'free_parameters': list(args.free_parameters),
        'apply_result': True,
        # The demo redraws the report against the truth once it has validated (its
        # refresh_report): plots drawn by the calibrator would only be overwritten.
        'write_report_plots': False,
        **sim_time,
    }
    # With leg limits, the calibrator plans its route with them (and waits for each move as
    # planned with them).
    if args.max_leg_speed > 0:
        parameters['max_leg_speed'] = float(args.max_leg_speed)
        if args.max_leg_acceleration > 0:
            parameters['max_leg_acceleration'] = float(args.max_leg_acceleration)
    # With --platform-effects, the payload the simulated legs carry (what a user knows of the
    # load), so that --free auto can try the compliance.
    effects = PRESETS[args.platform_effects]
    if args.platform_effects != 'none' and effects.payload_mass > 0:
        parameters['payload_mass'] = float(effects.payload_mass)
        parameters['payload_centre_of_mass'] = [float(v) for v in effects.centre_of_mass]
    if args.platform == 'ros2_control':
        parameters['platform_node_name'] = 'platform_bridge'
    return parameters


def uses_sim_time(args):
    """Whether the nodes run on platform_sim's /clock: its physics is the clock (``--backend
    physics`` at a ``--real-time-factor`` other than 1, docs/physics.md)."""
    return args.backend == 'physics' and args.real_time_factor != 1.0


def node_commands(args, output_root, which=shutil.which):
    """``{node name: argv}`` of the nodes for the parsed ``args``: platform_sim (or, with
    ``--platform ros2_control``, controller_sim and platform_bridge), device_driver (with
    ``--device serial``, its serial backend on ``args.device_port`` fed by gsp_fake_device) and
    the calibrator."""
    rate = float(args.sensor_rate)
    physics = args.backend == 'physics'
    truth = {'true_geometry_file': args.true_geometry}
    # The nodes other than platform_sim on its /clock when its physics is the clock
    # (--real-time-factor other than 1, docs/physics.md).
    sim_time = {'use_sim_time': True} if uses_sim_time(args) else {}
    # The simulated noise is not seeded: a node restarted with a fixed seed would replay its
    # noise (parameter_specs.resolve_seed). ``--seed`` seeds the postures, as the calibrator's own.
    platform = {
        **({'real_time_factor': float(args.real_time_factor)} if physics else {}),
        **truth,
        'settle_time': float(args.settle_time),
        'publish_markers': False,
        'max_leg_speed': float(args.max_leg_speed),
        'max_leg_acceleration': float(args.max_leg_acceleration),
    }
    if args.platform_effects != 'none':  # docs/platform_effects.md; none: a rigid ideal platform
        platform.update(PRESETS[args.platform_effects].to_parameters('effects.'))
    device = {
        **truth,
        **({'backend': 'physics', **sim_time} if physics else {}),
        **SENSOR_DYNAMICS[args.sensor_dynamics]['device'],
    }
    platform_files = [args.nominal_geometry, *([physics_preset_path()] if physics else [])]
    commands = {
        'platform_sim': ros_command(
            'platform_sim', which, {**platform, 'publish_rate': rate}, platform_files
        ),
        'device_driver': ros_command('device_driver', which, {**device, 'publish_rate': rate}),
        'calibrator': ros_command(
            'calibrator', which, _calibrator_parameters(args, output_root, sim_time)
        ),
    }
    # The user's calibrator parameters last: ROS takes the last '-p' of a name.
    commands['calibrator'] += [a for given in args.calibrator_param for a in ('-p', given)]
    if args.platform == 'ros2_control':
        del commands['platform_sim']
        controller = {**truth, 'max_leg_speed': EMULATED_LEG_SPEED, 'publish_rate': rate}
        commands['controller_sim'] = ros_command('controller_sim', which, controller)
        bridge = {
            'settle_time': float(args.settle_time),
            'max_leg_speed': BRIDGE_LEG_SPEED,
            'min_motion_duration': 0.02,
        }
        commands['platform_bridge'] = ros_command(
            'platform_bridge', which, bridge, [args.nominal_geometry]
        )
    if args.device == 'serial':
        commands.update(_serial_device_commands(args, rate, which))
    return commands


def _serial_device_commands(args, rate, which):
    """``--device serial``: gsp_fake_device on the pty, device_driver's serial backend on it."""
    dynamics = SENSOR_DYNAMICS[args.sensor_dynamics]['device']
    return {
        'gsp_fake_device': executable_command('gsp_fake_device', which)
        + ['--port', str(args.device_port), '--rate', repr(rate)]
        + ['--true-geometry', str(args.true_geometry)]
        + [a for name, v in dynamics.items() for a in (f'--{name.replace("_", "-")}', repr(v))],
        'device_driver': ros_command(
            'device_driver',
            which,
            {
                'backend': 'serial',
                'serial.port': args.device_port,
                'serial.reconnect_interval': 0.1,
                'publish_rate': rate,
            },
        ),
    }
