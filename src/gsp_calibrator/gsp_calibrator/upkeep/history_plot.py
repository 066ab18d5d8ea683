"""The plot of a platform's history (``gsp_history plot``): its accuracy over time (calibrations
and checks) and the parameters that moved (named significant by a drift comparison or a check),
each as its change from its first calibration with 1-sigma bars. matplotlib's Agg canvas."""

import collections
import datetime

from gsp_calibrator.files import history
from gsp_calibrator.report.plots import new_figure, save_figure
from gsp_kinematics.upkeep.drift import report_scale

_MARKERS = {'calibration': ('o', '#1f77b4'), 'check': ('s', '#ff7f0e')}
_RECALIBRATE_COLOUR = '#d62728'
#: At most this many moved parameters are drawn (the most often named first).
MAX_PARAMETERS = 8


def moved_parameters(found):
    """The parameters named in the runs ``found``, the most often named first."""
    named = (change['parameter'] for entry in found for change in entry['changes'])
    return [name for name, _ in collections.Counter(named).most_common(MAX_PARAMETERS)]


def _time(text):
    return datetime.datetime.fromisoformat(text)


def _accuracy_panel(axes, found, required_mm):
    for kind, (marker, colour) in _MARKERS.items():
        rows = [e for e in found if e['kind'] == kind and e['position_mm'] is not None]
        if rows:
            axes.plot(
                [_time(e['time_utc']) for e in rows],
                [e['position_mm'] for e in rows],
                marker=marker,
                color=colour,
                linestyle='-' if kind == 'calibration' else 'none',
                label=kind,
            )
    flagged = [e for e in found if e['verdict'] == 'recalibrate' and e['position_mm'] is not None]
    if flagged:
        axes.plot(
            [_time(e['time_utc']) for e in flagged],
            [e['position_mm'] for e in flagged],
            'x',
            color=_RECALIBRATE_COLOUR,
            markersize=10,
            label='check: recalibrate',
        )
    if required_mm:
        axes.axhline(required_mm, color='grey', linestyle='--', label='required')
    axes.set_ylabel('position error, mm (mean)')
    axes.set_title('accuracy')
    axes.legend(fontsize=8)


def _parameters_panel(axes, series):
    for name, points in series.items():
        if not points:
            continue
        factor, unit = report_scale(name)
        base = points[0][1]
        axes.errorbar(
            [_time(t) for t, _, _ in points],
            [(value - base) * factor for _, value, _ in points],
            yerr=[(sigma or 0.0) * factor for _, _, sigma in points],
            marker='o',
            capsize=3,
            label=f'{name} ({unit})',
        )
    axes.axhline(0.0, color='grey', linewidth=0.5)
    axes.set_ylabel('change from the first calibration')
    axes.set_title('parameters that moved (1 sigma bars)')
    if series:
        axes.legend(fontsize=8)
    else:
        axes.text(
            0.5, 0.5, 'no parameter moved significantly', ha='center', transform=axes.transAxes
        )


def plot_history(path, platform, output, required_mm=None):
    """Draw the history of ``platform`` in the database ``path`` to the PNG ``output``."""
    found = history.runs(path, platform)
    if not found:
        raise history.HistoryError(f'{path}: no run of platform {platform!r}')
    series = history.estimates(path, platform, moved_parameters(found))
    figure = new_figure(9, 7, left=0.1, right=0.97, top=0.93, bottom=0.1, hspace=0.35)
    figure.suptitle(f'platform {platform}: {len(found)} runs')
    _accuracy_panel(figure.add_subplot(2, 1, 1), found, required_mm)
    _parameters_panel(figure.add_subplot(2, 1, 2), series)
    figure.autofmt_xdate()
    return save_figure(figure, output)
