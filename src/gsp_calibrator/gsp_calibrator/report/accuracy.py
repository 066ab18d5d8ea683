"""Predicted accuracy of a calibration in its report: ``result.json`` ``predicted_accuracy`` and
``accuracy_map.png`` (pure, no rclpy)."""

import math

import numpy as np

from gsp_calibrator.report.data import validation_arrays
from gsp_calibrator.report.plots import new_figure, save_figure
from gsp_kinematics.estimation.identifiability import analyse_result
from gsp_kinematics.estimation.prediction import (
    accuracy_summary,
    predict_accuracy,
    predicted_errors,
)
from gsp_kinematics.model.kinematics import Workspace

ACCURACY_MAP_PNG = 'accuracy_map.png'


def _validation_poses(validation):
    poses = (validation or {}).get('poses') if isinstance(validation, dict) else None
    return None if poses is None else np.asarray(poses, dtype=float).reshape(-1, 6)


def prediction_for(
    result,
    validation_after=None,
    workspace=Workspace(),
    analysis=None,
    unmodelled=None,
    thermal_strain=None,
):
    """The full prediction (with maps) of an ``IdentificationResult``; None when it has no usable
    covariance (not converged, non-finite, or rank-deficient). ``analysis``: its
    ``analyse_result`` (None: computed here); ``unmodelled`` (``unmodelled_error``) and
    ``thermal_strain`` (6,): added at every pose (None: none)."""
    covariance = np.asarray(result.covariance, dtype=float)
    if not result.converged or not np.all(np.isfinite(covariance)):
        return None
    # Freed effects: the full covariance, geometry and effects jointly (the controller compensates
    # with both, their correlated errors cancel at the pose: docs/platform_effects.md).
    if analysis is None:
        analysis = analyse_result(result)
    if analysis['rank'] < analysis['parameters']:
        return None
    prediction = predict_accuracy(
        result.geometry,
        covariance,
        result.free,
        workspace,
        unmodelled=unmodelled,
        thermal_strain=thermal_strain,
        effect_free=result.effect_free,
    )
    poses = _validation_poses(validation_after)
    measured_position, measured_orientation = validation_arrays(validation_after or {})
    known = measured_position is not None and measured_orientation is not None
    if poses is not None and known and len(poses) == len(measured_position) and len(poses):
        position, orientation = predicted_errors(
            result.geometry,
            covariance,
            poses,
            result.free,
            unmodelled,
            thermal_strain,
            result.effect_free,
        )
        prediction['validation'] = {
            'poses': poses.tolist(),
            'predicted_position_mm': position.tolist(),
            'predicted_orientation_deg': orientation.tolist(),
            'measured_position_mm': measured_position.tolist(),
            'measured_orientation_deg': measured_orientation.tolist(),
            'position_ratio': float(np.mean(measured_position) / np.mean(position)),
            'orientation_ratio': float(np.mean(measured_orientation) / np.mean(orientation)),
        }
    return prediction


def result_json_entry(prediction):
    """``result.json`` ``predicted_accuracy``: the headline, random-posture statistics, the worst
    grid cell and (simulation) measured over predicted means at the validation postures."""
    if prediction is None:
        return None
    entry = {
        'statistic': prediction['statistic'],
        'assumes': prediction.get('assumes'),
        'units': prediction['units'],
        **accuracy_summary(prediction),
        'random': prediction['random'],
        'worst_cell': prediction['worst_cell'],
        'map_panels': [panel['title'] for panel in prediction['maps']],
    }
    validation = prediction.get('validation')
    if validation:
        means = ('measured_position_mm', 'predicted_position_mm')
        means += ('measured_orientation_deg', 'predicted_orientation_deg')
        entry['validation'] = {
            'postures': len(validation['poses']),
            **{f'{key}_mean': float(np.mean(validation[key])) for key in means},
            'position_ratio': validation['position_ratio'],
            'orientation_ratio': validation['orientation_ratio'],
        }
    return entry


def markdown_lines(entry, image=None):
    """The report's 'Predicted accuracy' section from :func:`result_json_entry`."""
    if not entry:
        return []

    def number(value):
        return '–' if value is None or not math.isfinite(value) else f'{value:.3g}'

    worst = entry.get('worst_cell') or {}
    lines = [
        '## Predicted accuracy',
        '',
        'The parameter covariance propagated to the pose error of the calibrated platform '
        '(expected error magnitude, 1σ noise).',
        '',
        '| | mean | p95 | worst map cell |',
        '|---|---|---|---|',
        f'| position (mm) | {number(entry["position_mm_mean"])} | '
        f'{number(entry["position_mm_p95"])} | {number(worst.get("position_mm"))} |',
        f'| orientation (deg) | {number(entry["orientation_deg_mean"])} | '
        f'{number(entry["orientation_deg_p95"])} | {number(worst.get("orientation_deg"))} |',
        '',
    ]
    if worst:
        lines += [
            f'Worst cell: {worst["panel"]}, x = {1000 * worst["pose"][0]:.0f} mm, '
            f'y = {1000 * worst["pose"][1]:.0f} mm.',
            '',
        ]
    validation = entry.get('validation')
    if validation:
        lines += [
            f'Measured over predicted mean at the {validation["postures"]} validation postures: '
            f'position {validation["position_ratio"]:.2f}, '
            f'orientation {validation["orientation_ratio"]:.2f}.',
            '',
        ]
    if image:
        lines += [f'![predicted accuracy map]({image})', '']
    return lines


