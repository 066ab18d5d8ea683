"""The PNG plots of a calibration report (pure, no rclpy; see :mod:`.write`)."""

import io
import math

import numpy as np

from gsp_calibrator.report.data import (
    ANGULAR,
    SENSOR_KIND,
    SENSOR_LABEL,
    parameter_error_table,
    residuals_by_sensor,
    validation_arrays,
    validation_summary,
)
from gsp_kinematics.fileio import atomic_write_bytes
from gsp_kinematics.model.geometry import (
    NUM_LEGS,
    PARAMETER_CHAIN,
    PARAMETER_NAMES,
    default_geometry,
)

_BEFORE_COLOUR = '#d62728'
_AFTER_COLOUR = '#1f77b4'
_CORRECTION_COLOUR = '#2ca02c'


def _residual_scale(kind, values):
    """``(factor, unit)`` so that the residuals read as numbers between ~0.1 and ~1000."""
    rms = float(np.sqrt(np.mean(np.square(values)))) if len(values) else 0.0
    deg = math.degrees(1.0)
    options = ((1e3, 'mm'), (1e6, 'µm'), (1e9, 'nm'))
    if kind != 'length':
        options = ((deg, 'deg'), (deg * 1e3, 'mdeg'), (deg * 1e6, 'µdeg'))
    for factor, unit in options:
        if rms * factor >= 0.1:
            return factor, unit
    return options[-1]


def new_figure(width, height, **adjust):
    """A figure on an Agg canvas (no pyplot, no GUI); ``adjust``: its subplot margins."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    # Fixed margins rather than a layout engine: a constrained layout doubles the drawing time.
    figure = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(figure)
    figure.subplots_adjust(**adjust)
    return figure


def rows_figure(width, row_height, rows, margins, wspace):
    """A figure of ``rows`` rows of ``row_height`` inches; ``margins``: left and right (figure
    fractions), then top, bottom and the gap between rows (inches)."""
    left, right, top_in, bottom_in, gap_in = margins
    height = row_height * rows
    return new_figure(
        width,
        height,
        left=left,
        right=right,
        top=1 - top_in / height,
        bottom=bottom_in / height,
        wspace=wspace,
        hspace=gap_in / row_height if rows > 1 else 0.2,
    )


def save_figure(figure, path):
    buffer = io.BytesIO()
    figure.savefig(buffer, format='png', dpi=100, pil_kwargs={'compress_level': 3})
    atomic_write_bytes(path, buffer.getvalue())
    return path


def plot_parameter_errors(path, result, truth=None, nominal=None):
    """Each parameter's error before (nominal) and after (estimate), with 1-sigma bars."""
    nominal = default_geometry('nominal') if nominal is None else nominal
    reference, before, after, sigma = parameter_error_table(result, truth, nominal)
    free = np.asarray(result.free, dtype=bool)
    lengths = [i for i in range(len(PARAMETER_NAMES)) if i not in ANGULAR]
    angles = sorted(ANGULAR)

    def panel(axes, indices, values, label, colour, marker, bars, unit):
        x = np.arange(len(indices))
        if bars:
            err = np.where(free[indices], sigma[indices], 0.0)
            axes.errorbar(
                x,
                values[indices],
                yerr=err,
                fmt=marker,
                color=colour,
                ms=6,
                capsize=3,
                label=label + ' ± 1σ',
                linestyle='none',
            )
        else:
            axes.plot(x, values[indices], marker, color=colour, ms=6, label=label, linestyle='none')
        axes.axhline(0.0, color='0.4', lw=0.8)
        axes.set_xticks(x)
        axes.set_xticklabels([PARAMETER_NAMES[i] for i in indices], rotation=90, fontsize=8)
        axes.set_ylabel(f'error ({unit})' if reference == 'truth' else f'correction ({unit})')
        axes.grid(True, axis='y', alpha=0.3)
        for position, index in enumerate(indices):
            if not free[index]:
                axes.axvspan(position - 0.5, position + 0.5, color='0.9', zorder=0)

    if reference == 'truth':
        after_label, after_colour = 'after (estimate − true)', _AFTER_COLOUR
        titles = (
            'Parameter errors against the true geometry: before and after calibration',
            'After calibration (zoom), error bars: 1σ from the covariance',
        )
    else:
        after_label, after_colour = 'estimate − nominal', _CORRECTION_COLOUR
        titles = ('Parameter corrections against the nominal geometry (no true geometry known)',)
    figure = rows_figure(15, 4.4, len(titles), margins=(0.06, 0.99, 0.3, 0.9, 1.0), wspace=0.2)
    grid = figure.add_gridspec(len(titles), 2, width_ratios=[len(lengths), 4])
    for row, title in enumerate(titles):
        main = figure.add_subplot(grid[row, 0])
        side = figure.add_subplot(grid[row, 1])
        for axes, indices, unit in ((main, lengths, 'mm'), (side, angles, 'deg')):
            if reference == 'truth' and row == 0:
                label = 'before (nominal − true)'
                panel(axes, indices, before, label, _BEFORE_COLOUR, 'o', False, unit)
            panel(axes, indices, after, after_label, after_colour, 'x', True, unit)
        main.set_title(title)
        side.set_title('gamma (after)' if row else 'gamma')
        main.legend(loc='upper right', fontsize=8)
    figure.axes[-2].set_xlabel('parameter (grey band: fixed, not identified)')
    return save_figure(figure, path)


