"""``result.json`` and ``report.md`` (with PNG plots) of a calibration run (pure, no rclpy).
See docs/data.md#resultjson."""

import dataclasses
import functools
import math
import os

import numpy as np

from gsp_calibrator.report.accuracy import (
    ACCURACY_MAP_PNG,
    HELD_OUT_PNG,
    markdown_lines,
    plot_accuracy_map,
    plot_held_out,
    prediction_for,
    result_json_entry,
)
from gsp_calibrator.report.data import (
    ANGULAR,
    SENSOR_KIND,
    SENSOR_LABEL,
    VALIDATION_KEYS,
    by_name,
    identifiability_record,
    parameter_error_table,
    settle_line,
    validation_summary,
)
from gsp_calibrator.report.effects import effects_markdown
from gsp_calibrator.report.fit import fit_data, fit_markdown, format_number, outcome_data
from gsp_calibrator.report.plots import (
    plot_chain_errors,
    plot_parameter_errors,
    plot_residuals,
    plot_validation,
)
from gsp_kinematics.estimation.identifiability import analyse_result
from gsp_kinematics.fileio import atomic_write_text, json_safe, to_json
from gsp_kinematics.model.geometry import PARAMETER_NAMES, default_geometry, to_report_units

RESULT_JSON = 'result.json'
REPORT_MD = 'report.md'
PARAMETER_ERRORS_PNG = 'parameter_errors.png'
CHAIN_ERRORS_PNG = 'chain_errors.png'
RESIDUALS_PNG = 'residuals.png'
VALIDATION_PNG = 'validation.png'

CORRELATION_THRESHOLD = 0.9

#: The scalar fields of an ``IdentificationResult`` that ``result.json`` holds as they are.
_RESULT_FIELDS = (
    'formulation',
    'converged',
    'status',
    'message',
    'iterations',
    'cost',
    'duration_s',
)


@dataclasses.dataclass(frozen=True)
class ReportInputs:
    """What a report shows besides the core's ``IdentificationResult`` (each optional)."""

    analysis: dict | None = None  #: the result's identifiability (``analyse_result``)
    #: ``validate`` summaries, or :func:`.data.validation_errors` dicts (per-posture arrays)
    validation_before: dict | None = None
    validation_after: dict | None = None
    truth: object = None  #: the true geometry, if known (else corrections against nominal)
    nominal: object = None  #: default: the shipped nominal geometry
    sigmas: object = None  #: the ``SensorNoise`` weights used
    extra: dict | None = None  #: more top-level keys of result.json
    prediction: dict | None = None  #: :func:`.accuracy.prediction_for` of the result
    unmodelled: object = None  #: the model's ``unmodelled_error``, in the prediction

    def completed(self, result):
        """These inputs with the analysis and the prediction of ``result`` computed where None
        (once, for result.json and report.md alike)."""
        analysis = analyse_result(result) if self.analysis is None else self.analysis
        prediction = self.prediction
        compare = self.validation_after is not None and 'validation' not in (prediction or {})
        if prediction is None or compare:
            prediction = prediction_for(
                result, self.validation_after, analysis=analysis, unmodelled=self.unmodelled
            )
        return dataclasses.replace(self, analysis=analysis, prediction=prediction)


def result_data(result, inputs=ReportInputs()):
    """The ``result.json`` content (a JSON-safe dict) of the core's ``IdentificationResult``
    ``result`` with :class:`ReportInputs` ``inputs``."""
    inputs = inputs.completed(result)
    analysis, truth = inputs.analysis, inputs.truth
    nominal = default_geometry('nominal') if inputs.nominal is None else inputs.nominal
    count = len(PARAMETER_NAMES)
    free = np.asarray(result.free, dtype=bool)[:count]
    estimate = np.asarray(result.parameters, dtype=float)[:count]
    deviations = np.asarray(result.standard_deviations, dtype=float)[:count]
    reference, before, after, _ = parameter_error_table(result, truth, nominal)
    correlations = []
    try:
        with np.errstate(invalid='ignore', divide='ignore'):
            pairs = result.correlations(CORRELATION_THRESHOLD)
        correlations = [{'a': a, 'b': b, 'correlation': r} for a, b, r in pairs]
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        pass
    residual_rms = {}
    for sensor, value in (result.residual_rms or {}).items():
        length = SENSOR_KIND.get(sensor, 'length') == 'length'
        factor, unit, si = (1e6, 'um', 'm') if length else (math.degrees(1.0), 'deg', 'rad')
        report = float(value) * factor
        residual_rms[sensor] = {'si': value, 'si_unit': si, 'report': report, 'report_unit': unit}
    data = {name: getattr(result, name) for name in _RESULT_FIELDS}
    data |= {
        'postures': int(np.asarray(result.poses).shape[0]) if result.poses is not None else None,
        'excluded_postures': list(result.excluded_postures or []),
        'free_parameters': list(result.free_names),
        'units': {
            'si': {n: 'rad' if i in ANGULAR else 'm' for i, n in enumerate(PARAMETER_NAMES)},
            'report': {n: 'deg' if i in ANGULAR else 'mm' for i, n in enumerate(PARAMETER_NAMES)},
        },
        'estimates': {'si': by_name(estimate), 'report': by_name(to_report_units(estimate))},
        'standard_deviations': {
            'si': by_name(deviations, free),
            'report': by_name(to_report_units(np.nan_to_num(deviations)), free),
        },
        'nominal': {
            'si': by_name(nominal.to_vector()),
            'report': by_name(to_report_units(nominal.to_vector())),
        },
        'parameter_errors': {
            'reference': reference,
            'unit': 'report',
            'before': by_name(before),
            'after': by_name(after),
        },
        'covariance': {'parameters': list(result.free_names), 'si': result.covariance},
        'correlation_threshold': CORRELATION_THRESHOLD,
        'correlations': correlations,
        'identifiability': identifiability_record(analysis),
        'residual_rms': residual_rms,
        'validation': {
            'before': validation_summary(inputs.validation_before),
            'after': validation_summary(inputs.validation_after),
        },
        'predicted_accuracy': result_json_entry(inputs.prediction),
    }
    lengths = np.array([i not in ANGULAR for i in range(len(PARAMETER_NAMES))])
    data['max_param_error_mm'] = float(np.max(np.abs(after[lengths])))
    data['max_param_error_deg'] = float(np.max(np.abs(after[~lengths])))
    data.update(fit_data(result, truth, nominal))
    if inputs.sigmas is not None:
        data['sigmas'] = inputs.sigmas.channels()
    if inputs.extra:
        data.update(inputs.extra)
    return json_safe(data)