def plot_accuracy_map(path, prediction):
    """``accuracy_map.png``: predicted position (top) and orientation (bottom) error maps, one
    column per panel, with the validation postures (measured error) overlaid when known."""
    maps = prediction['maps']
    validation = prediction.get('validation')
    columns = len(maps) + (1 if validation else 0)
    figure = new_figure(
        3.3 * columns, 6.6, left=0.05, right=0.97, top=0.88, bottom=0.08, wspace=0.35, hspace=0.35
    )
    heights = sorted({panel['z_m'] for panel in maps})
    height_step = min(np.diff(heights)) if len(heights) > 1 else math.inf
    rows = (('position_mm', 'position (mm)'), ('orientation_deg', 'orientation (deg)'))
    for row, (key, label) in enumerate(rows):
        values = np.array([panel[key] for panel in maps], dtype=float)
        finite = values[np.isfinite(values)]
        low, high = (finite.min(), finite.max()) if finite.size else (0.0, 1.0)
        # The predicted maps set the colour scale; a measured dot beyond it shows saturated.
        scale = {'vmin': low, 'vmax': high, 'cmap': 'viridis'}
        measured = None
        if validation:
            measured = np.asarray(validation[f'measured_{key}'], dtype=float)
        row_axes = []
        for column, panel in enumerate(maps):
            axes = figure.add_subplot(2, columns, row * columns + column + 1)
            row_axes.append(axes)
            x = 1000.0 * np.asarray(panel['x_m'])
            y = 1000.0 * np.asarray(panel['y_m'])
            grid = np.asarray(panel[key], dtype=float)
            image = axes.pcolormesh(x, y, grid, shading='nearest', **scale)
            if measured is not None:
                poses = np.asarray(validation['poses'])
                near = np.abs(poses[:, 2] - panel['z_m']) <= 0.5 * height_step
                near &= np.all(np.abs(poses[:, 3:5] - np.asarray(panel['tilt_rad'])) < 0.2, axis=1)
                x_near, y_near = 1000 * poses[near, :2].T
                axes.scatter(x_near, y_near, c=measured[near], edgecolors='w', s=22, **scale)
            axes.set_title(panel['title'], fontsize=8)
            axes.set_xlabel('x (mm)', fontsize=8)
            if column == 0:
                axes.set_ylabel(f'{label}\ny (mm)', fontsize=8)
            axes.tick_params(labelsize=7)
            axes.set_aspect('equal')
        figure.colorbar(image, ax=row_axes, shrink=0.8, label=label)
        if validation:
            axes = figure.add_subplot(2, columns, row * columns + columns)
            predicted = np.asarray(validation[f'predicted_{key}'], dtype=float)
            axes.plot(predicted, measured, '.', ms=4, color='#1f77b4')
            top = max(predicted.max(), measured.max()) * 1.05
            axes.plot([0, top], [0, top], 'k-', lw=1)
            axes.set_xlabel(f'predicted {label}', fontsize=8)
            axes.set_ylabel(f'measured {label}', fontsize=8)
            axes.set_title('validation postures', fontsize=8)
            axes.tick_params(labelsize=7)
    dots = '; dots: measured validation errors' if validation else ''
    figure.suptitle(
        'Predicted error of the calibrated platform (expected magnitude from the parameter '
        f'covariance){dots}'
    )
    return save_figure(figure, path)


HELD_OUT_PNG = 'held_out_accuracy.png'


def plot_held_out(path, accuracy, predicted=None, required_mm=None):
    """Each posture's held-out position error beside the nominal geometry's and its own noise
    (log scale), with the cross-validated and predicted means and the requirement as lines."""
    per_posture = accuracy['per_posture']
    figure = new_figure(11, 4.4, left=0.07, right=0.98, top=0.88, bottom=0.12)
    axes = figure.add_subplot(1, 1, 1)
    postures = np.arange(1, len(per_posture['position_mm']) + 1)
    for key, label, style in (
        ('nominal_position_mm', 'nominal geometry', 'x'),
        ('position_mm', 'calibrated, held out', 'o'),
        ('noise_position_mm', "the posture's own noise (1 sigma)", '_'),
    ):
        values = np.array(per_posture[key], dtype=float)
        axes.plot(postures, np.maximum(values, 1e-6), style, ms=4, label=label)
    lines = (
        (accuracy['calibrated']['position_mm']['mean'], 'k', 'held-out mean, noise removed'),
        (predicted, 'tab:green', 'predicted mean (workspace)'),
        (required_mm, 'tab:red', 'required'),
    )
    for value, colour, label in lines:
        if value is not None and np.isfinite(value) and value > 0:
            axes.axhline(value, color=colour, lw=1.2, ls='--', label=f'{label}: {value:.3g} mm')
    axes.set_yscale('log')
    axes.set_xlabel('posture (in the order collected)')
    axes.set_ylabel('position error (mm)')
    axes.grid(True, which='both', axis='y', alpha=0.3)
    axes.legend(fontsize=8, ncol=2)
    figure.suptitle(
        'Accuracy measured by the device on postures the fit did not use '
        f'({accuracy["folds"]}-fold cross-validation)'
    )
    return save_figure(figure, path)
