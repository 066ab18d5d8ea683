"""The calibrator alone (e.g. on a workstation, with the drivers on the device PC).

ros2 launch gsp_calibrator calibrator.launch.py [params_file:=...] [geometry_file:=...]
    [use_sim_time:=false]
"""

from launch import LaunchDescription
from launch.substitutions import LaunchConfiguration

from gsp_calibrator import launch_arguments


def generate_launch_description():
    geometry = {'nominal_geometry_file': LaunchConfiguration('geometry_file')}
    return LaunchDescription(
        [
            launch_arguments.params_file_argument(
                'gsp_hardware.yaml', 'Calibrator parameters (its calibrator: section is used)'
            ),
            launch_arguments.geometry_file_argument('Nominal geometry: the identification start'),
            launch_arguments.use_sim_time_argument(),
            launch_arguments.screen_node(
                'gsp_calibrator', 'calibrator', [LaunchConfiguration('params_file'), geometry]
            ),
        ]
    )
