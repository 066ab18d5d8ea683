"""What ``gsp_demo`` measured and reports (pure): validation summaries and per-posture errors,
parameter errors against the truth, the ``summary.json`` document (:class:`DemoSummary`) and its
text."""

import contextlib
import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from gsp_calibrator.report.data import VALIDATION_KEYS
from gsp_calibrator.report.write import RESULT_JSON
from gsp_kinematics.model.geometry import parameter_errors
from gsp_kinematics.model.validation import pose_errors, summarise


def validation_summary(commanded, reached):
    """Mean and max errors (mm, deg) over the rows of ``reached`` without NaN."""
    commanded, reached = np.asarray(commanded), np.asarray(reached)
    keep = np.all(np.isfinite(reached), axis=1)
    if not keep.any():
        return {key: math.nan for key in VALIDATION_KEYS}
    position_mm, orientation_deg = pose_errors(commanded[keep], reached[keep])
    return summarise(position_mm, orientation_deg)


def validation_details(commanded, reached):
    """:func:`validation_summary` plus the per-posture errors ``position_mm`` and
    ``orientation_deg`` and their commanded ``poses`` (lists, rows of ``reached`` without NaN), for
    the run's report (the accuracy map overlays them)."""
    commanded, reached = np.asarray(commanded), np.asarray(reached)
    details = dict(validation_summary(commanded, reached))
    keep = np.all(np.isfinite(reached), axis=1)
    if keep.any():
        position_mm, orientation_deg = pose_errors(commanded[keep], reached[keep])
        details['position_mm'] = np.asarray(position_mm, dtype=float).tolist()
        details['orientation_deg'] = np.asarray(orientation_deg, dtype=float).tolist()
        details['poses'] = commanded[keep].tolist()
    details['postures'] = int(keep.sum())
    return details


def parameter_error_maxima(calibrated, true):
    """``(max |error| of the 43 lengths in mm, |gamma error| in deg)``."""
    errors = parameter_errors(calibrated, true)
    return float(np.max(np.abs(errors[:43]))), float(abs(errors[43]))


@dataclasses.dataclass(frozen=True)
class DemoSummary:
    """What ``summary.json`` records of a demo run (:meth:`document`)."""

    before: dict  #: validation summary with the nominal controller
    after: dict  #: validation summary with the calibrated controller
    calibrated: object  #: the calibrated Geometry
    true: object  #: the true Geometry
    identification_ms: float
    calibration_s: float
    total_s: float
    run_directory: object = None  #: its path
    #: The calibrator's record of skipped postures and dropped samples, or None.
    collection: dict | None = None
    fit: dict | None = None  #: :func:`fit_record` (goodness of fit, noise estimates, verdict)

    def document(self):
        """The ``summary.json`` document (keys as in issue 3, plus ``run_directory``,
        ``collection`` and the :data:`FIT_KEYS`)."""
        max_mm, max_deg = parameter_error_maxima(self.calibrated, self.true)
        return {
            'validation': {'before': dict(self.before), 'after': dict(self.after)},
            'max_param_error_mm': max_mm,
            'max_param_error_deg': max_deg,
            'identification_ms': float(self.identification_ms),
            'calibration_s': float(self.calibration_s),
            'total_s': float(self.total_s),
            'run_directory': None if self.run_directory is None else str(self.run_directory),
            'collection': self.collection,
            **{key: (self.fit or {}).get(key) for key in FIT_KEYS},
        }


#: Keys of the calibrator's ``result.json`` that ``summary.json`` repeats.
FIT_KEYS = (
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


def fit_record(run_directory):
    """``{key: value}`` of :data:`FIT_KEYS` in the calibrator's ``result.json`` ({} if absent)."""
    with contextlib.suppress(OSError, ValueError):
        data = json.loads((Path(run_directory) / RESULT_JSON).read_text())
        return {key: data.get(key) for key in FIT_KEYS}
    return {}


def collection_record(run_directory):
    """The ``collection`` record of the calibrator's ``result.json`` in ``run_directory`` (None if
    absent). Read before the report is refreshed, which rewrites ``result.json``."""
    with contextlib.suppress(OSError, ValueError):
        record = json.loads((Path(run_directory) / RESULT_JSON).read_text()).get('collection')
        return record if isinstance(record, dict) else None
    return None


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


# --- main ----------------------------------------------------------------------------------------
