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


#: ``--backend physics``: platform_sim's realistic preset (gsp_platform_sim/config).
PHYSICS_PRESET = 'physics_realistic.yaml'


def physics_preset_path():
    """The installed :data:`PHYSICS_PRESET` (gsp_platform_sim's share directory)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        share = get_package_share_directory('gsp_platform_sim')
    except (ImportError, LookupError, ValueError, OSError):  # not in an ament index
        share = os.path.join(sys.prefix, 'share', 'gsp_platform_sim')
    return os.path.join(share, 'config', PHYSICS_PRESET)


def backend_parameters(args):
    """platform_sim's and device_driver's arguments of ``--backend`` (kinematic: none) and
    ``--real-time-factor``."""
    if getattr(args, 'backend', 'kinematic') != 'physics':
        return [], []
    factor = float(getattr(args, 'real_time_factor', 1.0))
    return (
        ['--params-file', physics_preset_path(), '-p', f'real_time_factor:={factor!r}'],
        ['-p', 'backend:=physics', *sim_time_parameters(args)],
    )


def sim_time_parameters(args):
    """``use_sim_time`` for the nodes other than platform_sim when its physics is the clock
    (``--real-time-factor`` other than 1, docs/physics.md); else none."""
    physics = getattr(args, 'backend', 'kinematic') == 'physics'
    if physics and float(getattr(args, 'real_time_factor', 1.0)) != 1.0:
        return ['-p', 'use_sim_time:=true']
    return []


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


def _dynamics(args):
    return SENSOR_DYNAMICS[getattr(args, 'sensor_dynamics', 'none')]


def device_dynamics_parameters(args):
    """The device's ``-p`` arguments of ``args.sensor_dynamics`` (none: the defaults)."""
    return [
        a for name, value in _dynamics(args)['device'].items() for a in ('-p', f'{name}:={value!r}')
    ]


def motion_parameters(args):
    """platform_sim's leg limits of ``--max-leg-speed`` / ``--max-leg-acceleration`` (0: none)."""
    speed = float(getattr(args, 'max_leg_speed', 0.0))
    acceleration = float(getattr(args, 'max_leg_acceleration', 0.0))
    return ['-p', f'max_leg_speed:={speed!r}', '-p', f'max_leg_acceleration:={acceleration!r}']


def _parameter_text(value):
    """A ``-p`` value: floats with a decimal point (``4e-06`` would not read as a double)."""
    if isinstance(value, list):
        return '[' + ', '.join(_parameter_text(item) for item in value) + ']'
    return yaml_float(value)


def platform_effect_parameters(args):
    """platform_sim's ``effects.*`` of ``--platform-effects`` (docs/platform_effects.md; none:
    the defaults, a rigid ideal platform)."""
    name = getattr(args, 'platform_effects', 'none')
    if name == 'none':
        return []
    values = PRESETS[name].to_parameters('effects.')
    return [a for key, value in values.items() for a in ('-p', f'{key}:={_parameter_text(value)}')]


def calibrator_payload_parameters(args):
    """With ``--platform-effects``, the calibrator is told the payload the simulated legs carry
    (its ``payload_mass`` and ``payload_centre_of_mass``: what a user knows of the load), so
    that ``--free auto`` can try the compliance; without, its defaults (unknown)."""
    name = getattr(args, 'platform_effects', 'none')
    if name == 'none' or not PRESETS[name].payload_mass > 0:
        return []
    effects = PRESETS[name]
    centre = ','.join(repr(float(v)) for v in effects.centre_of_mass)
    return [
        '-p',
        f'payload_mass:={float(effects.payload_mass)!r}',
        '-p',
        f'payload_centre_of_mass:=[{centre}]',
    ]


