"""Launch arguments and node actions shared by the package's launch files (``launch/``)."""

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def share_path(package, *parts):
    """The path ``parts`` under the share directory of ``package`` (a substitution)."""
    return PathJoinSubstitution([FindPackageShare(package), *parts])


def geometry_file_argument(description, name='geometry_file', kind='nominal'):
    """A geometry params file argument; default: gsp_kinematics' ``config/<kind>_geometry.yaml``."""
    return DeclareLaunchArgument(
        name,
        default_value=share_path('gsp_kinematics', 'config', f'{kind}_geometry.yaml'),
        description=description,
    )


def standard_arguments(config_file, params_description, geometry_description):
    """``params_file`` (default: ``config/<config_file>``), ``geometry_file`` and
    ``use_sim_time``: the arguments of every launch file of the package."""
    return [
        DeclareLaunchArgument(
            'params_file',
            default_value=share_path('gsp_calibrator', 'config', config_file),
            description=params_description,
        ),
        geometry_file_argument(geometry_description),
        DeclareLaunchArgument('use_sim_time', default_value='false', description='Use /clock time'),
    ]


def screen_node(package, executable, parameters):
    """The node ``executable`` of ``package``, named after it, logging to the screen."""
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)
    return Node(
        package=package,
        executable=executable,
        name=executable,
        output='screen',
        parameters=[*parameters, {'use_sim_time': use_sim_time}],
    )
