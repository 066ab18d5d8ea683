"""The simulated suite: platform_sim, device_driver (sim backend) and the calibrator; its
arguments: docs/hardware.md."""

from launch import LaunchDescription
from launch.substitutions import LaunchConfiguration

from gsp_calibrator import launch_arguments


def generate_launch_description():
    params_file = LaunchConfiguration('params_file')
    geometry_file = LaunchConfiguration('geometry_file')
    truth = {'true_geometry_file': LaunchConfiguration('true_geometry_file')}
    true_geometry_argument = launch_arguments.geometry_file_argument(
        'Geometry of the simulated real platform and device', name='true_geometry_file', kind='true'
    )
    return LaunchDescription(
        [
            *launch_arguments.standard_arguments(
                'gsp_suite.yaml',
                'Parameters of every node (one section per node name)',
                'Controller geometry params file (nominal or calibrated)',
            ),
            true_geometry_argument,
            launch_arguments.screen_node(
                'gsp_platform_sim', 'platform_sim', [geometry_file, params_file, truth]
            ),
            launch_arguments.screen_node(
                'gsp_device_driver', 'device_driver', [params_file, truth]
            ),
            launch_arguments.screen_node(
                'gsp_calibrator',
                'calibrator',
                [params_file, {'nominal_geometry_file': geometry_file}],
            ),
        ]
    )