def outcome_inputs(outcome, nominal, options, **extra):
    """The :class:`ReportInputs` of a ``run.identify.CalibrationOutcome``, with ``options`` and
    ``extra`` (e.g. the calibrator's ``collection``) among result.json's keys."""
    return ReportInputs(
        analysis=outcome.identifiability or None,
        nominal=nominal,
        sigmas=outcome.sigmas,
        prediction=outcome.prediction,
        unmodelled=outcome.unmodelled,
        extra={
            'success': outcome.success,
            'failure': outcome.message or None,
            'options': options,
            **outcome_data(outcome),
            **extra,
        },
    )


def write_result_json(run_dir, result, inputs=ReportInputs()):
    """Write ``run_dir/result.json`` atomically (see :func:`result_data`); returns its path.
    Non-finite numbers are written as ``null``."""
    path = os.path.join(run_dir, RESULT_JSON)
    atomic_write_text(path, to_json(result_data(result, inputs)))
    return path


# --- report.md ---------------------------------------------------------------------------------


def _validation_lines(data, images):
    """The ``## Validation`` section of ``report.md`` (none without a validation)."""
    validation = data.get('validation') or {}
    if not (validation.get('before') or validation.get('after')):
        return []
    lines = [
        '## Validation',
        '',
        '| | position mean (mm) | position max (mm) | orientation mean (deg) '
        '| orientation max (deg) | postures |',
        '|---|---|---|---|---|---|',
    ]
    for when in ('before', 'after'):
        summary = validation.get(when)
        if summary:
            numbers = ' | '.join(format_number(summary.get(k)) for k in VALIDATION_KEYS)
            lines.append(f'| {when} | {numbers} | {summary.get("postures", "–")} |')
    lines.append('')
    if 'validation' in images:
        lines += [f'![validation errors before and after]({images["validation"]})', '']
    return lines


def _parameter_lines(data, images):
    """The ``## Parameters`` section of ``report.md``: errors against the truth, or corrections."""
    errors = data['parameter_errors']
    against_truth = errors['reference'] == 'truth'
    lines = ['## Parameters', '']
    if against_truth:
        lines.append(
            f'Errors against the true geometry. Largest after calibration: '
            f'{format_number(data["max_param_error_mm"])} mm, gamma '
            f'{format_number(data["max_param_error_deg"])} deg.'
        )
    else:
        lines.append('No true geometry is known: the corrections (estimate − nominal) are shown.')
    lines.append('')
    if 'parameter_errors' in images:
        lines += [f'![parameter errors]({images["parameter_errors"]})', '']
    if 'chain_errors' in images:
        lines += [f'![kinematic chain errors]({images["chain_errors"]})', '']
    header = '| parameter | unit | nominal | estimate | 1σ | ' + (
        'error before | error after |' if against_truth else 'correction |'
    )
    lines += [header, '|' + '---|' * (header.count('|') - 1)]
    units = data['units']['report']
    shown = ('before', 'after') if against_truth else ('after',)
    for name in PARAMETER_NAMES:
        row = [
            name,
            units[name],
            format_number(data['nominal']['report'][name], 7),
            format_number(data['estimates']['report'][name], 7),
            format_number(data['standard_deviations']['report'][name], 3),
        ]
        row += [format_number(errors[when][name], 3) for when in shown]
        lines.append('| ' + ' | '.join(row) + ' |')
    lines.append('')
    return lines


#: The line of ``report.md`` written in place of the plots when they were not drawn.
PLOTS_SKIPPED_NOTE = (
    '- plots: skipped (write_report_plots false, or --no-plots); '
    '`gsp_reidentify <run directory>` writes a report with them'
)