def chain_errors(result, truth=None, nominal=None):
    """``(reference, before, after)``: (3, 6) arrays of |A_i|, |B_i|, |Loff_i| errors in mm."""
    nominal = default_geometry('nominal') if nominal is None else nominal
    reference, before, after, _ = parameter_error_table(result, truth, nominal)
    legs = range(1, NUM_LEGS + 1)
    pairs = list(zip(PARAMETER_CHAIN, PARAMETER_NAMES, strict=True))
    masks = np.array(  # (3, legs, parameters): the A_i, B_i and Loff_i of each leg
        [
            [[chain == leg and name.startswith(prefix) for chain, name in pairs] for leg in legs]
            for prefix in ('A', 'B', 'Loff')
        ]
    )
    before_norms = np.linalg.norm(np.where(masks, before, 0.0), axis=-1)
    return reference, before_norms, np.linalg.norm(np.where(masks, after, 0.0), axis=-1)


def plot_chain_errors(path, result, truth=None, nominal=None):
    """Per-leg (kinematic chain) error norms of A_i, B_i and Loff_i before and after."""
    reference, before, after = chain_errors(result, truth, nominal)
    figure = new_figure(13, 4.4, left=0.06, right=0.99, top=0.86, bottom=0.12, wspace=0.3)
    legs = np.arange(1, NUM_LEGS + 1)
    titles = ('base joint |ΔA_i|', 'platform joint |ΔB_i|', 'leg offset |ΔLoff_i|')
    width = 0.38
    if reference == 'truth':
        series = (
            (before, -width / 2, width, _BEFORE_COLOUR, 'before (nominal)'),
            (after, width / 2, width, _AFTER_COLOUR, 'after (calibrated)'),
        )
        ylabel = 'error norm against the truth (mm)'
        suptitle = 'Errors in the kinematic chains before and after calibration'
    else:
        series = ((after, 0.0, 2 * width, _CORRECTION_COLOUR, 'correction (estimate − nominal)'),)
        ylabel = 'correction norm (mm)'
        suptitle = 'Errors in the kinematic chains: corrections (no true geometry known)'
    for row, title in enumerate(titles):
        axes = figure.add_subplot(1, 3, row + 1)
        for values, offset, bar_width, colour, label in series:
            bars = axes.bar(legs + offset, values[row], bar_width, color=colour, label=label)
            axes.bar_label(bars, fmt='%.2g', fontsize=6, rotation=90, padding=2)
        axes.set_ylabel(ylabel)
        shown = np.concatenate([values[row] for values, *_ in series])
        positive = shown[shown > 0]
        if positive.size and positive.max() / positive.min() > 30:
            axes.set_yscale('log')
        axes.set_xticks(legs)
        axes.set_xlabel('leg (kinematic chain) i')
        axes.set_title(title)
        axes.grid(True, axis='y', alpha=0.3)
        axes.legend(fontsize=8, loc='best')
    figure.suptitle(suptitle)
    return save_figure(figure, path)


