"""The numbers of a calibration report shared by ``result.json``, ``report.md`` and the plots
(pure, no rclpy)."""

import math

import numpy as np

from gsp_kinematics import channels
from gsp_kinematics.fileio import json_safe
from gsp_kinematics.model.geometry import ANGULAR_PARAMETERS, PARAMETER_NAMES, to_report_units

ANGULAR = set(ANGULAR_PARAMETERS)
#: Each residual group (``identification.SENSOR_NAMES``) -> 'angle' or 'length', by unit.
SENSOR_KIND = {
    channels.LEG_LENGTHS: 'length',
    **{
        channel.name: 'angle' if channel.unit == 'rad' else 'length'
        for channel in channels.DEVICE_CHANNELS
    },
}
#: Each residual group -> its label in the report.
SENSOR_LABEL = {
    channels.LEG_LENGTHS: 'leg lengths '
    + '..'.join(channels.CHANNEL_NAMES[0 : channels.LEG_COUNT : 5]),
    **{channel.name: f'{channel.sensor} {channel.name}' for channel in channels.DEVICE_CHANNELS},
}

VALIDATION_KEYS = (
    'position_mm_mean',
    'position_mm_max',
    'orientation_deg_mean',
    'orientation_deg_max',
)


def by_name(values, mask=None):
    return {
        name: (json_safe(values[i]) if mask is None or mask[i] else None)
        for i, name in enumerate(PARAMETER_NAMES)
    }


def identifiability_record(analysis):
    """The ``identifiability`` of result.json from an ``analyse_result`` analysis (None: none)."""
    if not analysis:
        return None
    entries = analysis['unidentifiable']
    return {
        'rank': analysis['rank'],
        'parameters': analysis['parameters'],
        'condition_number': analysis['condition_number'],
        'singular_values': analysis.get('singular_values'),  # none for a failed fit
        'unidentifiable': entries,
        'unidentifiable_parameters': sorted({p for e in entries for p in e['parameters']}),
    }


def validation_summary(validation):
    """``{position_mm_mean, ..., postures}`` of a validation (summary dict or per-posture arrays)."""
    if validation is None:
        return None
    summary = {k: validation[k] for k in VALIDATION_KEYS if k in validation}
    arrays = validation_arrays(validation)
    for name, values in zip(('position_mm', 'orientation_deg'), arrays, strict=True):
        if values is not None and len(values):
            summary.setdefault(f'{name}_mean', float(np.mean(values)))
            summary.setdefault(f'{name}_max', float(np.max(values)))
    summary |= {key: validation[key] for key in ('postures', 'unreachable') if key in validation}
    if 'postures' not in summary and arrays[0] is not None:
        summary['postures'] = len(arrays[0])
    return summary


def validation_arrays(validation):
    """``(position mm, orientation deg)`` per posture of a validation (each None if absent)."""
    return tuple(
        None if validation.get(key) is None else np.asarray(validation[key], dtype=float).ravel()
        for key in ('position_mm', 'orientation_deg')
    )


def validation_errors(true, controller, poses):
    """Per-posture validation of ``controller`` against the real platform ``true`` (simulation)."""
    from gsp_kinematics.model.kinematics import forward_kinematics_masked
    from gsp_kinematics.model.validation import commanded_articular, pose_errors, summarise

    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    reached, converged = forward_kinematics_masked(
        true, commanded_articular(true, controller, poses), poses
    )
    if not converged.any():
        raise ValueError('no validation posture is reachable by the real platform')
    position, orientation = pose_errors(poses[converged], reached[converged])
    out = summarise(position, orientation)
    out.update(
        position_mm=position.tolist(),
        orientation_deg=orientation.tolist(),
        poses=poses[converged].tolist(),
        postures=int(converged.sum()),
        unreachable=int((~converged).sum()),
    )
    return out


def parameter_error_table(result, truth, nominal):
    """``(reference kind, before, after, sigma)`` per parameter in report units."""
    count = len(PARAMETER_NAMES)  # the 44; the sensor errors have their own section
    estimate = np.asarray(result.parameters, dtype=float)[:count]
    sigma = to_report_units(np.nan_to_num(result.standard_deviations[:count], nan=0.0))
    sigma = np.where(np.asarray(result.free, dtype=bool)[:count], sigma, np.nan)
    if truth is None:
        reference, before = nominal.to_vector(), np.zeros(count)
    else:
        reference = truth.to_vector()
        before = to_report_units(nominal.to_vector() - reference)
    kind = 'nominal' if truth is None else 'truth'
    return kind, before, to_report_units(estimate - reference), sigma


def residual_columns(result):
    """``[(sensor, columns), ...]`` of ``result.residuals`` (weighted), in column order."""
    residuals = np.asarray(result.residuals, dtype=float)
    if residuals.ndim != 2 or not result.residual_rms:
        return []
    layout, column = [], 0
    for sensor in result.residual_rms:
        width = channels.LEG_COUNT if sensor == channels.LEG_LENGTHS else 1
        layout.append((sensor, list(range(column, column + width))))
        column += width
    if column != residuals.shape[1]:
        return []
    return layout


def residuals_by_sensor(result):
    """``{sensor: residuals in SI (m or rad)}`` (1-D, finite values only): the core's weighted
    residuals scaled by the sensor's RMS in SI over theirs (the weights need not be known)."""
    residuals = np.asarray(result.residuals, dtype=float)
    out = {}
    for sensor, columns in residual_columns(result):
        weighted = residuals[:, columns].reshape(-1)
        weighted = weighted[np.isfinite(weighted)]
        rms_weighted = float(np.sqrt(np.mean(weighted**2))) if weighted.size else 0.0
        rms_si = float(result.residual_rms.get(sensor, float('nan')))
        if rms_weighted > 0.0 and math.isfinite(rms_si):
            out[sensor] = weighted * (rms_si / rms_weighted)
        else:
            out[sensor] = np.zeros_like(weighted)
    return out


def settle_line(settle):
    """The response's line of ``collection.settle`` (:func:`settle_statistics`); '' without
    rows."""
    if not settle or not settle.get('rows'):
        return ''
    return (
        f'rest wait (settled to averaged window): median {settle["median_s"]:.3g} s, max '
        f'{settle["max_s"]:.3g} s over {settle["rows"]} rows; {settle["waited"]} waited for a '
        'moving channel'
    )


def settle_statistics(waits):
    """``result.json`` ``collection.settle`` (docs/data.md#resultjson) of the kept rows' rest
    waits ``{posture: {wait_s, moving_pairs}}``."""
    values = np.array([entry['wait_s'] for entry in waits.values()], dtype=float)
    known = values.size > 0
    return {
        'rows': int(values.size),
        'median_s': float(np.median(values)) if known else None,
        'max_s': float(values.max()) if known else None,
        'mean_s': float(values.mean()) if known else None,
        'waited': sum(1 for entry in waits.values() if entry['moving_pairs'] > 0),
        'per_posture_s': {
            posture: float(waits[posture]['wait_s']) for posture in sorted(waits, key=int)
        },
    }
