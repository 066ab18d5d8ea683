"""The sensor errors, goodness of fit, outliers and noise estimates of ``result.json`` and
``report.md`` (docs/sensor_errors.md)."""

import math

from gsp_kinematics.geometry import (
    ANGULAR_SENSOR_PARAMETERS,
    PARAMETER_NAMES,
    SENSOR_PARAMETER_NAMES,
)
from gsp_kinematics.identification import DATUM_SENSOR_PARAMETERS
from gsp_kinematics.sensors.noise import NOISE_UNITS


def format_number(value, digits=4):
    """``value`` with ``digits`` significant digits; a dash for None or NaN."""
    if value is None:
        return '–'
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(value):
        return '∞' if value > 0 else ('–' if math.isnan(value) else '−∞')
    return f'{value:.{digits}g}'


_fmt = format_number


def _free_text(name, free):
    if free:
        return 'yes'
    return 'no (datum)' if name in DATUM_SENSOR_PARAMETERS else 'no'


def fit_data(result, truth=None, nominal=None):
    """``sensor_errors``, ``goodness_of_fit``, ``loss``, ``outliers`` and ``down_weighted`` keys
    of ``result.json`` (docs/sensor_errors.md)."""
    sensor_errors = {}
    for index, name in enumerate(SENSOR_PARAMETER_NAMES, start=len(PARAMETER_NAMES)):
        free = bool(result.free[index])
        entry = {
            'unit': 'rad' if name in ANGULAR_SENSOR_PARAMETERS else '1',
            'free': free,
            'estimate': float(result.parameters[index]),
            'standard_deviation': float(result.standard_deviations[index]) if free else None,
        }
        if nominal is not None:
            entry['nominal'] = float(nominal.to_full_vector()[index])
        if truth is not None:
            entry['truth'] = float(truth.to_full_vector()[index])
        sensor_errors[name] = entry
    fit = result.goodness_of_fit
    return {
        'sensor_errors': sensor_errors,
        'goodness_of_fit': None
        if fit is None
        else {**fit.as_dict(), 'excluded_outlier_postures': list(fit.excluded_postures)},
        'loss': result.loss,
        'outliers': list(result.outliers),
        'down_weighted': list(result.down_weighted),
    }


def fit_markdown(data):
    """The sensor errors, goodness of fit, outliers and noise estimates of ``report.md``."""
    lines = ['## Sensor errors', '', '| parameter | unit | free | nominal | estimate | 1σ |']
    lines.append('|---|---|---|---|---|---|')
    for name, entry in (data.get('sensor_errors') or {}).items():
        degrees = entry['unit'] == 'rad'
        factor, unit = (math.degrees(1.0), 'deg') if degrees else (1.0, '1')
        nominal = entry.get('nominal')
        deviation = entry.get('standard_deviation')
        lines.append(
            f'| {name} | {unit} | {_free_text(name, entry["free"])} | '
            f'{_fmt(None if nominal is None else nominal * factor)} | '
            f'{_fmt(entry["estimate"] * factor)} | '
            f'{_fmt(None if deviation is None else deviation * factor, 3)} |'
        )
    lines += ['', '## Goodness of fit', '']
    fit = data.get('goodness_of_fit')
    if fit:
        loss = data.get('loss', 'linear')
        if fit.get('test') == 'lack_of_fit':
            lines.append(
                f'Lack-of-fit F test (noise estimated from the run): F '
                f'{_fmt(fit["f_statistic"], 4)} for ({_fmt(fit["dof"])}, '
                f'{_fmt(fit["pure_error_dof"])}) degrees of freedom, p = '
                f'{_fmt(fit["p_value"], 3)} (loss: {loss}).'
            )
        else:
            lines.append(
                f'chi2 {_fmt(fit["chi2"])} for {_fmt(fit["dof"])} degrees of freedom, p = '
                f'{_fmt(fit["p_value"], 3)} (loss: {loss}).'
            )
    if data.get('verdict'):
        lines += ['', f'**{data["verdict"]}**']
    if data.get('fit_accepted') is False:
        lines += ['', 'The result is written but marked REJECTED and not applied.']
    if data.get('outliers'):
        lines += [
            '',
            '| outlier posture | largest studentised residual | sensor |',
            '|---|---|---|',
        ]
        for entry in data['outliers']:
            lines.append(
                f'| {entry["posture"]} | {_fmt(entry["max_studentised_residual"], 3)} | '
                f'{entry["sensor"]} |'
            )
    if data.get('down_weighted'):
        lines += ['', '| down-weighted posture | weight |', '|---|---|']
        lines += [f'| {e["posture"]} | {_fmt(e["weight"], 3)} |' for e in data['down_weighted']]
    noise = data.get('noise_estimates') or {}
    if noise:
        used = data.get('noise_source', 'configured')
        lines += [
            '',
            f'Weights from the {used} noise. Per-sample equivalents (the noise of an averaged row '
            'times sqrt(samples)):',
            '',
            '| sensor noise | configured | estimated | within postures | between postures | '
            'source | unit |',
            '|---|---|---|---|---|---|---|',
        ]
        for channel, entry in noise.items():
            angular = NOISE_UNITS[channel] == 'rad'
            factor, unit = (math.degrees(1.0), 'deg') if angular else (1e3, 'mm')
            values = [entry.get(key) for key in ('configured', 'estimated', 'within_posture')] + [
                entry.get('between_postures')
            ]
            shown = ' | '.join(_fmt(None if v is None else v * factor, 3) for v in values)
            source = entry.get('source', '') + (
                ' (within: lower bound)' if entry.get('within_lower_bound') else ''
            )
            lines.append(f'| {channel} | {shown} | {source} | {unit} |')
    return lines + ['']