def report_markdown(data, images, title='Calibration report', plots=True):
    """``report.md`` text from :func:`result_data` output and ``{kind: file name}`` of plots;
    ``plots=False``: the report says its plots were not drawn."""
    status = 'converged' if data['converged'] else 'NOT converged'
    milliseconds = format_number((data.get('duration_s') or 0.0) * 1000.0, 3)
    lines = [
        f'# {title}',
        '',
        f'- status: {status} (status {data["status"]}: {data["message"]})',
        f'- formulation: {data["formulation"]}; postures: {data["postures"]}; free parameters: '
        f'{len(data["free_parameters"])}; iterations: {data["iterations"]}; identification '
        f'time: {milliseconds} ms',
    ]
    if data.get('excluded_postures'):
        lines.append(f'- excluded postures (FK failed): {data["excluded_postures"]}')
    identifiability = data.get('identifiability')
    if identifiability:
        lines.append(
            f'- identifiability: rank {identifiability["rank"]} of '
            f'{identifiability["parameters"]}, scaled condition number '
            f'{format_number(identifiability["condition_number"])}'
        )
        for entry in identifiability['unidentifiable']:
            lines.append(f'  - not identifiable: `{entry["combination"]}`')
    settle = settle_line((data.get('collection') or {}).get('settle'))
    if settle:
        lines.append(f'- {settle}')
    if not plots:
        lines.append(PLOTS_SKIPPED_NOTE)
    lines.append('')
    lines += _validation_lines(data, images)
    lines += _parameter_lines(data, images)
    lines += fit_markdown(data)
    lines += effects_markdown(data.get('effects'))
    if 'held_out' in images:
        lines += [f'![accuracy measured on held-out postures]({images["held_out"]})', '']
    lines += [f'## Correlations above {data["correlation_threshold"]}', '']
    if data['correlations']:
        lines += ['| a | b | correlation |', '|---|---|---|']
        lines += [
            f'| {c["a"]} | {c["b"]} | {format_number(c["correlation"], 4)} |'
            for c in data['correlations']
        ]
    else:
        lines.append('None.')
    lines.append('')
    lines += markdown_lines(data.get('predicted_accuracy'), images.get('accuracy_map'))
    lines += ['## Residuals', '', '| sensor | RMS | unit |', '|---|---|---|']
    for sensor, rms in data['residual_rms'].items():
        label = SENSOR_LABEL.get(sensor, sensor)
        lines.append(f'| {label} | {format_number(rms["report"])} | {rms["report_unit"]} |')
    lines.append('')
    if 'residuals' in images:
        lines += [f'![residual histograms]({images["residuals"]})', '']
    return '\n'.join(lines) + '\n'


def write_report(run_dir, result, inputs=ReportInputs(), title='Calibration report', plots=True):
    """Write ``report.md`` and its PNGs into ``run_dir`` (atomic); returns ``{kind: path}``."""
    inputs = inputs.completed(result)
    data = result_data(result, inputs)
    written = _write_plots(run_dir, result, inputs) if plots else {}
    images = {kind: os.path.basename(path) for kind, path in written.items()}
    text = report_markdown(data, images, title, plots)
    written['report'] = os.path.join(run_dir, REPORT_MD)
    atomic_write_text(written['report'], text)
    return written


def _write_plots(run_dir, result, inputs):
    """The PNGs of :func:`write_report` (``inputs`` completed); returns ``{kind: path}``."""
    truth, nominal, prediction = inputs.truth, inputs.nominal, inputs.prediction
    before, after = inputs.validation_before, inputs.validation_after
    path = functools.partial(os.path.join, run_dir)
    written = {
        'parameter_errors': plot_parameter_errors(
            path(PARAMETER_ERRORS_PNG), result, truth, nominal
        ),
        'chain_errors': plot_chain_errors(path(CHAIN_ERRORS_PNG), result, truth, nominal),
        'residuals': plot_residuals(path(RESIDUALS_PNG), result),
    }
    if before is not None or after is not None:
        written['validation'] = plot_validation(path(VALIDATION_PNG), before, after)
    extra = inputs.extra or {}
    if extra.get('accuracy'):
        required = ((extra.get('acceptance') or {}).get('requirement') or {}).get('position_mm')
        predicted = (prediction or {}).get('random', {}).get('position_mm', {}).get('mean')
        written['held_out'] = plot_held_out(
            path(HELD_OUT_PNG), extra['accuracy'], predicted, required
        )
    if prediction is not None:
        written['accuracy_map'] = plot_accuracy_map(path(ACCURACY_MAP_PNG), prediction)
    return written


def write_all(run_dir, result, inputs=ReportInputs(), title='Calibration report', plots=True):
    """:func:`write_result_json` and :func:`write_report` (``plots``: draw its PNGs); returns
    ``{kind: path}``."""
    inputs = inputs.completed(result)  # the analysis and prediction once for both files
    paths = {'result_json': write_result_json(run_dir, result, inputs)}
    paths.update(write_report(run_dir, result, inputs, title, plots))
    return paths
