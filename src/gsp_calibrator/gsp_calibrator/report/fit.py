"""The verdict, accuracy, sensor errors, goodness of fit, outliers and noise estimates of
``result.json``, ``report.md`` and the service's response (docs/verdict.md)."""

import math

from gsp_kinematics.estimation.identification import DATUM_SENSOR_PARAMETERS
from gsp_kinematics.model.geometry import (
    ANGULAR_SENSOR_PARAMETERS,
    PARAMETER_NAMES,
    SENSOR_PARAMETER_NAMES,
)
from gsp_kinematics.model.sensor_noise import NOISE_UNITS

#: The verdict's next step when the plain model leaves an error unexplained (no effect group
#: freed, ``auto`` not asked): the platform's effects can be modelled (docs/verdict.md).
EFFECTS_HINT = (
    'to model the effects behind it (load, backlash, warming, joint axes): free_parameters '
    '[auto] chooses them from the data; give payload_mass (kg the legs carry) for the load '
    '(docs/platform_effects.md)'
)


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


def outcome_data(outcome):
    """The ``result.json`` keys of a ``run.identify.CalibrationOutcome`` beside the fit's: the
    verdict, accuracy, unmodelled error, noise and goodness-of-fit verdict."""
    judgement, requirement = outcome.judgement, outcome.requirement
    acceptance = None
    if judgement is not None:
        acceptance = {**judgement.as_dict(), 'requirement': requirement.as_dict()}
    rigid = outcome.rigid_judgement  # the rigid geometry's (run.rigid.judge_rigid)
    return {
        'accepted': outcome.accepted,
        'acceptance': acceptance,
        'accuracy': outcome.accuracy,
        'rigid_acceptance': None if rigid is None else rigid.as_dict(),
        'rigid_accuracy': outcome.rigid_accuracy,
        'unmodelled': unmodelled_record(outcome.unmodelled),
        'noise_source': outcome.noise_source,
        'noise_estimates': outcome.noise_estimates,
        'fit_accepted': outcome.fit_accepted,
        'fit_diagnosis': outcome.fit_diagnosis or None,
        'effects': outcome.effects,  # report.effects.effects_record
    }


def unmodelled_record(unmodelled):
    """``{leg_lengths_um, inclinometer_urad, encoder_urad, lvdt_um}`` (rms per row) or None."""
    if unmodelled is None:
        return None
    units = {'leg_lengths': 'um', 'inclinometer': 'urad', 'encoder': 'urad', 'lvdt': 'um'}
    return {f'{name}_{units[name]}': 1e6 * value for name, value in unmodelled.channels().items()}


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


def _sensor_error_table(data):
    rows = []
    for name, entry in (data.get('sensor_errors') or {}).items():
        degrees = entry['unit'] == 'rad'
        factor, unit = (math.degrees(1.0), 'deg') if degrees else (1.0, '1')
        nominal = entry.get('nominal')
        deviation = entry.get('standard_deviation')
        fixed = 'no (datum)' if name in DATUM_SENSOR_PARAMETERS else 'no'
        rows.append(
            [
                name,
                unit,
                'yes' if entry['free'] else fixed,
                _fmt(None if nominal is None else nominal * factor),
                _fmt(entry['estimate'] * factor),
                _fmt(None if deviation is None else deviation * factor, 3),
            ]
        )
    return ('table', ['parameter', 'unit', 'free', 'nominal', 'estimate', '1σ'], rows)


def _interval(interval):
    """``'0.0017-0.0067'`` of a held-out figure's ``mean_interval_95``; a dash without one."""
    if not interval:
        return '–'
    return f'{_fmt(interval[0], 2)}-{_fmt(interval[1], 2)}'


def _accuracy_table(data):
    """Cross-validated accuracy of the calibrated and nominal geometries, and the prediction."""
    accuracy = data.get('accuracy')
    if not accuracy:
        return None
    where = ', workspace postures' if accuracy.get('measured_on') == 'workspace' else ''
    labelled = [
        (f'calibrated (held out{where})', accuracy['calibrated']),
        ('nominal geometry', accuracy['nominal']),
    ]
    if accuracy.get('selected'):
        selected = accuracy['selected']['calibrated']
        labelled.append(('calibrated (held out, selected postures)', selected))
    if data.get('rigid_accuracy'):
        labelled.append(('rigid geometry (held out)', data['rigid_accuracy']['calibrated']))
    rows = []
    for label, entry in labelled:
        p, phi = entry['position_mm'], entry['phi_deg']
        cells = [_fmt(v, 3) for v in (p['mean'], p['p95'], phi['mean'], phi['p95'])]
        interval = _interval(p.get('mean_interval_95'))
        rows.append([label, cells[0], interval, *cells[1:], _fmt(p['measured_mean'], 3)])
    predicted = data.get('predicted_accuracy') or {}
    if predicted.get('position_mm_mean') is not None:
        mean, p95 = _fmt(predicted['position_mm_mean'], 3), _fmt(predicted['position_mm_p95'], 3)
        rows.append(['predicted (workspace)', mean, '–', p95, '–', '–', '–'])
    header = ['accuracy', 'position mean (mm)', 'its 95 % interval (mm)', 'position p95 (mm)']
    header += ['phi mean (deg)', 'phi p95 (deg)', 'measured position mean, noise included (mm)']
    return ('table', header, rows)


