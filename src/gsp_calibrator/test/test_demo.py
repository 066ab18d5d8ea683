"""The main job's plain parts: environment, node commands, summaries, child processes."""

import json
import math
import random
import signal
import sys

import numpy as np
import pytest
from gsp_testing import wait_until

from gsp_calibrator.files.run_directory import RunDirectory
from gsp_calibrator.report.data import VALIDATION_KEYS
from gsp_calibrator.settings import DEFAULTS
from gsp_calibrator.tools import demo, demo_commands, demo_summary
from gsp_calibrator.tools.processes import NodeProcesses
from gsp_kinematics.model.effects import PRESETS
from gsp_kinematics.model.geometry import default_geometry


def test_ros_environment_is_loopback_with_a_domain():
    env = demo_commands.ros_environment({'PATH': '/bin'}, rng=random.Random(1))
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 1 <= int(env['ROS_DOMAIN_ID']) <= 101 and env['PATH'] == '/bin'
    kept = demo_commands.ros_environment(
        {'ROS_DOMAIN_ID': '42', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
    )
    assert kept['ROS_DOMAIN_ID'] == '42' and kept['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert kept['PYTHONUNBUFFERED'] == '1'


def test_node_commands(tmp_path):
    args = demo.parse_arguments(['--postures', '30', '--seed', '3', '--sensor-rate', '100'])
    found = demo_commands.node_commands(args, str(tmp_path), which=lambda name: f'/opt/bin/{name}')
    assert set(found) == {'platform_sim', 'device_driver', 'calibrator'}
    platform = found['platform_sim']
    assert platform[:2] == ['/opt/bin/platform_sim', '--ros-args']
    assert f'true_geometry_file:={args.true_geometry}' in platform
    assert platform[platform.index('--params-file') + 1] == args.nominal_geometry
    assert 'publish_rate:=100.0' in platform
    assert f'true_geometry_file:={args.true_geometry}' in found['device_driver']
    # --seed seeds the postures; the simulated noise is fresh at each start of a node, so a
    # restarted node does not replay it.
    assert 'seed:=3' in found['calibrator']
    assert not any(arg.startswith('seed:=') for arg in platform + found['device_driver'])
    calibrator = found['calibrator']
    for value in (
        f'output_root:={tmp_path}',
        'posture_count:=30',
        'apply_result:=true',
        f'nominal_geometry_file:={args.nominal_geometry}',
        'sync_tolerance:=0.005',
    ):
        assert value in calibrator
    missing = demo_commands.node_commands(args, str(tmp_path), which=lambda name: None)
    assert missing['calibrator'][:3] == [
        sys.executable,
        '-m',
        'gsp_calibrator.node.calibrator_node',
    ]


def test_the_realistic_device_preset_sets_the_device_and_the_default_settle_look_back_fits_it(
    tmp_path,
):
    preset = demo_commands.SENSOR_DYNAMICS['realistic']
    for device in ('sim', 'serial'):
        args = demo.parse_arguments(['--sensor-dynamics', 'realistic', '--device', device])
        args.device_port = str(tmp_path / 'gsp_device')  # as the demo sets it
        found = demo_commands.node_commands(args, str(tmp_path), which=lambda name: name)
        source = found['gsp_fake_device' if device == 'serial' else 'device_driver']
        for name, value in preset['device'].items():
            expected = (
                [f'--{name.replace("_", "-")}', repr(value)]
                if device == 'serial'
                else [f'{name}:={value!r}']
            )
            assert all(arg in source for arg in expected), (name, source)
        # The calibrator's default look-back (5 tau of this inclinometer) is the preset's.
        assert not any('rest_lookback' in arg for arg in found['calibrator'])
    assert DEFAULTS['rest_lookback'] >= 5 * preset['device']['inclinometer_response_time']
    plain = demo_commands.node_commands(demo.parse_arguments([]), str(tmp_path), lambda n: n)
    assert not any('response_time' in arg for arg in plain['device_driver'])
    assert not any('rest_lookback' in arg for arg in plain['calibrator'])


def test_the_realistic_platform_preset_sets_platform_sim_effects(tmp_path):
    preset = PRESETS['realistic'].to_parameters('effects.')
    args = demo.parse_arguments(['--platform-effects', 'realistic'])
    platform = demo_commands.node_commands(args, str(tmp_path), lambda n: n)['platform_sim']
    given = dict(arg.split(':=', 1) for arg in platform if arg.startswith('effects.'))
    assert set(given) == set(preset)
    for name, value in preset.items():
        text = given[name]
        # A double (or double array) to ROS: every number written with a decimal point.
        numbers = text.strip('[]').split(', ')
        assert all('.' in number for number in numbers), (name, text)
        np.testing.assert_array_equal(np.array(numbers, dtype=float), np.ravel(value))
    plain = demo_commands.node_commands(demo.parse_arguments([]), str(tmp_path), lambda n: n)
    assert not any(arg.startswith('effects.') for arg in plain['platform_sim'])


@pytest.mark.parametrize(
    'argv',
    [
        ['--postures', '0'],
        ['--sensor-rate', '0'],
        ['--settle-time', '-1'],
        ['--platform-effects', 'realistic', '--platform', 'ros2_control'],
        ['--calibrator-param', 'rest_sigmas=inf'],
        ['--calibrator-param', 'no_such_parameter:=1'],
    ],
)
def test_bad_arguments_are_rejected(argv):
    with pytest.raises(SystemExit):
        demo.parse_arguments(argv)


def test_calibrator_params_come_last_so_they_win(tmp_path):
    argv = ['--calibrator-param', 'rest_sigmas:=.inf', '--calibrator-param', 'seed:=7']
    calibrator = demo_commands.node_commands(demo.parse_arguments(argv), str(tmp_path), str)
    calibrator = calibrator['calibrator']
    assert calibrator[-4:] == ['-p', 'rest_sigmas:=.inf', '-p', 'seed:=7']
    # The demo's own seed is given too, earlier: ROS takes the last '-p' of a name.
    assert calibrator.index('seed:=0') < calibrator.index('seed:=7')


def test_validation_details_of_the_postures_reached_both_times():
    commanded = np.array([[0, 0, 1, 0, 0, 0], [0, 0, 1, 0, 0, 0.1]], float)
    reached = commanded + np.array([[0.001, 0, 0, 0, 0, 0], [0, 0.002, 0, 0, 0, math.radians(0.5)]])
    details = demo_summary.validation_details(commanded, reached)
    assert details['position_mm_mean'] == pytest.approx(1.5)
    assert details['orientation_deg_max'] == pytest.approx(0.5)
    assert details['position_mm'] == pytest.approx([1.0, 2.0])
    assert details['orientation_deg'] == pytest.approx([0.0, 0.5])
    assert details['postures'] == 2 and details['position_mm_max'] == pytest.approx(2.0)


def _measured(before, after, calibrated, **more):
    return demo_summary.Measured(
        before=before,
        after=after,
        calibrated=calibrated,
        identification_ms=600.0,
        calibration_s=12.0,
        **more,
    )


def test_summary_has_the_keys_of_the_issue():
    true, nominal = default_geometry('true'), default_geometry('nominal')
    before = dict.fromkeys(VALIDATION_KEYS, 1.0)
    summary = demo_summary.summary_document(_measured(before, before, nominal), true, 40.0, {})
    assert set(summary) == {
        'validation',
        'max_param_error_mm',
        'max_param_error_deg',
        'identification_ms',
        'calibration_s',
        'total_s',
        'run_directory',
        *demo_summary.RESULT_KEYS,
    }
    assert summary['run_directory'] is None and summary['collection'] is None
    assert set(summary['validation']) == {'before', 'after'}
    assert set(summary['validation']['after']) == set(VALIDATION_KEYS)
    assert summary['max_param_error_mm'] > 0.1 and summary['max_param_error_deg'] > 0.0
    text = demo_summary.summary_text(summary, 49, 1)
    assert 'before (nominal)' in text and '1 rejected' in text


def test_summary_repeats_the_goodness_of_fit_of_result_json(tmp_path):
    fit = {'chi2': 190.5, 'dof': 185, 'p_value': 0.38}
    noise = {'lvdt': {'configured': 1e-6, 'estimated': 0.96e-6}}
    (tmp_path / 'result.json').write_text(
        json.dumps({'goodness_of_fit': fit, 'noise_estimates': noise, 'fit_diagnosis': 'ok'})
    )
    record = demo_summary.result_record(tmp_path)
    true, nominal = default_geometry('true'), default_geometry('nominal')
    before = dict.fromkeys(VALIDATION_KEYS, 1.0)
    summary = demo_summary.summary_document(_measured(before, before, nominal), true, 1.0, record)
    assert summary['goodness_of_fit'] == fit and summary['noise_estimates'] == noise
    assert demo_summary.summary_text(summary, 1, 0).endswith('ok')


def test_the_summary_sets_the_held_out_interval_beside_the_validation(tmp_path):
    """Issue 33: the demo prints the calibrator's held-out accuracy with its 95 % interval next
    to the validation after calibration, and says whether the validation lies inside."""
    position = {'mean': 0.0042, 'mean_interval_95': [0.0017, 0.0067]}
    accuracy = {'calibrated': {'position_mm': position, 'phi_deg': {'mean': 1e-5}}}
    (tmp_path / 'result.json').write_text(json.dumps({'accuracy': accuracy}))
    true, nominal = default_geometry('true'), default_geometry('nominal')
    before = dict.fromkeys(VALIDATION_KEYS, 1.0)
    fit = demo_summary.result_record(tmp_path)
    for validated, where in ((0.0029, 'inside'), (0.0068, 'OUTSIDE')):
        after = {**before, 'position_mm_mean': validated}
        summary = demo_summary.summary_document(_measured(before, after, nominal), true, 1.0, fit)
        line = [
            v for v in demo_summary.summary_text(summary, 50, 0).splitlines() if 'held out' in v
        ]
        assert line == [
            f"  held out (calibrator) 0.0042 mm, 95 %: 0.0017-0.0067 mm: the validation's "
            f'{validated:.4f} mm lies {where}'
        ]


def test_demo_free_accepts_groups_and_names_and_rejects_unknown(capsys):
    assert demo.parse_arguments([]).free_parameters == ['auto']
    assert demo.parse_arguments(['--free', 'paper', 'kq1,kq2']).free_parameters == [
        'paper',
        'kq1',
        'kq2',
    ]
    with pytest.raises(SystemExit):
        demo.parse_arguments(['--free', 'kq9'])
    assert 'unknown parameter name' in capsys.readouterr().err


def test_summary_names_the_run_directory_and_keeps_the_collection_record(tmp_path):
    record = {
        'skipped': [
            {
                'posture': 2,
                'reason': 'rejected by the platform: singular',
                'rejected_by_platform': True,
            }
        ],
        'inconsistent_dropped': 0,
        'non_finite_dropped': {'leg_lengths': 0, 'inclinometer': 1, 'encoder': 0, 'lvdt': 0},
    }
    assert not any(demo_summary.result_record(tmp_path).values())  # no result.json
    (tmp_path / 'result.json').write_text(json.dumps({'converged': True}))
    assert demo_summary.result_record(tmp_path)['collection'] is None  # an older calibrator
    (tmp_path / 'result.json').write_text(json.dumps({'collection': record}))
    true, nominal = default_geometry('true'), default_geometry('nominal')
    before = dict.fromkeys(VALIDATION_KEYS, 1.0)
    found = demo_summary.result_record(tmp_path)
    measured = _measured(before, before, nominal, run_directory=RunDirectory(tmp_path))
    summary = demo_summary.summary_document(measured, true, 40.0, found)
    assert summary['run_directory'] == str(tmp_path) and summary['collection'] == record


def _child(code):
    return [sys.executable, '-c', code]


IGNORES_SIGINT = (
    'import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); '
    'print("up", flush=True); time.sleep(60)'
)
IGNORES_ALL = (
    'import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); '
    'signal.signal(signal.SIGTERM, signal.SIG_IGN); print("up", flush=True); '
    'time.sleep(60)'
)
# A shell starts background jobs with SIGINT ignored and Python then keeps it ignored: install
# the KeyboardInterrupt handler explicitly, as rclpy does for the real nodes.
POLITE = (
    'import signal, time\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n'
    'try:\n    print("ready", flush=True)\n    time.sleep(60)\nexcept KeyboardInterrupt:\n    pass'
)


def _wait_for_output(processes, names, timeout=60.0):
    """Wait until each child has printed (its handlers are in place); the timeout bounds a failure."""
    assert wait_until(
        lambda: all((processes.log_directory / f'{n}.log').read_text().strip() for n in names),
        timeout,
    ), 'a child printed nothing'


def test_children_are_stopped_sigint_then_sigterm_then_sigkill(tmp_path):
    processes = NodeProcesses(
        {'polite': _child(POLITE), 'stubborn': _child(IGNORES_SIGINT), 'deaf': _child(IGNORES_ALL)},
        env=None,
        log_directory=tmp_path,
    )
    processes.start()
    # Each child prints once its handlers (or the polite child's try block) are in place.
    _wait_for_output(processes, ['polite', 'stubborn', 'deaf'])
    # The stubborn and the deaf child make stop() wait out the grace once and twice: it only
    # bounds how long the polite child may take to exit after SIGINT (ms when idle).
    codes = processes.stop(grace=1.5)
    assert codes == {'polite': 0, 'stubborn': -signal.SIGTERM, 'deaf': -signal.SIGKILL}
    assert processes.stop() == codes  # idempotent


def test_a_child_that_exits_is_reported_with_its_log(tmp_path):
    processes = NodeProcesses(
        {'broken': _child('import sys; print("cannot start: bad parameter"); sys.exit(3)')},
        env=None,
        log_directory=tmp_path,
    )
    processes.start()
    processes.processes['broken'].wait(timeout=20.0)
    assert processes.exited() == ('broken', 3)
    assert 'bad parameter' in processes.log_tail('broken')
    processes.stop()


def test_the_physics_backend_runs_platform_sim_on_its_preset_with_the_device_on_the_physics(
    tmp_path,
):
    args = demo.parse_arguments(['--backend', 'physics'])
    found = demo_commands.node_commands(args, str(tmp_path), which=lambda name: f'/opt/bin/{name}')
    platform = found['platform_sim']
    files = [platform[i + 1] for i, arg in enumerate(platform) if arg == '--params-file']
    # The preset after the nominal geometry (the controller's), which it does not touch.
    assert files[0] == args.nominal_geometry
    assert files[1].endswith('gsp_platform_sim/config/physics_realistic.yaml')
    assert 'backend:=physics' in found['device_driver']
    # A servo does not jump: the legs' realistic limits, known to the calibrator's plan.
    assert 'max_leg_speed:=0.05' in platform and 'max_leg_speed:=0.05' in found['calibrator']
    # ... and a calibration that takes the servos' time: not the kinematic backend's 120 s.
    assert args.timeout == demo.CALIBRATION_TIMEOUT_S['physics'] >= 3600.0
    assert demo.parse_arguments([]).timeout == 120.0
    assert demo.parse_arguments(['--backend', 'physics', '--timeout', '9']).timeout == 9.0
    for bad in (['--platform', 'ros2_control'], ['--platform-effects', 'realistic']):
        with pytest.raises(SystemExit):
            demo.parse_arguments(['--backend', 'physics', *bad])
