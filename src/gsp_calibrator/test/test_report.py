"""result.json and report.md with PNGs: headless (Agg), readable, non-trivial images."""

import dataclasses
import json
import math

import numpy as np
import pytest
from synthetic import synthetic_samples

from gsp_calibrator.report.data import VALIDATION_KEYS, residuals_by_sensor, validation_errors
from gsp_calibrator.report.write import (
    PLOTS_SKIPPED_NOTE,
    ReportInputs,
    write_all,
    write_result_json,
)
from gsp_calibrator.run.identify import (
    identify_from_samples,
    identify_with_settings,
    write_run_files,
)
from gsp_kinematics.estimation.identifiability import analyse_identifiability
from gsp_kinematics.estimation.identification import Options
from gsp_kinematics.model.geometry import PARAMETER_NAMES, default_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.sensor_noise import SensorNoise

SIGMAS = SensorNoise()


@pytest.fixture(scope='module')
def calibrated():
    nominal, truth = default_geometry('nominal'), default_geometry('true')
    outcome = identify_from_samples(nominal, synthetic_samples(), SIGMAS, noise_source='configured')
    assert outcome.success, outcome.message
    poses = sample_valid_postures(truth, 20, np.random.default_rng(7))
    before = validation_errors(truth, nominal, poses)
    after = validation_errors(truth, outcome.geometry, poses)
    return outcome, nominal, truth, before, after


def _strict_json(path):
    def reject(constant):
        raise ValueError(f'non-standard JSON constant {constant}')

    with open(path, encoding='utf-8') as stream:
        return json.load(stream, parse_constant=reject)


def _check_png(path, min_width=500, min_height=250):
    from matplotlib.image import imread

    image = imread(path)
    height, width = image.shape[:2]
    assert width >= min_width and height >= min_height, (path, image.shape)
    rgb = image[..., :3].reshape(-1, 3)
    assert float(rgb.std()) > 0.02, f'{path} is (almost) a single flat colour'
    # One integer per pixel: np.unique(axis=0) sorts the rows as records, slow on a whole image.
    rgb8 = (rgb * 255).astype(np.uint32)
    colours = np.unique((rgb8[:, 0] << 16) | (rgb8[:, 1] << 8) | rgb8[:, 2])
    assert len(colours) > 20, f'{path} has only {len(colours)} colours'
    assert np.mean(np.all(rgb > 0.98, axis=1)) < 0.97, f'{path} is almost blank'


def _inputs(calibrated):
    """The report inputs of the calibrated fixture: its analysis, validations and geometries."""
    outcome, nominal, truth, before, after = calibrated
    return ReportInputs(
        analysis=outcome.identifiability,
        validation_before=before,
        validation_after=after,
        truth=truth,
        nominal=nominal,
    )