def _goodness_lines(data):
    fit = data.get('goodness_of_fit')
    blocks = [('heading', 'Goodness of fit (a diagnostic)')]
    if fit:
        if fit.get('test') == 'lack_of_fit':
            test = (
                f'lack-of-fit F test (noise estimated from the run): F '
                f'{_fmt(fit["f_statistic"], 4)} for ({_fmt(fit["dof"])}, '
                f'{_fmt(fit["pure_error_dof"])})'
            )
        else:
            test = f'chi2 {_fmt(fit["chi2"])} for {_fmt(fit["dof"])}'
        loss = data.get('loss', 'linear')
        text = f'{test} degrees of freedom, p = {_fmt(fit["p_value"], 3)} (loss: {loss})'
        blocks.append(('line', text))
    if data.get('fit_diagnosis'):
        blocks.append(('line', data['fit_diagnosis']))
    return blocks


def _noise_table(data):
    noise = data.get('noise_estimates') or {}
    if not noise:
        return []
    used = data.get('noise_source', 'configured')
    rows = []
    for channel, entry in noise.items():
        angular = NOISE_UNITS[channel] == 'rad'
        factor = math.degrees(1.0) if angular else 1e3
        keys = ('configured', 'estimated', 'within_posture', 'between_postures')
        shown = [_fmt(None if entry.get(k) is None else entry[k] * factor, 3) for k in keys]
        unmodelled = entry.get('unmodelled') or 0.0
        lower = ' (within: lower bound)' if entry.get('within_lower_bound') else ''
        source = entry.get('source', '') + lower
        warning = 'WARNING: differs by more than 2x' if entry.get('warning') else ''
        unit = 'urad' if angular else 'um'
        rows.append([channel, *shown, _fmt(unmodelled * 1e6, 3), unit, source, warning])
    line = (
        f'weights from the {used} noise (noise_source); per-sample noise (an averaged row '
        "times sqrt(samples)); 'unmodelled' per row, which averaging does not reduce"
    )
    header = ['sensor noise', 'configured', 'estimated (the noise)', 'within postures']
    header += ['between postures', 'unmodelled', 'unit of unmodelled', 'source', '']
    return [('line', line), ('table', header, rows)]


def fit_summary(data):
    """The fit summary of ``result.json`` ``data`` as blocks ``('heading', text)``, ``('line',
    text)`` and ``('table', header, rows)``, for :func:`as_text` and :func:`as_markdown`."""
    blocks = [('heading', 'Verdict')]
    acceptance = data.get('acceptance')
    if acceptance:
        blocks += [('line', line) for line in acceptance['text'].splitlines()]
    if data.get('rigid_acceptance'):
        blocks += [('line', line) for line in data['rigid_acceptance']['text'].splitlines()]
    if data.get('unmodelled') and not data.get('effects'):
        blocks.append(('line', EFFECTS_HINT))
    accuracy = _accuracy_table(data)
    if accuracy:
        blocks.append(accuracy)
    blocks += _goodness_lines(data)
    if data.get('outliers'):
        rows = [
            [
                entry['posture'],
                _fmt(entry['max_studentised_residual'], 3),
                entry['sensor'],
                _fmt(entry.get('neighbour_deviation'), 3),
            ]
            for entry in data['outliers']
        ]
        header = [
            'outlier posture',
            'largest studentised residual',
            'sensor',
            'deviation from its neighbours',
        ]
        blocks.append(('table', header, rows))
    if data.get('down_weighted'):
        rows = [[e['posture'], _fmt(e['weight'], 3)] for e in data['down_weighted']]
        blocks.append(('table', [f'{data.get("loss")} loss down-weighted posture', 'weight'], rows))
    return blocks + _noise_table(data)


def as_markdown(blocks):
    """``report.md`` lines of :func:`fit_summary` blocks (the first line of a section in bold)."""
    lines = []
    bold = False
    for block in blocks:
        if block[0] == 'heading':
            lines += ['', f'## {block[1]}', '']
            bold = True
        elif block[0] == 'line':
            lines += [f'**{block[1]}**' if bold else block[1], '']
            bold = False
        else:
            _, header, rows = block
            lines += ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
            lines += ['| ' + ' | '.join(str(v) for v in row) + ' |' for row in rows]
            lines.append('')
    return lines


def as_text(blocks):
    """Plain-text lines of :func:`fit_summary` blocks (headings left out; a table row is
    ``first column: header value, ...``)."""
    lines = []
    for block in blocks:
        if block[0] == 'line':
            lines.append(block[1])
        elif block[0] == 'table':
            _, header, rows = block
            for row in rows:
                pairs = ', '.join(
                    f'{name} {value}'.strip()
                    for name, value in zip(header[1:], row[1:], strict=True)
                    if value not in ('', '–')
                )
                lines.append(f'{header[0]} {row[0]}: {pairs}')
    return lines


def fit_markdown(data):
    """The sensor errors and the fit summary of ``report.md``."""
    return (
        ['## Sensor errors', '']
        + as_markdown([_sensor_error_table(data)])
        + as_markdown(fit_summary(data))
    )
