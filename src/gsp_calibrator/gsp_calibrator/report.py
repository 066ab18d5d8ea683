"""``result.json`` and ``report.md`` (with PNG plots) of a calibration run (pure, no rclpy).

* :func:`write_result_json`: estimates (SI and report units), standard deviations, correlations
  above 0.9, identifiability (rank, condition number, unidentifiable combinations), residual RMS
  per sensor, iterations, status, validation errors before and after.
* :func:`write_report`: ``report.md`` and its plots: ``parameter_errors.png`` (the paper's
  Figs. 6-8), ``chain_errors.png`` (Figs. 9-12), ``residuals.png`` (histograms per sensor) and
  ``validation.png`` (error distributions before and after, when a validation is given).

Parameter errors are taken against the true geometry when one is given (simulation), otherwise
the plots show the correction (estimate - nominal). Report units: mm, and deg for gamma.
Every file is written atomically; plots use matplotlib's Agg canvas directly (headless, no
pyplot state), and matplotlib is imported only when a report is written.
"""

import io
import math
import os

import numpy as np

from gsp_kinematics.geometry import (
    ANGULAR_PARAMETERS,
    NUM_LEGS,
    PARAMETER_CHAIN,
    PARAMETER_NAMES,
    default_geometry,
    to_report_units,
)

from .run_directory import atomic_write_bytes, atomic_write_text, to_json

RESULT_JSON = 'result.json'
REPORT_MD = 'report.md'
PARAMETER_ERRORS_PNG = 'parameter_errors.png'
CHAIN_ERRORS_PNG = 'chain_errors.png'
RESIDUALS_PNG = 'residuals.png'
VALIDATION_PNG = 'validation.png'

CORRELATION_THRESHOLD = 0.9
VALIDATION_KEYS = ('position_mm_mean', 'position_mm_max', 'orientation_deg_mean',
                   'orientation_deg_max')
_ANGULAR = set(ANGULAR_PARAMETERS)
_SENSOR_KIND = {'leg_lengths': 'length', 'alpha': 'angle', 'beta': 'angle', 'phi': 'angle',
                'd_m': 'length'}
_SENSOR_LABEL = {'leg_lengths': 'leg lengths q1..q6', 'alpha': 'inclinometer alpha',
                 'beta': 'inclinometer beta', 'phi': 'encoder phi', 'd_m': 'LVDT d_m'}
_BEFORE_COLOUR = '#d62728'
_AFTER_COLOUR = '#1f77b4'
_CORRECTION_COLOUR = '#2ca02c'


# --- helpers -----------------------------------------------------------------------------------


def _report_unit(index):
    return 'deg' if index in _ANGULAR else 'mm'


def _si_unit(index):
    return 'rad' if index in _ANGULAR else 'm'


def _finite_or_none(value):
    value = float(value)
    return value if math.isfinite(value) else None


