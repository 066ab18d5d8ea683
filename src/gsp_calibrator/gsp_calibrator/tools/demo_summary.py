"""What ``gsp_demo`` measured and reports (pure): validation errors, parameter errors against
the truth, the ``summary.json`` document and its text."""

import dataclasses
import math
from pathlib import Path

import numpy as np

from gsp_calibrator.report.data import VALIDATION_KEYS
from gsp_calibrator.tools.reidentify_inputs import result_json
from gsp_kinematics.model.geometry import parameter_errors
from gsp_kinematics.model.validation import pose_errors, summarise


@dataclasses.dataclass
class Measured:
    """What the demo measured through the nodes."""

    run_directory: object = None  #: the calibration's RunDirectory once it has answered
    calibrated: object = None  #: the calibrated Geometry
    identification_ms: float = math.nan
    calibration_s: float = math.nan
    before: dict | None = None  #: validation errors before and after (``validation_details``)
    after: dict | None = None


def validation_details(commanded, reached):
    """Mean and max errors (mm, deg) of the ``reached`` poses (M, 6) against the ``commanded``
    ones, with the per-posture errors ``position_mm`` and ``orientation_deg``, the commanded
    ``poses`` and their count ``postures`` (the run's report overlays them on its accuracy map)."""
    position_mm, orientation_deg = pose_errors(commanded, reached)
    return {
        **summarise(position_mm, orientation_deg),
        'position_mm': np.asarray(position_mm, dtype=float).tolist(),
        'orientation_deg': np.asarray(orientation_deg, dtype=float).tolist(),
        'poses': np.asarray(commanded).tolist(),
        'postures': len(commanded),
    }


#: Keys of the calibrator's ``result.json`` that ``summary.json`` repeats (``collection``: its
#: record of skipped postures and dropped samples).
RESULT_KEYS = (
    'collection',
    'accepted',
    'acceptance',
    'accuracy',
    'predicted_accuracy',
    'unmodelled',
    'goodness_of_fit',
    'noise_source',
    'noise_estimates',
    'fit_diagnosis',
    'fit_accepted',
)


def result_record(run_directory):
    """``{key: value}`` of :data:`RESULT_KEYS` in the calibrator's ``result.json`` (None where
    absent). Read before the report is refreshed, which rewrites ``result.json``."""
    data = result_json(Path(run_directory))
    return {key: data.get(key) for key in RESULT_KEYS}


def summary_document(measured, true, total_s, record):
    """The ``summary.json`` document of a :class:`Measured` demo: its validation before and after
    calibration (their :data:`VALIDATION_KEYS`), the largest errors of its calibrated geometry's
    parameters against the ``true`` one, its times (ms, s; ``total_s``: the demo's), its run
    directory and the ``record`` of its ``result.json`` (:func:`result_record`)."""
    errors = parameter_errors(measured.calibrated, true)
    run_directory = measured.run_directory
    return {
        'validation': {
            'before': {key: measured.before[key] for key in VALIDATION_KEYS},
            'after': {key: measured.after[key] for key in VALIDATION_KEYS},
        },
        'max_param_error_mm': float(np.max(np.abs(errors[:43]))),  # the 43 lengths
        'max_param_error_deg': float(abs(errors[43])),  # gamma
        'identification_ms': float(measured.identification_ms),
        'calibration_s': float(measured.calibration_s),
        'total_s': float(total_s),
        'run_directory': None if run_directory is None else str(run_directory.path),
        **{key: record.get(key) for key in RESULT_KEYS},
    }


def held_out_line(summary):
    """``'  held out (calibrator) 0.0042 mm, 95 %: 0.0017-0.0067 mm: the validation's 0.0029
    mm lies inside'``: the calibrator's held-out accuracy and its interval (``accuracy`` of
    ``result.json``) beside the validation after calibration; '' without one."""
    position = ((summary.get('accuracy') or {}).get('calibrated') or {}).get('position_mm')
    if not position:
        return ''
    line = f'  held out (calibrator) {position["mean"]:.4f} mm'
    interval = position.get('mean_interval_95')
    validated = summary['validation']['after']['position_mm_mean']
    if interval and math.isfinite(validated):
        low, high = interval
        where = 'inside' if low <= validated <= high else 'OUTSIDE'
        line += f", 95 %: {low:.4f}-{high:.4f} mm: the validation's {validated:.4f} mm lies {where}"
    return line


def summary_text(summary, validated, rejected):
    """Human-readable lines of ``summary``."""
    before, after = summary['validation']['before'], summary['validation']['after']
    lines = [
        f'validation over {validated} postures ({rejected} rejected by the platform):',
        '                    position mm (mean / max)   orientation deg (mean / max)',
    ]
    for label, values in (('before (nominal)', before), ('after (calibrated)', after)):
        lines.append(
            f'  {label:<18}{values["position_mm_mean"]:>10.4f} / {values["position_mm_max"]:<10.4f}'
            f'{values["orientation_deg_mean"]:>14.5f} / {values["orientation_deg_max"]:.5f}'
        )
    held_out = held_out_line(summary)
    lines += [held_out] if held_out else []
    lines += [
        f'parameter errors vs the true geometry: max {summary["max_param_error_mm"]:.4f} mm, '
        f'gamma {summary["max_param_error_deg"]:.5f} deg',
        f'identification time: {summary["identification_ms"]:.0f} ms; calibration '
        f'{summary["calibration_s"]:.1f} s; total {summary["total_s"]:.1f} s',
    ]
    if summary.get('acceptance'):
        lines += summary['acceptance']['text'].splitlines()
    if summary.get('fit_diagnosis'):
        lines.append(summary['fit_diagnosis'])
    return '\n'.join(lines)
