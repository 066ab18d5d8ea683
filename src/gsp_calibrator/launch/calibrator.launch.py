"""The calibrator alone (e.g. on a workstation, with the drivers on the device PC).

ros2 launch gsp_calibrator calibrator.launch.py [params_file:=...] [geometry_file:=...]
    [use_sim_time:=false]
"""

from launch import LaunchDescription
from launch.substitutions import LaunchConfiguration

from gsp_calibrator.launch_arguments import (
    geometry_file_argument,
    params_file_argument,
    screen_node,
    use_sim_time_argument,
)


def generate_launch_description():
    geometry = {'nominal_geometry_file': LaunchConfiguration('geometry_file')}
    return LaunchDescription(
        [
            params_file_argument(
                'gsp_hardware.yaml', 'Calibrator parameters (its calibrator: section is used)'
            ),
            geometry_file_argument('Nominal geometry: the identification start'),
            use_sim_time_argument(),
            screen_node(
                'gsp_calibrator', 'calibrator', [LaunchConfiguration('params_file'), geometry]
            ),
        ]
    )