def test_result_json(tmp_path, calibrated):
    outcome, nominal, truth, before, after = calibrated
    result = outcome.result
    path = write_result_json(
        tmp_path,
        result,
        dataclasses.replace(_inputs(calibrated), sigmas=outcome.sigmas, extra={'run': 'test'}),
    )
    data = _strict_json(path)
    for key in (
        'estimates',
        'standard_deviations',
        'correlations',
        'identifiability',
        'residual_rms',
        'iterations',
        'status',
        'message',
        'validation',
        'converged',
        'formulation',
        'parameter_errors',
        'free_parameters',
        'units',
        'sigmas',
        'run',
    ):
        assert key in data, key
    assert data['estimates']['si']['A1x'] == result.parameters[0]
    assert data['estimates']['report']['A1x'] == pytest.approx(result.parameters[0] * 1000.0)
    assert data['estimates']['report']['gamma'] == pytest.approx(
        math.degrees(result.parameters[43])
    )
    assert data['units']['report']['gamma'] == 'deg' and data['units']['si']['D0'] == 'm'
    assert data['standard_deviations']['si']['B2y'] == pytest.approx(
        result.standard_deviations[PARAMETER_NAMES.index('B2y')]
    )
    assert set(data['estimates']['si']) == set(PARAMETER_NAMES)
    identifiability = data['identifiability']
    assert identifiability['rank'] == len(result.free_names) == 51  # extended
    assert identifiability['unidentifiable'] == []
    assert data['goodness_of_fit']['dof'] > 0 and 0.0 <= data['goodness_of_fit']['p_value'] <= 1
    assert data['sensor_errors']['kq1']['free'] and not data['sensor_errors']['kDm']['free']
    assert data['sensor_errors']['kq1']['standard_deviation'] > 0
    assert identifiability['condition_number'] > 1.0
    assert set(data['residual_rms']) == {'leg_lengths', 'alpha', 'beta', 'phi', 'd_m'}
    assert data['residual_rms']['alpha']['si_unit'] == 'rad'
    assert data['iterations'] == result.iterations and data['status'] == result.status
    for when in ('before', 'after'):
        for key in VALIDATION_KEYS:
            assert data['validation'][when][key] >= 0.0
    assert (
        data['validation']['after']['position_mm_mean']
        < data['validation']['before']['position_mm_mean']
    )
    assert data['parameter_errors']['reference'] == 'truth'
    assert data['max_param_error_mm'] < 0.5
    # The pairs above the threshold, from the covariance directly (this fit has some).
    names = result.free_names
    deviations = np.sqrt(np.diag(result.covariance))
    matrix = result.covariance / np.outer(deviations, deviations)
    rows, columns = np.triu_indices(len(names), k=1)
    strong = np.abs(matrix[rows, columns]) > data['correlation_threshold']
    expected = [(names[i], names[j]) for i, j in zip(rows[strong], columns[strong], strict=True)]
    assert data['correlation_threshold'] == 0.9 and len(expected) >= 1
    assert [(pair['a'], pair['b']) for pair in data['correlations']] == expected
    for pair in data['correlations']:
        assert abs(pair['correlation']) > 0.9
    predicted = data['predicted_accuracy']
    assert 0 < predicted['position_mm_mean'] <= predicted['position_mm_p95']
    assert 0 < predicted['orientation_deg_mean'] <= predicted['orientation_deg_p95']
    assert predicted['worst_cell']['position_mm'] == predicted['worst_cell_position_mm'] > 0
    # The measured validation sits beside the prediction at the same postures.
    check = predicted['validation']
    assert check['postures'] == data['validation']['after']['postures']
    assert check['measured_position_mm_mean'] == pytest.approx(
        data['validation']['after']['position_mm_mean']
    )
    assert 0.2 < check['position_ratio'] < 5.0


def test_report_with_truth(tmp_path, calibrated):
    outcome, nominal, truth, before, after = calibrated
    written = write_all(
        tmp_path,
        outcome.result,
        _inputs(calibrated),
    )
    for kind in ('parameter_errors', 'chain_errors', 'residuals', 'validation', 'accuracy_map'):
        _check_png(written[kind])
    assert not list(tmp_path.glob('*.tmp')) and not list(tmp_path.glob('.*.tmp'))
    text = (tmp_path / 'report.md').read_text(encoding='utf-8')
    for name in ('parameter_errors.png', 'chain_errors.png', 'residuals.png', 'validation.png'):
        assert f']({name})' in text
    assert '| A1x | mm |' in text and '| gamma | deg |' in text
    assert 'error before' in text and '## Validation' in text
    assert '## Predicted accuracy' in text and '](accuracy_map.png)' in text
    assert 'Measured over predicted mean at the 20 validation postures' in text
    assert (tmp_path / 'result.json').exists()


def test_report_without_truth_and_failed_identification(tmp_path):
    nominal = default_geometry('nominal')
    samples = synthetic_samples(count=12, seed=2)
    outcome = identify_from_samples(
        nominal,
        samples,
        SIGMAS,
        free=['A1x', 'B1y', 'Loff1', 'D0', 'gamma'],
        options=Options(max_iterations=1),
    )
    result = outcome.result
    assert result is not None and not result.converged
    singular = np.diag([1.0, 1.0, 1.0, 1.0, 0.0])
    analysis = analyse_identifiability(singular, result.free)
    written = write_all(tmp_path, result, ReportInputs(analysis=analysis, nominal=nominal))
    assert 'validation' not in written
    for kind in ('parameter_errors', 'chain_errors', 'residuals'):
        _check_png(written[kind])
    data = _strict_json(written['result_json'])
    assert data['converged'] is False
    assert data['parameter_errors']['reference'] == 'nominal'
    assert data['standard_deviations']['si']['A2x'] is None  # fixed parameter
    assert data['validation'] == {'before': None, 'after': None}
    assert data['predicted_accuracy'] is None and 'accuracy_map' not in written
    assert data['identifiability']['rank'] == 4
    assert data['identifiability']['unidentifiable'][0]['parameters'] == ['gamma']
    text = (tmp_path / 'report.md').read_text(encoding='utf-8')
    assert 'NOT converged' in text and 'not identifiable: `1.00*gamma`' in text
    assert 'correction |' in text


