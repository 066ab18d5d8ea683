"""Pure numpy/scipy core of gsp-calibration (never imports rclpy); the most used names are lent
here, imported on first use (docs/core_api.md)."""

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
