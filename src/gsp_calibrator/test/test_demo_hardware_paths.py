"""gsp_demo's hardware paths: --platform ros2_control and --device serial (node commands)."""

import sys

from gsp_calibrator.tools import demo, demo_commands


def test_ros2_control_replaces_platform_sim_by_the_bridge_and_the_emulated_controller(tmp_path):
    args = demo.parse_arguments(['--platform', 'ros2_control', '--seed', '4'])
    found = demo_commands.node_commands(args, str(tmp_path), which=lambda name: f'/opt/bin/{name}')
    assert set(found) == {'controller_sim', 'platform_bridge', 'device_driver', 'calibrator'}
    bridge = found['platform_bridge']
    assert bridge[:2] == ['/opt/bin/platform_bridge', '--ros-args']
    assert bridge[bridge.index('--params-file') + 1] == args.nominal_geometry
    assert f'true_geometry_file:={args.true_geometry}' in found['controller_sim']
    assert not any(arg.startswith('seed:=') for arg in found['controller_sim'])
    assert 'platform_node_name:=platform_bridge' in found['calibrator']


def test_serial_runs_the_emulated_device_into_the_serial_backend(tmp_path):
    args = demo.parse_arguments(['--device', 'serial', '--sensor-rate', '100'])
    args.device_port = str(tmp_path / 'gsp_device')
    found = demo_commands.node_commands(args, str(tmp_path), which=lambda name: None)
    assert set(found) == {'platform_sim', 'gsp_fake_device', 'device_driver', 'calibrator'}
    fake = found['gsp_fake_device']
    assert fake[:3] == [sys.executable, '-m', 'gsp_device_driver.fake_device_node']
    assert fake[fake.index('--port') + 1] == args.device_port and '100.0' in fake
    driver = found['device_driver']
    assert 'backend:=serial' in driver and f'serial.port:={args.device_port}' in driver
