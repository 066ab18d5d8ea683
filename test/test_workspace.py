"""Cross-package checks of the colcon workspace: install layout, ament index, loopback DDS."""

import os
import sys
from pathlib import Path

import numpy as np
import pytest

#: Bounds a wait that only ends early on failure (the test waits on the event itself).
TIMEOUT_S = 30.0
WS = Path(__file__).resolve().parents[1]
INSTALL = WS / 'install'
PACKAGES = (
    'gsp_kinematics',
    'gsp_msgs_py',
    'gsp_platform_sim',
    'gsp_device_driver',
    'gsp_platform_bridge',
    'gsp_calibrator',
)
EXECUTABLES = {
    'gsp_msgs_py': ('gsp_check_interfaces',),
    'gsp_platform_sim': ('platform_sim', 'controller_sim'),
    'gsp_device_driver': ('device_driver', 'gsp_fake_device'),
    'gsp_platform_bridge': ('platform_bridge',),
    'gsp_calibrator': (
        'calibrator',
        'gsp_demo',
        'gsp_calibrate_client',
        'gsp_reidentify',
        'replay',
    ),
}

needs_install = pytest.mark.skipif(
    not (INSTALL / 'local_setup.sh').exists(), reason='no colcon install/ (run `make build`)'
)


def test_ros_network_is_local():
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 0 <= int(os.environ['ROS_DOMAIN_ID']) <= 232


@needs_install
@pytest.mark.parametrize('package', PACKAGES)
def test_packages_are_in_the_ament_index(package):
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    assert Path(get_package_prefix(package)) == INSTALL / package
    assert (Path(get_package_share_directory(package)) / 'package.xml').is_file()
    # Message packages of the wheels are found too (AMENT_PREFIX_PATH includes .venv).
    assert Path(get_package_share_directory('sensor_msgs')).is_dir()


@needs_install
@pytest.mark.parametrize('package', sorted(EXECUTABLES))
def test_console_scripts_use_the_venv_python(package):
    for name in EXECUTABLES[package]:
        exe = INSTALL / package / 'lib' / package / name
        assert exe.is_file() and os.access(exe, os.X_OK), f'{exe} missing (ros2 run layout)'
        shebang = exe.read_text().splitlines()[0]
        interpreter = Path(shebang[2:].split()[0])
        assert interpreter.parent == Path(sys.executable).parent, shebang


@needs_install
def test_default_geometries_are_installed_as_config():
    source = {p.name for p in (WS / 'src/gsp_kinematics/gsp_kinematics/data').glob('*.yaml')}
    config = {
        p.name for p in (INSTALL / 'gsp_kinematics/share/gsp_kinematics/config').glob('*.yaml')
    }
    assert source == config


def test_pose_command_and_status_round_trip(ros_context):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseStamped
    from gsp_testing import spin_until
    from rclpy.executors import SingleThreadedExecutor

    from gsp_msgs_py import names, qos
    from gsp_msgs_py.conversions import (
        command_id_from_stamp,
        make_status,
        parse_status,
        pose_stamped_to_pose,
        pose_to_pose_stamped,
    )

    node = rclpy.create_node('gsp_workspace_test', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    poses, statuses = [], []
    try:
        node.create_subscription(
            PoseStamped,
            names.TOPIC_POSE_COMMAND,
            lambda m: poses.append(
                (command_id_from_stamp(m.header.stamp), pose_stamped_to_pose(m))
            ),
            qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND],
        )
        node.create_subscription(
            DiagnosticStatus,
            names.TOPIC_PLATFORM_STATUS,
            lambda m: statuses.append(parse_status(m)),
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
        )
        command_pub = node.create_publisher(
            PoseStamped, names.TOPIC_POSE_COMMAND, qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND]
        )
        status_pub = node.create_publisher(
            DiagnosticStatus,
            names.TOPIC_PLATFORM_STATUS,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
        )

        assert spin_until(
            executor,
            lambda: (
                command_pub.get_subscription_count() > 0 and status_pub.get_subscription_count() > 0
            ),
            TIMEOUT_S,
        )

        x = np.array([0.01, -0.02, 0.95, 0.05, -0.03, 0.2])
        stamp = node.get_clock().now().to_msg()
        command_pub.publish(pose_to_pose_stamped(x, stamp))
        command_id = command_id_from_stamp(stamp)
        status_pub.publish(make_status(command_id, 'settled'))
        assert spin_until(executor, lambda: poses and statuses, TIMEOUT_S)

        assert poses and poses[0][0] == command_id
        np.testing.assert_allclose(poses[0][1], x, atol=1e-12)
        assert statuses[0].command_id == command_id and statuses[0].settled
    finally:
        executor.shutdown()
        node.destroy_node()
