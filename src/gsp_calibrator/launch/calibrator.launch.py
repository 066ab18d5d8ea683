"""The calibrator alone (e.g. on a workstation, with the drivers on the device PC).

ros2 launch gsp_calibrator calibrator.launch.py [params_file:=...] [geometry_file:=...]
    [use_sim_time:=false]
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'params_file',
                default_value=PathJoinSubstitution(
                    [FindPackageShare('gsp_calibrator'), 'config', 'gsp_hardware.yaml']
                ),
                description='Calibrator parameters (its calibrator: section is used)',
            ),
            DeclareLaunchArgument(
                'geometry_file',
                default_value=PathJoinSubstitution(
                    [FindPackageShare('gsp_kinematics'), 'config', 'nominal_geometry.yaml']
                ),
                description='Nominal geometry: the identification start',
            ),
            DeclareLaunchArgument(
                'use_sim_time', default_value='false', description='Use /clock time'
            ),
            Node(
                package='gsp_calibrator',
                executable='calibrator',
                name='calibrator',
                output='screen',
                parameters=[
                    LaunchConfiguration('params_file'),
                    {
                        'nominal_geometry_file': LaunchConfiguration('geometry_file'),
                        'use_sim_time': use_sim_time,
                    },
                ],
            ),
        ]
    )
