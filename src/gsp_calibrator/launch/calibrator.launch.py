"""The calibrator alone (e.g. on a workstation, with the drivers on the device PC); its
arguments: docs/hardware.md."""

from launch import LaunchDescription
from launch.substitutions import LaunchConfiguration

from gsp_calibrator import launch_arguments


def generate_launch_description():
    calibrator_parameters = [
        LaunchConfiguration('params_file'),
        {'nominal_geometry_file': LaunchConfiguration('geometry_file')},
    ]
    return LaunchDescription(
        [
            *launch_arguments.standard_arguments(
                'gsp_hardware.yaml',
                'Calibrator parameters (its calibrator: section is used)',
                'Nominal geometry: the identification start',
            ),
            launch_arguments.screen_node('gsp_calibrator', 'calibrator', calibrator_parameters),
        ]
    )
