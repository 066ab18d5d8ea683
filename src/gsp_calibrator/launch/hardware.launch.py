"""Real hardware: device_driver on the serial device and platform_bridge to ros2_control.

The ros2_control side (controller_manager, joint_trajectory_controller, joint_state_broadcaster)
is the hexapod's own launch. Start the calibrator with calibrator.launch.py (same params file).

    ros2 launch gsp_calibrator hardware.launch.py [params_file:=...] [geometry_file:=...]
        [port:=/dev/ttyACM0] [controller_name:=joint_trajectory_controller] [use_sim_time:=false]
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    params_file = LaunchConfiguration('params_file')
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'params_file',
                default_value=PathJoinSubstitution(
                    [FindPackageShare('gsp_calibrator'), 'config', 'gsp_hardware.yaml']
                ),
                description='Parameters of device_driver and platform_bridge',
            ),
            DeclareLaunchArgument(
                'geometry_file',
                default_value=PathJoinSubstitution(
                    [FindPackageShare('gsp_kinematics'), 'config', 'nominal_geometry.yaml']
                ),
                description="Controller geometry params file of the bridge (the hexapod's model)",
            ),
            DeclareLaunchArgument(
                'port', default_value='/dev/ttyACM0', description='Serial port of the device'
            ),
            DeclareLaunchArgument(
                'controller_name',
                default_value='joint_trajectory_controller',
                description='The joint_trajectory_controller of the six legs',
            ),
            DeclareLaunchArgument(
                'use_sim_time', default_value='false', description='Use /clock time'
            ),
            Node(
                package='gsp_device_driver',
                executable='device_driver',
                name='device_driver',
                output='screen',
                parameters=[
                    params_file,
                    {
                        'serial.port': LaunchConfiguration('port'),
                        'use_sim_time': use_sim_time,
                    },
                ],
            ),
            Node(
                package='gsp_platform_bridge',
                executable='platform_bridge',
                name='platform_bridge',
                output='screen',
                parameters=[
                    LaunchConfiguration('geometry_file'),
                    params_file,
                    {
                        'controller_name': LaunchConfiguration('controller_name'),
                        'use_sim_time': use_sim_time,
                    },
                ],
            ),
        ]
    )
