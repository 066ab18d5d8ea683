"""A calibration or a check read back from its run directory as a ``drift.Calibration``."""

import json
from pathlib import Path

import numpy as np

from gsp_kinematics.model.geometry import (
    ALL_PARAMETER_NAMES,
    PARAMETER_NAMES,
    SENSOR_PARAMETER_NAMES,
    Geometry,
)
from gsp_kinematics.upkeep.drift import Calibration

RESULT_JSON = 'result.json'
CHECK_JSON = 'check.json'


class CalibrationFileError(ValueError):
    """A run directory or file holds no usable calibration; the message says what is missing."""


def run_file(path):
    """The ``result.json`` or ``check.json`` of ``path`` (a run directory or the file itself)."""
    path = Path(path)
    if path.is_dir():
        for name in (RESULT_JSON, CHECK_JSON):
            if (path / name).is_file():
                return path / name
        raise CalibrationFileError(f'{path}: neither {RESULT_JSON} nor {CHECK_JSON} is there')
    if not path.is_file():
        raise CalibrationFileError(f'{path}: no such file or directory')
    return path


def read_json(path):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError) as error:
        raise CalibrationFileError(f'{path}: cannot read it as JSON ({error})') from None


def _full_vector(data, path):
    estimates = (data.get('estimates') or {}).get('si') or {}
    sensors = data.get('sensor_errors') or {}
    for name in PARAMETER_NAMES:
        if estimates.get(name) is None:
            raise CalibrationFileError(f'{path}: estimates.si.{name} is missing')
    sensor = [(sensors.get(name) or {}).get('estimate') or 0.0 for name in SENSOR_PARAMETER_NAMES]
    return np.array([estimates[name] for name in PARAMETER_NAMES] + sensor, dtype=float)


def _deviations(data, names, path):
    deviations = (data.get('standard_deviations') or {}).get('si') or {}
    sensors = data.get('sensor_errors') or {}
    values = []
    for name in names:
        value = (
            deviations.get(name)
            if name in PARAMETER_NAMES
            else (sensors.get(name) or {}).get('standard_deviation')
        )
        if value is None:
            raise CalibrationFileError(f'{path}: no standard deviation of free parameter {name}')
        values.append(float(value))
    return np.array(values)


def calibration_from_result(data, path='result.json'):
    """A ``drift.Calibration`` of a ``result.json`` dict ``data`` (``path`` names it in errors)."""
    free = tuple(data.get('free_parameters') or ())
    if not free:
        raise CalibrationFileError(f'{path}: no free_parameters (did the identification run?)')
    # The drift is compared over the geometry and the sensor errors; the effect parameters an
    # `auto` run also freed (compliance1, backlash1, ...) follow them in `free_parameters` and
    # are left out, with their marginal covariance (the block of the others), which is exact.
    keep = [k for k, name in enumerate(free) if name in ALL_PARAMETER_NAMES]
    names = tuple(free[k] for k in keep)
    if not names:
        raise CalibrationFileError(
            f'{path}: no geometric or sensor parameter among free_parameters'
        )
    vector = _full_vector(data, path)
    index = [ALL_PARAMETER_NAMES.index(name) for name in names]
    stored = data.get('covariance') or {}
    matrix = stored.get('si')
    if stored.get('parameters') == list(free) and matrix is not None:
        covariance = np.array(matrix, dtype=float)
        if covariance.shape != (len(free), len(free)):
            raise CalibrationFileError(
                f'{path}: the covariance is {covariance.shape}, not {len(free)}x{len(free)}'
            )
        covariance = covariance[np.ix_(keep, keep)]
        if not np.all(np.isfinite(covariance)):
            raise CalibrationFileError(f'{path}: the covariance is not finite')
    else:
        covariance = np.diag(_deviations(data, names, path) ** 2)
    geometry = Geometry.from_full_vector(vector)
    return Calibration(names, vector[index], covariance, geometry, str(path))


def calibration_from_check(data, path='check.json'):
    """A ``drift.Calibration`` of a ``check.json`` dict: its small identification."""
    found = data.get('identification') or {}
    names = tuple(found.get('parameters') or ())
    if not names:
        raise CalibrationFileError(f'{path}: the check identified no parameter')
    geometry_si = data.get('geometry_si') or {}
    try:
        vector = np.array([float(geometry_si[name]) for name in ALL_PARAMETER_NAMES])
    except KeyError as error:
        raise CalibrationFileError(f'{path}: geometry_si.{error.args[0]} is missing') from None
    return Calibration(
        names,
        np.array(found['estimates_si'], dtype=float),
        np.array(found['covariance_si'], dtype=float),
        Geometry.from_full_vector(vector),
        str(path),
    )


def load_calibration(path):
    """The ``drift.Calibration`` of a run directory, ``result.json`` or ``check.json``."""
    file = run_file(path)
    data = read_json(file)
    if data.get('kind') == 'check':
        return calibration_from_check(data, file)
    return calibration_from_result(data, file)
