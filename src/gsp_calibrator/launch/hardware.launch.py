"""Real hardware: device_driver on the serial device and platform_bridge to ros2_control (the
hexapod's own launch starts ros2_control; calibrator.launch.py the calibrator, same params file).
Its arguments: docs/hardware.md."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration

from gsp_calibrator import launch_arguments


def generate_launch_description():
    params_file = LaunchConfiguration('params_file')
    return LaunchDescription(
        [
            *launch_arguments.standard_arguments(
                'gsp_hardware.yaml',
                'Parameters of device_driver and platform_bridge',
                "Controller geometry params file of the bridge (the hexapod's model)",
            ),
            DeclareLaunchArgument(
                'port', default_value='/dev/ttyACM0', description='Serial port of the device'
            ),
            DeclareLaunchArgument(
                'controller_name',
                default_value='joint_trajectory_controller',
                description='The joint_trajectory_controller of the six legs',
            ),
            launch_arguments.screen_node(
                'gsp_device_driver',
                'device_driver',
                [params_file, {'serial.port': LaunchConfiguration('port')}],
            ),
            launch_arguments.screen_node(
                'gsp_platform_bridge',
                'platform_bridge',
                [
                    LaunchConfiguration('geometry_file'),
                    params_file,
                    {'controller_name': LaunchConfiguration('controller_name')},
                ],
            ),
        ]
    )