def test_residuals_by_sensor_recovers_si_units(calibrated):
    result = calibrated[0].result
    by_sensor = residuals_by_sensor(result)
    assert set(by_sensor) == set(result.residual_rms)
    for sensor, values in by_sensor.items():
        assert math.sqrt(np.mean(values**2)) == pytest.approx(result.residual_rms[sensor])
    assert by_sensor['leg_lengths'].size == 6 * len(result.poses)


def test_no_prediction_without_a_full_rank_covariance(calibrated):
    import dataclasses

    from gsp_calibrator.report.accuracy import prediction_for, result_json_entry

    result = calibrated[0].result
    assert prediction_for(result) is not None
    singular = result.information.copy()
    singular[:, 0] = singular[0, :] = 0.0  # A1x carries no information
    assert prediction_for(dataclasses.replace(result, information=singular)) is None
    unconverged = dataclasses.replace(result, status=0)
    assert result_json_entry(prediction_for(unconverged)) is None


def test_write_report_plots_false_writes_the_report_without_its_pngs(tmp_path):
    """The calibrator's ``write_report_plots``: false skips every PNG and says so in report.md;
    result.json, report.md's tables and result.yaml are as with the plots (the default)."""
    from gsp_calibrator.files.run_directory import RESULT_FILE, RunDirectory
    from gsp_calibrator.report.data import settle_line, settle_statistics
    from gsp_calibrator.settings import CalibratorSettings

    samples = synthetic_samples(count=25, seed=5)
    waits = {str(k): {'wait_s': 0.2 + 0.01 * k, 'moving_pairs': k % 2} for k in range(1, 26)}
    collection = {
        'skipped': [],
        'inconsistent_dropped': 0,
        'settle': settle_statistics(waits),
    }
    written = {}
    for plots in (True, False):
        settings = CalibratorSettings.from_values(
            {'posture_count': 25, 'free_parameters': ['paper'], 'write_report_plots': plots}
        )
        if plots:  # the parameter's default
            default = CalibratorSettings.from_values({'posture_count': 25})
            assert default.write_report_plots is True
        run = RunDirectory(tmp_path / str(plots))
        run.path.mkdir()
        outcome = identify_with_settings(settings, samples)
        finished = write_run_files(run, settings, outcome, collection, {'plots': plots})
        assert outcome.success and finished.report_error == ''
        written[plots] = run.path
    with_plots, without_plots = written[True], written[False]
    pngs = sorted(p.name for p in with_plots.glob('*.png'))
    assert pngs == sorted(
        [
            'parameter_errors.png',
            'chain_errors.png',
            'residuals.png',
            'accuracy_map.png',
            'held_out_accuracy.png',
        ]
    )
    assert not list(without_plots.glob('*.png'))
    assert (without_plots / RESULT_FILE).read_text() == (with_plots / RESULT_FILE).read_text()
    drawn = _strict_json(with_plots / 'result.json')
    skipped = _strict_json(without_plots / 'result.json')
    assert skipped['options'] == {'plots': False} and drawn['options'] == {'plots': True}
    drawn.pop('duration_s'), skipped.pop('duration_s')  # wall time
    drawn['accuracy'].pop('duration_s'), skipped['accuracy'].pop('duration_s')
    assert {**skipped, 'options': None} == {**drawn, 'options': None}
    text = (without_plots / 'report.md').read_text(encoding='utf-8')
    assert PLOTS_SKIPPED_NOTE in text and '.png' not in text
    # How long the rows waited for rest: per posture in result.json, a line in both texts.
    assert skipped['collection']['settle']['per_posture_s']['7'] == pytest.approx(0.27)
    line = settle_line(collection['settle'])
    assert 'median 0.33 s, max 0.45 s over 25 rows; 13 waited' in line
    assert f'- {line}' in text and line in finished.summary.splitlines()
    assert PLOTS_SKIPPED_NOTE not in (with_plots / 'report.md').read_text(encoding='utf-8')
    assert '](held_out_accuracy.png)' in (with_plots / 'report.md').read_text(encoding='utf-8')
    tables = [
        line
        for line in (with_plots / 'report.md').read_text(encoding='utf-8').splitlines()
        if line.startswith('|') and 'ms' not in line
    ]
    assert len(tables) > len(PARAMETER_NAMES) and all(line in text for line in tables)