def _clean(data):
    """JSON-safe copy: numpy to Python, non-finite floats to None (strict JSON has no NaN)."""
    if isinstance(data, dict):
        return {str(k): _clean(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_clean(v) for v in data]
    if isinstance(data, np.ndarray):
        return _clean(data.tolist())
    if isinstance(data, (bool, np.bool_)):
        return bool(data)
    if isinstance(data, (int, np.integer)):
        return int(data)
    if isinstance(data, (float, np.floating)):
        return _finite_or_none(data)
    return data


def _by_name(values, mask=None):
    return {name: (_finite_or_none(values[i]) if mask is None or mask[i] else None)
            for i, name in enumerate(PARAMETER_NAMES)}


def _path(run_dir, name):
    return os.path.join(os.fspath(run_dir), name)


def analyse(result):
    """The core's identifiability analysis of ``result`` (``None`` if it cannot be computed)."""
    from gsp_kinematics.identifiability import analyse_identifiability

    try:
        return analyse_identifiability(result.information, result.free)
    except (ValueError, np.linalg.LinAlgError):
        return None


def _identifiability(analysis):
    """Normalised identifiability: unidentifiable combinations as text and parameter names."""
    if not analysis:
        return None
    entries = []
    for entry in analysis.get('unidentifiable', []) or []:
        if isinstance(entry, dict):
            entries.append({'combination': entry.get('combination', ''),
                            'parameters': list(entry.get('parameters', [])),
                            'coefficients': list(entry.get('coefficients', []))})
        else:  # a plain parameter name
            entries.append({'combination': str(entry), 'parameters': [str(entry)],
                            'coefficients': [1.0]})
    size = analysis.get('parameters', analysis.get('size'))
    return {
        'rank': analysis.get('rank'),
        'parameters': size,
        'condition_number': analysis.get('condition_number'),
        'singular_values': analysis.get('singular_values'),
        'unidentifiable': entries,
        'unidentifiable_parameters': sorted({p for e in entries for p in e['parameters']}),
    }


def _validation_summary(validation):
    """``{position_mm_mean, ..., postures}`` of a validation (summary dict or per-posture arrays)."""
    if validation is None:
        return None
    summary = {k: validation[k] for k in VALIDATION_KEYS if k in validation}
    position, orientation = _validation_arrays(validation)
    if position is not None and len(position):
        summary.setdefault('position_mm_mean', float(np.mean(position)))
        summary.setdefault('position_mm_max', float(np.max(position)))
    if orientation is not None and len(orientation):
        summary.setdefault('orientation_deg_mean', float(np.mean(orientation)))
        summary.setdefault('orientation_deg_max', float(np.max(orientation)))
    for key in ('postures', 'unreachable'):
        if key in validation:
            summary[key] = validation[key]
    if 'postures' not in summary and position is not None:
        summary['postures'] = len(position)
    return summary


def _validation_arrays(validation):
    if validation is None:
        return None, None
    position = validation.get('position_mm')
    orientation = validation.get('orientation_deg')
    position = None if position is None else np.asarray(position, dtype=float).reshape(-1)
    orientation = None if orientation is None else np.asarray(orientation, dtype=float).reshape(-1)
    return position, orientation


def validation_errors(true, controller, poses):
    """Per-posture validation of ``controller`` against the real platform ``true`` (simulation).

    ``{'position_mm': [...], 'orientation_deg': [...], <the summary keys>, 'postures',
    'unreachable'}``: the arrays that :func:`write_report` plots as distributions.
    """
    from gsp_kinematics.kinematics import forward_kinematics_masked, inverse_kinematics
    from gsp_kinematics.validation import pose_errors, summarise

    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    reached, converged = forward_kinematics_masked(true, inverse_kinematics(controller, poses),
                                                   poses)
    if not converged.any():
        raise ValueError('no validation posture is reachable by the real platform')
    position, orientation = pose_errors(poses[converged], reached[converged])
    out = summarise(position, orientation)
    out.update(position_mm=position.tolist(), orientation_deg=orientation.tolist(),
               postures=int(converged.sum()), unreachable=int((~converged).sum()))
    return out


def _errors(result, truth, nominal):
    """``(reference kind, before, after, sigma)`` per parameter in report units."""
    estimate = np.asarray(result.parameters, dtype=float)
    sigma = to_report_units(np.nan_to_num(result.standard_deviations, nan=0.0))
    sigma = np.where(np.asarray(result.free, dtype=bool), sigma, np.nan)
    if truth is not None:
        reference = truth.to_vector()
        return ('truth', to_report_units(nominal.to_vector() - reference),
                to_report_units(estimate - reference), sigma)
    return 'nominal', np.zeros(len(PARAMETER_NAMES)), \
        to_report_units(estimate - nominal.to_vector()), sigma


def _residual_columns(result):
    """``[(sensor, columns), ...]`` of ``result.residuals`` (weighted), in column order."""
    residuals = np.asarray(result.residuals, dtype=float)
    if residuals.ndim != 2 or not result.residual_rms:
        return []
    layout, column = [], 0
    for sensor in result.residual_rms:
        width = 6 if sensor == 'leg_lengths' else 1
        layout.append((sensor, list(range(column, column + width))))
        column += width
    if column != residuals.shape[1]:
        return []
    return layout


def residuals_by_sensor(result):
    """``{sensor: residuals in SI (m or rad)}`` (1-D arrays, finite values only).

    The core returns residuals weighted by each sensor's sigma and the per-sensor RMS in SI;
    the sigma is their ratio, so the weights need not be known here.
    """
    residuals = np.asarray(result.residuals, dtype=float)
    out = {}
    for sensor, columns in _residual_columns(result):
        weighted = residuals[:, columns].reshape(-1)
        weighted = weighted[np.isfinite(weighted)]
        rms_weighted = float(np.sqrt(np.mean(weighted**2))) if weighted.size else 0.0
        rms_si = float(result.residual_rms.get(sensor, float('nan')))
        if rms_weighted > 0.0 and math.isfinite(rms_si):
            out[sensor] = weighted * (rms_si / rms_weighted)
        else:
            out[sensor] = np.zeros_like(weighted)
    return out


def _residual_scale(kind, values):
    """``(factor, unit)`` so that the residuals read as numbers between ~0.1 and ~1000."""
    rms = float(np.sqrt(np.mean(np.square(values)))) if len(values) else 0.0
    if kind == 'length':
        options = ((1e3, 'mm'), (1e6, 'µm'), (1e9, 'nm'))
    else:
        options = ((math.degrees(1.0), 'deg'), (math.degrees(1.0) * 1e3, 'mdeg'),
                   (math.degrees(1.0) * 1e6, 'µdeg'))
    for factor, unit in options:
        if rms * factor >= 0.1:
            return factor, unit
    return options[-1]


# --- result.json -------------------------------------------------------------------------------


def result_data(result, analysis=None, validation_before=None, validation_after=None,
                truth=None, nominal=None, sigmas=None, extra=None):
    """The ``result.json`` content (a JSON-safe dict); see :func:`write_result_json`."""
    nominal = default_geometry('nominal') if nominal is None else nominal
    if analysis is None:
        analysis = analyse(result)
    free = np.asarray(result.free, dtype=bool)
    estimate = np.asarray(result.parameters, dtype=float)
    deviations = np.asarray(result.standard_deviations, dtype=float)
    reference, before, after, _ = _errors(result, truth, nominal)
    correlations = []
    try:
        with np.errstate(invalid='ignore', divide='ignore'):
            pairs = result.correlations(CORRELATION_THRESHOLD)
        correlations = [{'a': a, 'b': b, 'correlation': r} for a, b, r in pairs]
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        pass
    residual_rms = {}
    for sensor, value in (result.residual_rms or {}).items():
        kind = _SENSOR_KIND.get(sensor, 'length')
        factor, unit = (1e6, 'um') if kind == 'length' else (math.degrees(1.0), 'deg')
        residual_rms[sensor] = {'si': value, 'si_unit': 'm' if kind == 'length' else 'rad',
                                'report': float(value) * factor, 'report_unit': unit}
    data = {
        'formulation': result.formulation,
        'converged': bool(result.converged),
        'status': int(result.status),
        'message': result.message,
        'iterations': int(result.iterations),
        'cost': result.cost,
        'duration_s': result.duration_s,
        'postures': int(np.asarray(result.poses).shape[0]) if result.poses is not None else None,
        'excluded_postures': list(result.excluded_postures or []),
        'free_parameters': [n for n, f in zip(PARAMETER_NAMES, free, strict=True) if f],
        'units': {
            'si': {n: _si_unit(i) for i, n in enumerate(PARAMETER_NAMES)},
            'report': {n: _report_unit(i) for i, n in enumerate(PARAMETER_NAMES)},
        },
        'estimates': {'si': _by_name(estimate), 'report': _by_name(to_report_units(estimate))},
        'standard_deviations': {
            'si': _by_name(deviations, free),
            'report': _by_name(to_report_units(np.nan_to_num(deviations)), free),
        },
        'nominal': {'si': _by_name(nominal.to_vector()),
                    'report': _by_name(to_report_units(nominal.to_vector()))},
        'parameter_errors': {
            'reference': reference,
            'unit': 'report',
            'before': _by_name(before),
            'after': _by_name(after),
        },
        'correlation_threshold': CORRELATION_THRESHOLD,
        'correlations': correlations,
        'identifiability': _identifiability(analysis),
        'residual_rms': residual_rms,
        'validation': {'before': _validation_summary(validation_before),
                       'after': _validation_summary(validation_after)},
    }
    lengths = np.array([i not in _ANGULAR for i in range(len(PARAMETER_NAMES))])
    data['max_param_error_mm'] = float(np.max(np.abs(after[lengths])))
    data['max_param_error_deg'] = float(np.max(np.abs(after[~lengths])))
    if sigmas is not None:
        data['sigmas'] = {'leg_lengths_m': sigmas.leg_lengths,
                          'inclinometer_rad': sigmas.inclinometer,
                          'encoder_rad': sigmas.encoder, 'lvdt_m': sigmas.lvdt}
    if extra:
        data.update(extra)
    return _clean(data)


def write_result_json(run_dir, result, analysis=None, validation_before=None,
                      validation_after=None, truth=None, nominal=None, sigmas=None, extra=None):
    """Write ``run_dir/result.json`` atomically; returns its path.

    ``result``: the core's ``IdentificationResult``. ``analysis``: an identifiability analysis
    (computed with ``gsp_kinematics.identifiability`` when None). ``validation_before`` /
    ``validation_after``: ``gsp_kinematics.validation.validate`` summaries, or
    :func:`validation_errors` dicts (per-posture arrays). ``truth``: the true geometry, if known
    (errors are then against it; else corrections against ``nominal``). ``nominal`` defaults to
    the shipped nominal geometry. ``sigmas``: the weights used. ``extra``: more top-level keys.
    Non-finite numbers are written as ``null``.
    """
    data = result_data(result, analysis, validation_before, validation_after, truth, nominal,
                       sigmas, extra)
    path = _path(run_dir, RESULT_JSON)
    atomic_write_text(path, to_json(data))
    return path


# --- plots -------------------------------------------------------------------------------------


def _figure(width, height, **adjust):
    """A figure on an Agg canvas (no pyplot, no GUI); ``adjust``: its subplot margins."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    # Fixed margins rather than a layout engine: a constrained layout doubles the drawing time.
    figure = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(figure)
    figure.subplots_adjust(**adjust)
    return figure


def _save(figure, path):
    buffer = io.BytesIO()
    figure.savefig(buffer, format='png', dpi=100, pil_kwargs={'compress_level': 3})
    atomic_write_bytes(path, buffer.getvalue())
    return path


def plot_parameter_errors(path, result, truth=None, nominal=None):
    """Each parameter's error before (nominal) and after (estimate), with 1-sigma bars."""
    nominal = default_geometry('nominal') if nominal is None else nominal
    reference, before, after, sigma = _errors(result, truth, nominal)
    free = np.asarray(result.free, dtype=bool)
    lengths = [i for i in range(len(PARAMETER_NAMES)) if i not in _ANGULAR]
    angles = sorted(_ANGULAR)
    rows = 2 if reference == 'truth' else 1
    figure = _figure(15, 4.4 * rows, left=0.06, right=0.99, top=1 - 0.3 / (4.4 * rows),
                     bottom=0.9 / (4.4 * rows), wspace=0.2,
                     hspace=1.0 / 4.4 if rows > 1 else 0.2)
    grid = figure.add_gridspec(rows, 2, width_ratios=[len(lengths), 4])

    def panel(axes, indices, values, label, colour, marker, bars, unit, zero_line=True):
        x = np.arange(len(indices))
        if bars:
            err = np.where(free[indices], sigma[indices], 0.0)
            axes.errorbar(x, values[indices], yerr=err, fmt=marker, color=colour, ms=6,
                          capsize=3, label=label + ' ± 1σ', linestyle='none')
        else:
            axes.plot(x, values[indices], marker, color=colour, ms=6, label=label,
                      linestyle='none')
        if zero_line:
            axes.axhline(0.0, color='0.4', lw=0.8)
        axes.set_xticks(x)
        axes.set_xticklabels([PARAMETER_NAMES[i] for i in indices], rotation=90, fontsize=8)
        axes.set_ylabel(f'error ({unit})' if reference == 'truth' else f'correction ({unit})')
        axes.grid(True, axis='y', alpha=0.3)
        for position, index in enumerate(indices):
            if not free[index]:
                axes.axvspan(position - 0.5, position + 0.5, color='0.9', zorder=0)

    if reference == 'truth':
        title = 'Parameter errors against the true geometry'
        main = figure.add_subplot(grid[0, 0])
        side = figure.add_subplot(grid[0, 1])
        for axes, indices, unit in ((main, lengths, 'mm'), (side, angles, 'deg')):
            panel(axes, indices, before, 'before (nominal − true)', _BEFORE_COLOUR, 'o', False,
                  unit)
            panel(axes, indices, after, 'after (estimate − true)', _AFTER_COLOUR, 'x', True, unit)
        main.set_title(title + ': before and after calibration')
        side.set_title('gamma')
        main.legend(loc='upper right', fontsize=8)
        zoom = figure.add_subplot(grid[1, 0])
        zoom_side = figure.add_subplot(grid[1, 1])
        for axes, indices, unit in ((zoom, lengths, 'mm'), (zoom_side, angles, 'deg')):
            panel(axes, indices, after, 'after (estimate − true)', _AFTER_COLOUR, 'x', True, unit)
        zoom.set_title('After calibration (zoom), error bars: 1σ from the covariance')
        zoom_side.set_title('gamma (after)')
        zoom.legend(loc='upper right', fontsize=8)
    else:
        main = figure.add_subplot(grid[0, 0])
        side = figure.add_subplot(grid[0, 1])
        for axes, indices, unit in ((main, lengths, 'mm'), (side, angles, 'deg')):
            panel(axes, indices, after, 'estimate − nominal', _CORRECTION_COLOUR, 'x', True, unit)
        main.set_title('Parameter corrections against the nominal geometry (no true geometry '
                       'known)')
        side.set_title('gamma')
        main.legend(loc='upper right', fontsize=8)
    figure.axes[-2].set_xlabel('parameter (grey band: fixed, not identified)')
    return _save(figure, path)


def chain_errors(result, truth=None, nominal=None):
    """``(reference, before, after)``: (3, 6) arrays of |A_i|, |B_i|, |Loff_i| errors in mm."""
    nominal = default_geometry('nominal') if nominal is None else nominal
    reference, before, after, _ = _errors(result, truth, nominal)
    chains = np.array([c if c is not None else 0 for c in PARAMETER_CHAIN])

    def norms(values):
        out = np.zeros((3, NUM_LEGS))
        for leg in range(1, NUM_LEGS + 1):
            for row, prefix in enumerate(('A', 'B', 'Loff')):
                mask = np.array([chains[i] == leg and n.startswith(prefix)
                                 for i, n in enumerate(PARAMETER_NAMES)])
                out[row, leg - 1] = float(np.linalg.norm(values[mask]))
        return out

    return reference, norms(before), norms(after)


def plot_chain_errors(path, result, truth=None, nominal=None):
    """Per-leg (kinematic chain) error norms of A_i, B_i and Loff_i before and after."""
    reference, before, after = chain_errors(result, truth, nominal)
    figure = _figure(13, 4.4, left=0.06, right=0.99, top=0.86, bottom=0.12, wspace=0.3)
    legs = np.arange(1, NUM_LEGS + 1)
    titles = ('base joint |ΔA_i|', 'platform joint |ΔB_i|', 'leg offset |ΔLoff_i|')
    width = 0.38
    for row, title in enumerate(titles):
        axes = figure.add_subplot(1, 3, row + 1)
        if reference == 'truth':
            bars_before = axes.bar(legs - width / 2, before[row], width, color=_BEFORE_COLOUR,
                                   label='before (nominal)')
            bars_after = axes.bar(legs + width / 2, after[row], width, color=_AFTER_COLOUR,
                                  label='after (calibrated)')
            values = np.concatenate([before[row], after[row]])
            axes.set_ylabel('error norm against the truth (mm)')
        else:
            bars_before = None
            bars_after = axes.bar(legs, after[row], 2 * width, color=_CORRECTION_COLOUR,
                                  label='correction (estimate − nominal)')
            values = after[row]
            axes.set_ylabel('correction norm (mm)')
        positive = values[values > 0]
        if positive.size and positive.max() / positive.min() > 30:
            axes.set_yscale('log')
        for bars in (bars_before, bars_after):
            if bars is not None:
                axes.bar_label(bars, fmt='%.2g', fontsize=6, rotation=90, padding=2)
        axes.set_xticks(legs)
        axes.set_xlabel('leg (kinematic chain) i')
        axes.set_title(title)
        axes.grid(True, axis='y', alpha=0.3)
        axes.legend(fontsize=8, loc='best')
    figure.suptitle('Errors in the kinematic chains' + (
        ' before and after calibration' if reference == 'truth'
        else ': corrections (no true geometry known)'))
    return _save(figure, path)


def plot_residuals(path, result):
    """Histogram of the identification residuals of each sensor, in physical units."""
    by_sensor = residuals_by_sensor(result)
    count = max(len(by_sensor), 1)
    columns = min(count, 3)
    rows = int(math.ceil(count / columns))
    figure = _figure(4.6 * columns, 3.8 * rows, left=0.08, right=0.98,
                     top=1 - 0.8 / (3.8 * rows), bottom=0.5 / (3.8 * rows), wspace=0.3,
                     hspace=1.1 / 3.8 if rows > 1 else 0.2)
    if not by_sensor:
        axes = figure.add_subplot(1, 1, 1)
        axes.text(0.5, 0.5, 'no residuals (identification failed)', ha='center', va='center')
        axes.set_axis_off()
        return _save(figure, path)
    for k, (sensor, values) in enumerate(by_sensor.items()):
        axes = figure.add_subplot(rows, columns, k + 1)
        factor, unit = _residual_scale(_SENSOR_KIND.get(sensor, 'length'), values)
        scaled = values * factor
        bins = int(np.clip(np.sqrt(scaled.size) * 2, 10, 60))
        axes.hist(scaled, bins=bins, color=_AFTER_COLOUR, alpha=0.8,
                  label=f'{scaled.size} residuals')
        rms = float(np.sqrt(np.mean(scaled**2))) if scaled.size else 0.0
        axes.axvline(rms, color=_BEFORE_COLOUR, ls='--', lw=1, label=f'± RMS {rms:.3g} {unit}')
        axes.axvline(-rms, color=_BEFORE_COLOUR, ls='--', lw=1)
        axes.set_xlabel(f'residual at the solution ({unit})')
        axes.set_ylabel('count')
        axes.set_title(_SENSOR_LABEL.get(sensor, sensor))
        axes.legend(fontsize=8)
        axes.grid(True, alpha=0.3)
    figure.suptitle(f'Identification residuals at the solution ({result.formulation} '
                    'formulation)')
    return _save(figure, path)


def plot_validation(path, validation_before, validation_after):
    """Validation error distributions (position mm, orientation deg) before and after."""
    figure = _figure(11, 4.4, left=0.08, right=0.98, top=0.86, bottom=0.08, wspace=0.25)
    series = (('before', validation_before, _BEFORE_COLOUR),
              ('after', validation_after, _AFTER_COLOUR))
    quantities = (('position', 'position_mm', 'position error (mm)'),
                  ('orientation', 'orientation_deg', 'orientation error (deg)'))
    for column, (name, key, label) in enumerate(quantities):
        axes = figure.add_subplot(1, 2, column + 1)
        drawn = []
        for position, (when, validation, colour) in enumerate(series):
            if validation is None:
                continue
            arrays = dict(zip(('position_mm', 'orientation_deg'),
                              _validation_arrays(validation), strict=True))
            values = arrays[key]
            if values is not None and values.size:
                parts = axes.violinplot(np.maximum(values, 1e-12), positions=[position],
                                        showmeans=False, showextrema=False)
                for body in parts['bodies']:
                    body.set_facecolor(colour)
                    body.set_alpha(0.35)
                jitter = (np.random.default_rng(0).random(values.size) - 0.5) * 0.2
                axes.plot(position + jitter, np.maximum(values, 1e-12), '.', color=colour,
                          ms=4, label=f'{when}: {values.size} postures')
                axes.plot([position - 0.3, position + 0.3], [np.mean(values)] * 2, '-',
                          color='k', lw=1.5)
                drawn.extend(values[values > 0].tolist())
            else:
                summary = _validation_summary(validation)
                mean = summary.get(f'{key}_mean')
                top = summary.get(f'{key}_max')
                if mean is None:
                    continue
                axes.bar(position, top if top is not None else mean, 0.5, color=colour,
                         alpha=0.35, label=f'{when}: max')
                axes.plot([position - 0.25, position + 0.25], [mean] * 2, '-', color='k', lw=1.5)
                drawn.extend(v for v in (mean, top) if v)
        positive = [v for v in drawn if v > 0]
        if positive and max(positive) / min(positive) > 30:
            axes.set_yscale('log')
        axes.set_xticks([0, 1])
        axes.set_xticklabels(['before calibration', 'after calibration'])
        axes.set_xlim(-0.6, 1.6)
        axes.set_ylabel(label)
        axes.set_title(f'{name.capitalize()} error (black line: mean)')
        axes.grid(True, axis='y', alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(fontsize=8)
    figure.suptitle('Validation: commanded pose versus where the platform really goes')
    return _save(figure, path)


# --- report.md ---------------------------------------------------------------------------------


def _fmt(value, digits=4):
    if value is None:
        return '–'
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(value):
        return '∞' if value > 0 else ('–' if math.isnan(value) else '−∞')
    return f'{value:.{digits}g}'


def report_markdown(data, images, title='Calibration report'):
    """``report.md`` text from :func:`result_data` output and ``{kind: file name}`` of plots."""
    lines = [f'# {title}', '']
    lines.append(f"- status: {'converged' if data['converged'] else 'NOT converged'} "
                 f"(status {data['status']}: {data['message']})")
    lines.append(f"- formulation: {data['formulation']}; postures: {data['postures']}; "
                 f"free parameters: {len(data['free_parameters'])}; iterations: "
                 f"{data['iterations']}; identification time: "
                 f"{_fmt((data.get('duration_s') or 0.0) * 1000.0, 3)} ms")
    if data.get('excluded_postures'):
        lines.append(f"- excluded postures (FK failed): {data['excluded_postures']}")
    identifiability = data.get('identifiability')
    if identifiability:
        lines.append(f"- identifiability: rank {identifiability['rank']} of "
                     f"{identifiability['parameters']}, scaled condition number "
                     f"{_fmt(identifiability['condition_number'])}")
        for entry in identifiability['unidentifiable']:
            lines.append(f"  - not identifiable: `{entry['combination']}`")
    lines.append('')
    validation = data.get('validation') or {}
    if validation.get('before') or validation.get('after'):
        lines += ['## Validation', '',
                  '| | position mean (mm) | position max (mm) | orientation mean (deg) '
                  '| orientation max (deg) | postures |',
                  '|---|---|---|---|---|---|']
        for when in ('before', 'after'):
            summary = validation.get(when)
            if summary:
                lines.append(f'| {when} | ' + ' | '.join(_fmt(summary.get(k)) for k in
                                                       VALIDATION_KEYS)
                             + f" | {summary.get('postures', '–')} |")
        lines.append('')
        if 'validation' in images:
            lines += [f"![validation errors before and after]({images['validation']})", '']
    errors = data['parameter_errors']
    against_truth = errors['reference'] == 'truth'
    lines += ['## Parameters', '']
    if against_truth:
        lines.append(f"Errors against the true geometry. Largest after calibration: "
                     f"{_fmt(data['max_param_error_mm'])} mm, gamma "
                     f"{_fmt(data['max_param_error_deg'])} deg.")
    else:
        lines.append('No true geometry is known: the corrections (estimate − nominal) are shown.')
    lines.append('')
    if 'parameter_errors' in images:
        lines += [f"![parameter errors]({images['parameter_errors']})", '']
    if 'chain_errors' in images:
        lines += [f"![kinematic chain errors]({images['chain_errors']})", '']
    header = ('| parameter | unit | nominal | estimate | 1σ | '
              + ('error before | error after |' if against_truth else 'correction |'))
    lines += [header, '|' + '---|' * (header.count('|') - 1)]
    units = data['units']['report']
    for name in PARAMETER_NAMES:
        row = [name, units[name], _fmt(data['nominal']['report'][name], 7),
               _fmt(data['estimates']['report'][name], 7),
               _fmt(data['standard_deviations']['report'][name], 3)]
        if against_truth:
            row += [_fmt(errors['before'][name], 3), _fmt(errors['after'][name], 3)]
        else:
            row.append(_fmt(errors['after'][name], 3))
        lines.append('| ' + ' | '.join(row) + ' |')
    lines.append('')
    lines += [f"## Correlations above {data['correlation_threshold']}", '']
    if data['correlations']:
        lines += ['| a | b | correlation |', '|---|---|---|']
        lines += [f"| {c['a']} | {c['b']} | {_fmt(c['correlation'], 4)} |"
                  for c in data['correlations']]
    else:
        lines.append('None.')
    lines.append('')
    lines += ['## Residuals', '', '| sensor | RMS | unit |', '|---|---|---|']
    for sensor, rms in data['residual_rms'].items():
        lines.append(f"| {_SENSOR_LABEL.get(sensor, sensor)} | {_fmt(rms['report'])} | "
                     f"{rms['report_unit']} |")
    lines.append('')
    if 'residuals' in images:
        lines += [f"![residual histograms]({images['residuals']})", '']
    return '\n'.join(lines) + '\n'


def write_report(run_dir, result, analysis=None, validation_before=None, validation_after=None,
                 truth=None, nominal=None, sigmas=None, extra=None, title='Calibration report'):
    """Write ``report.md`` and its PNGs into ``run_dir`` (atomic); returns ``{kind: path}``.

    Same arguments as :func:`write_result_json`. The validation plot is drawn when a validation
    is given (distributions from per-posture arrays, else the mean and max of the summaries).
    """
    data = result_data(result, analysis, validation_before, validation_after, truth, nominal,
                       sigmas, extra)
    written = {}
    written['parameter_errors'] = plot_parameter_errors(
        _path(run_dir, PARAMETER_ERRORS_PNG), result, truth, nominal)
    written['chain_errors'] = plot_chain_errors(_path(run_dir, CHAIN_ERRORS_PNG), result, truth,
                                                nominal)
    written['residuals'] = plot_residuals(_path(run_dir, RESIDUALS_PNG), result)
    if validation_before is not None or validation_after is not None:
        written['validation'] = plot_validation(_path(run_dir, VALIDATION_PNG),
                                                validation_before, validation_after)
    images = {kind: os.path.basename(path) for kind, path in written.items()}
    text = report_markdown(data, images, title)
    written['report'] = _path(run_dir, REPORT_MD)
    atomic_write_text(written['report'], text)
    return written


def write_all(run_dir, result, **kwargs):
    """:func:`write_result_json` and :func:`write_report`; returns ``{kind: path}``."""
    paths = {'result_json': write_result_json(run_dir, result, **{
        k: v for k, v in kwargs.items() if k != 'title'})}
    paths.update(write_report(run_dir, result, **kwargs))
    return paths
