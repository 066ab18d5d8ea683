"""The simulated suite: platform_sim, device_driver (sim backend) and the calibrator.

ros2 launch gsp_calibrator sim_suite.launch.py [params_file:=...] [geometry_file:=...]
    [true_geometry_file:=...] [use_sim_time:=false]
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    params_file = LaunchConfiguration('params_file')
    geometry_file = LaunchConfiguration('geometry_file')
    true_geometry_file = LaunchConfiguration('true_geometry_file')
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)
    geometry_config = PathJoinSubstitution([FindPackageShare('gsp_kinematics'), 'config'])
    common = {'use_sim_time': use_sim_time}
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'params_file',
                default_value=PathJoinSubstitution(
                    [FindPackageShare('gsp_calibrator'), 'config', 'gsp_suite.yaml']
                ),
                description='Parameters of every node (one section per node name)',
            ),
            DeclareLaunchArgument(
                'geometry_file',
                default_value=PathJoinSubstitution([geometry_config, 'nominal_geometry.yaml']),
                description='Controller geometry params file (nominal or calibrated)',
            ),
            DeclareLaunchArgument(
                'true_geometry_file',
                default_value=PathJoinSubstitution([geometry_config, 'true_geometry.yaml']),
                description='Geometry of the simulated real platform and device',
            ),
            DeclareLaunchArgument(
                'use_sim_time', default_value='false', description='Use /clock time'
            ),
            Node(
                package='gsp_platform_sim',
                executable='platform_sim',
                name='platform_sim',
                output='screen',
                parameters=[
                    geometry_file,
                    params_file,
                    {'true_geometry_file': true_geometry_file},
                    common,
                ],
            ),
            Node(
                package='gsp_device_driver',
                executable='device_driver',
                name='device_driver',
                output='screen',
                parameters=[params_file, {'true_geometry_file': true_geometry_file}, common],
            ),
            Node(
                package='gsp_calibrator',
                executable='calibrator',
                name='calibrator',
                output='screen',
                parameters=[params_file, {'nominal_geometry_file': geometry_file}, common],
            ),
        ]
    )
