"""The text of a calibration run (pure): each posture's report, the outcome summary, and the
Trigger response (a human summary, then the calibrated geometry's params file) and its parser."""

import dataclasses
import math

import numpy as np

from gsp_kinematics.channels import (
    DEVICE_CHANNELS,
    LEG_LENGTHS,
    PHI_READING_COLUMN,
    READING_NAMES,
)
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import (
    ALL_PARAMETER_NAMES,
    ANGULAR_SENSOR_PARAMETERS,
    NUM_PARAMETERS,
    geometry_to_yaml,
    parameter_errors,
)
from gsp_kinematics.model.kinematics import inverse_kinematics
from gsp_kinematics.rotation import wrap_angle
from gsp_msgs_py.names import PHASE_COLLECTING, PHASE_MOVING

#: Comment of the calibrated geometry: its file, the latched result and the response.
RESULT_COMMENT = 'calibrated by gsp_calibrator'
RESPONSE_SEPARATOR = '--- calibrated geometry (ROS 2 parameters file) ---'
RUN_DIRECTORY_LABEL = 'run directory: '
IDENTIFICATION_TIME_LABEL = 'identification time: '


def sensor_error_text(result):
    """``'kq1 +3.1e-04 (sd 2e-05), alpha0 +0.0101 deg (sd 0.0004)'`` of the free sensor errors."""
    parts = []
    for index, name in enumerate(ALL_PARAMETER_NAMES[NUM_PARAMETERS:], start=NUM_PARAMETERS):
        if not result.free[index]:
            continue
        value, deviation = result.parameters[index], result.standard_deviations[index]
        if name in ANGULAR_SENSOR_PARAMETERS:
            parts.append(
                f'{name} {math.degrees(value):+.4f} deg (sd {math.degrees(deviation):.2g})'
            )
        else:
            parts.append(f'{name} {value:+.2e} (sd {deviation:.1g})')
    return ', '.join(parts)


def fit_lines(outcome):
    """The fit summary of a successful ``outcome`` as text lines (``report.fit.fit_summary``)."""
    from gsp_calibrator.report.accuracy import result_json_entry
    from gsp_calibrator.report.fit import as_text, fit_data, fit_summary, outcome_data

    data = {
        **fit_data(outcome.result),
        **outcome_data(outcome),
        'predicted_accuracy': result_json_entry(outcome.prediction),
    }
    return as_text(fit_summary(data))


def posture_residuals(nominal, commanded_pose, leg_lengths, readings):
    """Measured minus the nominal model at the commanded pose: ``{sensor: value}`` (m, rad)."""
    pose = np.reshape(np.asarray(commanded_pose, dtype=float), (1, 6))
    legs = np.asarray(leg_lengths, dtype=float) - inverse_kinematics(nominal, pose)[0]
    device = np.asarray(readings, dtype=float) - device_readings(nominal, pose)[0]
    device[PHI_READING_COLUMN] = wrap_angle(device[PHI_READING_COLUMN])
    residuals = {LEG_LENGTHS: float(np.max(np.abs(legs)))}
    residuals.update({name: float(v) for name, v in zip(READING_NAMES, device, strict=True)})
    return residuals


def report_posture_end(event, count, nominal, log, progress):
    """Log (``log``: a logger) and publish (``progress``: :attr:`.host.RunHost.progress`) the end
    of a posture of a run of ``count`` postures: a protocol ``RowReady`` (its residuals under the
    ``nominal`` geometry) or ``PostureSkipped``."""
    k = event.posture
    if not hasattr(event, 'sample'):  # skipped
        log.warning(f'posture {k}/{count} skipped: {event.reason}')
        text = f'posture {k} of {count} skipped: {event.reason}'
        progress(k, PHASE_MOVING, text, None, True, skipped=k)
        return
    row = event.sample
    if event.dropped:
        log.warning(
            f'posture {k}/{count}: dropped {event.dropped} synchronised sample(s) '
            'inconsistent with the rest (glitch, or a stream still reporting the '
            'previous posture)'
        )
    log.info(f'posture {k}/{count}: {row.n_samples} samples averaged')
    residuals = posture_residuals(nominal, event.pose, row.leg_lengths, row.readings)
    progress(
        k, PHASE_COLLECTING, f'posture {k} of {count}: {row.n_samples} samples averaged', residuals
    )


#: The device readings that are angles (rad), summarised in degrees.
ANGLE_READINGS = tuple(channel.name for channel in DEVICE_CHANNELS if channel.unit == 'rad')


def residual_summary(residual_rms):
    """``'legs 0.06 um, alpha 0.0003 deg, ...'`` of per-sensor residual RMS (m, rad)."""
    parts = []
    for name, value in residual_rms.items():
        if name in ANGLE_READINGS:
            parts.append(f'{name} {math.degrees(value):.2g} deg')
        else:
            parts.append(f'{"legs" if name == LEG_LENGTHS else name} {value * 1e6:.3g} um')
    return ', '.join(parts)


#: Head of the summary of a calibration that does not meet the requirement (not applied).
NOT_ACCEPTED_HEAD = 'calibration NOT ACCEPTED'


def final_progress_message(summary, success, note):
    """The last progress message of a run that identified: the summary's head, or the ``note``
    of a failed apply (the text agrees with the phase)."""
    head = summary.splitlines()[0] if summary else ''
    return head if success or not note else note