def plot_residuals(path, result):
    """Histogram of the identification residuals of each sensor, in physical units."""
    by_sensor = residuals_by_sensor(result)
    count = max(len(by_sensor), 1)
    columns = min(count, 3)
    rows = int(math.ceil(count / columns))
    figure = rows_figure(4.6 * columns, 3.8, rows, margins=(0.08, 0.98, 0.8, 0.5, 1.1), wspace=0.3)
    if not by_sensor:
        axes = figure.add_subplot(1, 1, 1)
        axes.text(0.5, 0.5, 'no residuals (identification failed)', ha='center', va='center')
        axes.set_axis_off()
        return save_figure(figure, path)
    for k, (sensor, values) in enumerate(by_sensor.items()):
        axes = figure.add_subplot(rows, columns, k + 1)
        factor, unit = _residual_scale(SENSOR_KIND.get(sensor, 'length'), values)
        scaled = values * factor
        bins = int(np.clip(np.sqrt(scaled.size) * 2, 10, 60))
        text = f'{scaled.size} residuals'
        axes.hist(scaled, bins=bins, color=_AFTER_COLOUR, alpha=0.8, label=text)
        rms = float(np.sqrt(np.mean(scaled**2))) if scaled.size else 0.0
        axes.axvline(rms, color=_BEFORE_COLOUR, ls='--', lw=1, label=f'± RMS {rms:.3g} {unit}')
        axes.axvline(-rms, color=_BEFORE_COLOUR, ls='--', lw=1)
        axes.set_xlabel(f'residual at the solution ({unit})')
        axes.set_ylabel('count')
        axes.set_title(SENSOR_LABEL.get(sensor, sensor))
        axes.legend(fontsize=8)
        axes.grid(True, alpha=0.3)
    figure.suptitle(f'Identification residuals at the solution ({result.formulation} formulation)')
    return save_figure(figure, path)


def plot_validation(path, validation_before, validation_after):
    """Validation error distributions (position mm, orientation deg) before and after."""
    figure = new_figure(11, 4.4, left=0.08, right=0.98, top=0.86, bottom=0.08, wspace=0.25)
    series = (
        ('before', validation_before, _BEFORE_COLOUR),
        ('after', validation_after, _AFTER_COLOUR),
    )
    quantities = (
        ('position', 'position_mm', 'position error (mm)'),
        ('orientation', 'orientation_deg', 'orientation error (deg)'),
    )
    for column, (name, key, label) in enumerate(quantities):
        axes = figure.add_subplot(1, 2, column + 1)
        drawn = []
        for position, (when, validation, colour) in enumerate(series):
            if validation is None:
                continue
            values = validation_arrays(validation)[column]  # (position, orientation)
            if values is not None and values.size:
                clipped = np.maximum(values, 1e-12)
                parts = axes.violinplot(
                    clipped, positions=[position], showmeans=False, showextrema=False
                )
                for body in parts['bodies']:
                    body.set_facecolor(colour)
                    body.set_alpha(0.35)
                jitter = (np.random.default_rng(0).random(values.size) - 0.5) * 0.2
                text = f'{when}: {values.size} postures'
                axes.plot(position + jitter, clipped, '.', color=colour, ms=4, label=text)
                axes.plot(
                    [position - 0.3, position + 0.3], [np.mean(values)] * 2, '-', color='k', lw=1.5
                )
                drawn.extend(values[values > 0].tolist())
            else:
                summary = validation_summary(validation)
                mean = summary.get(f'{key}_mean')
                top = summary.get(f'{key}_max')
                if mean is None:
                    continue
                height = mean if top is None else top
                axes.bar(position, height, 0.5, color=colour, alpha=0.35, label=f'{when}: max')
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
    return save_figure(figure, path)