def calibrator_motion_parameters(args):
    """With leg limits, the calibrator plans its route with them (and waits for each move as
    planned with them); without, its defaults."""
    speed = float(getattr(args, 'max_leg_speed', 0.0))
    acceleration = float(getattr(args, 'max_leg_acceleration', 0.0))
    if not speed > 0:
        return []
    extra = [
        '-p',
        f'max_leg_speed:={speed!r}',
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
    platform_backend, device_backend = backend_parameters(args)
    # The simulated noise is not seeded: a node restarted with a fixed seed would replay its
    # noise (parameter_specs.resolve_seed). ``--seed`` seeds the postures, as the calibrator's own.
    common = ['-p', f'publish_rate:={rate!r}']
    commands = {
        'platform_sim': executable_command('platform_sim', which)
        + [
            '--ros-args',
            '--params-file',
            str(args.nominal_geometry),
            *platform_backend,
            '-p',
            f'true_geometry_file:={args.true_geometry}',
            '-p',
            f'settle_time:={float(args.settle_time)!r}',
            '-p',
            'publish_markers:=false',
            *motion_parameters(args),
            *platform_effect_parameters(args),
            *common,
        ],
        'device_driver': executable_command('device_driver', which)
        + [
            '--ros-args',
            '-p',
            f'true_geometry_file:={args.true_geometry}',
            *device_backend,
            *device_dynamics_parameters(args),
            *common,
        ],
        'calibrator': executable_command('calibrator', which)
        + ['--ros-args', *_calibrator_parameters(args, output_root, rate)],
    }
    if getattr(args, 'platform', 'sim') == 'ros2_control':
        del commands['platform_sim']
        commands.update(_ros2_control_commands(args, common, which))
        commands['calibrator'] += ['-p', 'platform_node_name:=platform_bridge']
    if getattr(args, 'device', 'sim') == 'serial':
        commands.update(_serial_device_commands(args, rate, which))
    return commands


def _calibrator_parameters(args, output_root, rate):
    """The calibrator's ``-p`` arguments: the run of ``args``, applied to the platform."""
    return [
        '-p',
        f'nominal_geometry_file:={args.nominal_geometry}',
        '-p',
        f'output_root:={output_root}',
        '-p',
        f'posture_count:={int(args.posture_count)}',
        '-p',
        f'pool_size:={max(int(args.pool_size), int(args.posture_count))}',
        '-p',
        f'workspace_postures:={int(getattr(args, "workspace_postures", 0))}',
        '-p',
        f'pairs_per_posture:={int(args.pairs_per_posture)}',
        '-p',
        f'sync_tolerance:={0.5 / rate!r}',
        '-p',
        f'seed:={int(args.seed)}',
        '-p',
        f'formulation:={args.formulation}',
        '-p',
        f'noise_source:={args.noise_source}',
        '-p',
        f'free_parameters:=[{",".join(args.free_parameters)}]',
        '-p',
        'apply_result:=true',
        # The demo redraws the report against the truth once it has validated (its
        # refresh_report): plots drawn by the calibrator would only be overwritten.
        '-p',
        'write_report_plots:=false',
        *calibrator_motion_parameters(args),
        *calibrator_payload_parameters(args),
        *sim_time_parameters(args),
        # Last: a later '-p' of the same name wins.
        *(a for assignment in getattr(args, 'calibrator_param', ()) for a in ('-p', assignment)),
    ]


def _ros2_control_commands(args, common, which):
    """``--platform ros2_control``: the emulated controller and the bridge."""
    return {
        'controller_sim': executable_command('controller_sim', which)
        + [
            '--ros-args',
            '-p',
            f'true_geometry_file:={args.true_geometry}',
            '-p',
            f'max_leg_speed:={EMULATED_LEG_SPEED!r}',
            *common,
        ],
        'platform_bridge': executable_command('platform_bridge', which)
        + [
            '--ros-args',
            '--params-file',
            str(args.nominal_geometry),
            '-p',
            f'settle_time:={float(args.settle_time)!r}',
            '-p',
            f'max_leg_speed:={BRIDGE_LEG_SPEED!r}',
            '-p',
            'min_motion_duration:=0.02',
        ],
    }


def _serial_device_commands(args, rate, which):
    """``--device serial``: gsp_fake_device on the pty, device_driver's serial backend on it."""
    return {
        'gsp_fake_device': executable_command('gsp_fake_device', which)
        + [
            '--port',
            str(args.device_port),
            '--rate',
            repr(rate),
            '--true-geometry',
            str(args.true_geometry),
            *[
                a
                for name, value in _dynamics(args)['device'].items()
                for a in (f'--{name.replace("_", "-")}', repr(value))
            ],
        ],
        'device_driver': executable_command('device_driver', which)
        + [
            '--ros-args',
            '-p',
            'backend:=serial',
            '-p',
            f'serial.port:={args.device_port}',
            '-p',
            'serial.reconnect_interval:=0.1',
            '-p',
            f'publish_rate:={rate!r}',
        ],
    }