def accuracy_headline(outcome):
    """``'; accuracy 0.048 mm held out (95 %: 0.039-0.061 mm; nominal 13.6 mm, predicted
    0.045 mm)'`` of an outcome's cross-validation ('' without one)."""
    accuracy = outcome.accuracy
    if not accuracy:
        return ''
    calibrated = accuracy['calibrated']['position_mm']
    nominal = accuracy['nominal']['position_mm']['mean']
    where = ' on workspace postures' if accuracy.get('measured_on') == 'workspace' else ''
    text = f'; accuracy {calibrated["mean"]:.3g} mm held out{where} ('
    low, high = calibrated.get('mean_interval_95') or (math.nan, math.nan)
    if math.isfinite(low) and math.isfinite(high):
        text += f'95 %: {low:.2g}-{high:.2g} mm; '
    text += f'nominal {nominal:.3g} mm'
    prediction = (outcome.prediction or {}).get('random')
    if prediction:
        text += f', predicted {prediction["position_mm"]["mean"]:.3g} mm'
    return text + ')'


def outcome_summary(outcome, selected=None, skipped=(), run_directory=None, reference=None):
    """Human summary lines of a calibration (str, no trailing newline)."""
    lines = []
    head = 'calibration FAILED'
    if outcome.success:
        # A calibration that does not meet the requirement is not applied: the head must not
        # say 'succeeded' above a failed phase (the client's last progress line is this head).
        head = 'calibration succeeded' if outcome.accepted else NOT_ACCEPTED_HEAD
    used = f'{outcome.postures} posture(s)' + (f' of {selected} commanded' if selected else '')
    lines.append(f'{head}: {used}{accuracy_headline(outcome)}')
    if not outcome.success:
        lines.append(f'reason: {outcome.message}')
    for k, reason in skipped:
        lines.append(f'skipped posture {k}: {reason}')
    result = outcome.result
    if result is not None:
        lines.append(
            f'{result.formulation} formulation, {int(np.sum(result.free))} free parameter(s), '
            f'{result.iterations} iteration(s): {result.message}'
        )
        lines.append(f'{IDENTIFICATION_TIME_LABEL}{outcome.duration_s * 1000.0:.1f} ms')
        if result.residual_rms:
            lines.append(f'residual rms: {residual_summary(result.residual_rms)}')
    if outcome.identifiability:
        condition = outcome.identifiability.get('condition_number', math.inf)
        lines.append(
            f'identifiability: rank {outcome.identifiability.get("rank")} of '
            f'{outcome.identifiability.get("parameters")}, scaled condition number '
            f'{condition:.4g}'
        )
    if outcome.success:  # a result, then
        deviations = result.standard_deviations
        free = np.asarray(result.free, dtype=bool)
        lengths = deviations[:43][free[:43]]
        if lengths.size:
            lines.append(
                f'largest standard deviation: {np.nanmax(lengths) * 1000.0:.4g} mm'
                + (f', gamma {math.degrees(deviations[43]):.3g} deg' if free[43] else '')
            )
        sensor_text = sensor_error_text(result)
        if sensor_text:
            lines.append(f'sensor errors: {sensor_text}')
        lines.extend(fit_lines(outcome))
    if outcome.result is not None:
        from gsp_calibrator.report.effects import effects_lines

        lines.extend(effects_lines(outcome.effects))
    if outcome.success and reference is not None:
        errors = parameter_errors(outcome.geometry, reference)
        lines.append(
            f'parameter errors vs reference: max {np.max(np.abs(errors[:43])):.4g} mm, '
            f'gamma {abs(errors[43]):.3g} deg'
        )
    if run_directory is not None:
        lines.append(f'{RUN_DIRECTORY_LABEL}{run_directory}')
    return '\n'.join(lines)


def failure_message(error, collected, run):
    """The response of a run (``run``: its ``RunDirectory``) that ended early with ``error``."""
    from gsp_calibrator.files.run_directory import SAMPLES_FILE

    return (
        f'calibration FAILED after {collected} collected posture(s): {error}\n'
        f'{collected} posture(s) saved to {run.file(SAMPLES_FILE)}\n'
        f'{RUN_DIRECTORY_LABEL}{run.path}'
    )


def format_response(summary, geometry=None, node_name='/**'):
    """Trigger response message: the summary, then (on success) the geometry params file."""
    if geometry is None:
        return summary
    yaml_text = geometry_to_yaml(geometry, node_name=node_name, comment=RESULT_COMMENT)
    return f'{summary}\n{RESPONSE_SEPARATOR}\n{yaml_text}'


@dataclasses.dataclass(frozen=True)
class ParsedResponse:
    """A Trigger response message split into its parts."""

    summary: str
    geometry_yaml: str  #: '' when the response carries no geometry
    run_directory: str  #: '' when not named
    identification_ms: float  #: NaN when not given


def parse_response(message):
    """Split a calibrate response (see :func:`format_response`) into a :class:`ParsedResponse`."""
    summary, separator, geometry_yaml = message.partition('\n' + RESPONSE_SEPARATOR + '\n')
    if not separator:
        summary, geometry_yaml = message, ''
    run_directory, identification_ms = '', math.nan
    for line in summary.splitlines():
        if line.startswith(RUN_DIRECTORY_LABEL):
            run_directory = line[len(RUN_DIRECTORY_LABEL) :].strip()
        elif line.startswith(IDENTIFICATION_TIME_LABEL):
            try:
                identification_ms = float(line[len(IDENTIFICATION_TIME_LABEL) :].split()[0])
            except (ValueError, IndexError):
                pass
    return ParsedResponse(summary, geometry_yaml, run_directory, identification_ms)
