"""Pure numpy/scipy core of gsp-calibration: kinematics, device model and identification.

Never imports rclpy, so it is usable and testable without ROS.
"""

from .device import device_position, device_readings, position_to_inclinations  # noqa: F401
from .geometry import (  # noqa: F401
    PARAMETER_NAMES,
    Geometry,
    GeometryError,
    Limits,
    default_geometry,
    default_geometry_path,
    load_geometry,
    save_geometry,
)
from .identification import IdentificationResult, Sigmas, identify  # noqa: F401
from .kinematics import (  # noqa: F401
    ForwardKinematicsError,
    Workspace,
    check_reachable,
    forward_kinematics,
    inverse_kinematics,
    sample_valid_postures,
)
