"""Pure numpy/scipy core of gsp-calibration: kinematics, device model and identification.

Never imports rclpy, so it is usable and testable without ROS. The modules are the API; the most
used names are also available here (``from gsp_kinematics import identify``), imported on first
use so that importing one module (e.g. :mod:`gsp_kinematics.rotation`) does not load them all.
"""

import importlib

#: Module -> the names it lends to the package.
_EXPORTS = {
    'model.device': ('device_position', 'device_readings', 'position_to_inclinations'),
    'model.geometry': (
        'ALL_PARAMETER_NAMES PARAMETER_NAMES Geometry GeometryError Limits default_geometry default_geometry_path '
        'SensorErrors load_geometry save_geometry'
    ).split(),
    'estimation.identification': ('IdentificationResult', 'identify'),
    'model.sensor_noise': ('DEFAULT_SENSOR_NOISE', 'SensorNoise'),
    'model.kinematics': (
        'ForwardKinematicsError Workspace check_reachable forward_kinematics inverse_kinematics '
        'sample_valid_postures'
    ).split(),
}
_MODULE_OF = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_MODULE_OF)


def __getattr__(name):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(importlib.import_module(f'.{module}', __name__), name)


def __dir__():
    return sorted(set(globals()) | set(__all__))
