"""The paper reproduction and the benchmark: their building blocks and output contracts (small runs)."""

import json
import math
import shutil

import numpy as np
import pytest

from gsp_bench import core, paper, paper_cli, tables
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.kinematics import Workspace, inverse_kinematics, sample_valid_postures
from gsp_kinematics.model.sensor_noise import SensorNoise


def test_tables_are_the_shipped_file_or_an_explicit_one(tmp_path):
    shipped, source = tables.load_tables()
    assert source == tables.SHIPPED
    initial, levels = tables.table3(shipped)
    assert initial == {'position_mm': 1.344, 'orientation_deg': 0.345}
    assert [(level['angle_noise_deg'], level['length_noise_mm']) for level in levels] == [
        (0.001, 0.001),
        (0.001, 0.005),
        (0.005, 0.001),
        (0.005, 0.005),
    ]
    assert tables.table1(shipped)[2] == (12.35, 5.18, 5.89)
    assert tables.table2(shipped)[3] == (848.7, 91.0)
    copy = shutil.copy(tables.__file__.replace('tables.py', 'data/tables.yaml'), tmp_path)
    assert tables.load_tables(copy) == (shipped, str(copy))
    with pytest.raises(FileNotFoundError):
        tables.load_tables(tmp_path / 'absent.yaml')
    (tmp_path / 'other.yaml').write_text('table3_mean_errors_after_calibration: {levels: []}\n')
    with pytest.raises(ValueError, match='Table 3'):
        tables.load_tables(tmp_path / 'other.yaml')


def test_noise_model_hits_the_right_sensors(rng):
    legs, readings = np.zeros((20000, 6)), np.zeros((20000, 4))
    noisy_legs, noisy_readings = paper.add_noise(legs, readings, 0.005, 0.001, rng)
    assert np.std(noisy_legs) == pytest.approx(1e-6, rel=0.02)
    np.testing.assert_allclose(
        np.std(noisy_readings, axis=0), [math.radians(0.005)] * 3 + [1e-6], rtol=0.03
    )


def test_paper_main_writes_the_contract(tmp_path, capsys):
    output = tmp_path / 'paper.json'
    code = paper_cli.main(
        [
            '--seeds',
            '1',
            '--pool',
            '80',
            '--sets',
            '1',
            '--formulations',
            'paper,implicit',
            '--jobs',
            '1',
            '--output',
            str(output),
            '--plot-dir',
            str(tmp_path),
            '--matched-evaluations',
            '2',
        ]
    )
    assert code == 0
    document = json.loads(output.read_text())
    assert {'position_mm', 'orientation_deg'} <= set(document['initial'])
    assert document['initial']['position_mm'] > 0.1
    (row,) = document['noise_free']
    assert row['set'] == 1 and row['converged'] is True
    assert row['max_param_error_mm'] < 1e-6 and row['max_param_error_deg'] < 1e-6
    assert len(row['parameters']) == 44
    assert len(document['noise']) == 8
    for entry in document['noise']:
        assert {
            'angle_noise_deg',
            'length_noise_mm',
            'formulation',
            'seeds',
            'position_mm',
            'orientation_deg',
            'paper_position_mm',
            'paper_orientation_deg',
        } <= set(entry)
        assert entry['formulation'] in ('paper', 'implicit') and entry['seeds'] == 1
        assert 0.0 < entry['position_mm'] < document['initial']['position_mm']
        # The Cramér-Rao prediction beside the Monte-Carlo figure.
        assert 0.0 < entry['cramer_rao_position_mm'] < document['initial']['position_mm']
        assert entry['cramer_rao_orientation_deg'] > 0.0
    matched = document['paper_matched']
    assert matched['target'] == {'position_mm': 1.344, 'orientation_deg': 0.345, 'tolerance': 0.1}
    assert matched['search']['evaluations'] >= 4 and isinstance(matched['matched'], bool)
    assert (matched['why_not'] is None) == matched['matched']
    candidate = matched['candidate']
    assert set(candidate['initial_error']) == {'set_1', 'set_2', 'set_3'}
    assert candidate['device_length_m'] == pytest.approx(0.85)
    assert matched['default_platform']['initial_error']['set_1']['position_mm'] > 1.0
    assert len(matched['candidate_table3']['noise']) == 8
    assert all('cramer_rao_position_mm' in row for row in matched['candidate_table3']['noise'])
    assert (tmp_path / 'paper_fig6_set1_parameter_errors.png').stat().st_size > 10000
    assert 'Table 3' in capsys.readouterr().out


def test_scipy_baseline_residuals_vanish_at_the_exact_geometry(exact, nominal_sets):
    workspace = Workspace(rotation_range=math.radians(25.0))
    poses = sample_valid_postures(exact, 20, np.random.default_rng(8), workspace)
    legs, readings = inverse_kinematics(exact, poses), device_readings(exact, poses)
    residuals = core.fk_residual_function(nominal_sets[2], legs, readings, SensorNoise(), poses)
    assert residuals(exact.to_vector()).shape == (80,)
    assert np.max(np.abs(residuals(exact.to_vector()))) < 1e-6
    assert np.max(np.abs(residuals(nominal_sets[2].to_vector()))) > 10.0


def test_fk_throughput_section():
    section = core.bench_fk(count=300, repeats=1)
    assert section['postures_per_s'] > 0 and section['converged_fraction'] == 1.0
    assert section['max_position_error_m'] < 1e-9


def test_bench_json_merges(tmp_path):
    path = tmp_path / 'bench.json'
    path.write_text(json.dumps({'end_to_end': {'seconds': 12.0}, 'fk': {'postures_per_s': 1.0}}))
    document = core.merge_sections(path, {'fk': {'postures_per_s': 2.0}})
    assert document == {'end_to_end': {'seconds': 12.0}, 'fk': {'postures_per_s': 2.0}}
    assert json.loads(path.read_text()) == document
    assert core.merge_sections(path, {'fk': {}}, merge=False) == {'fk': {}}


def test_extra_sections_are_called_and_failures_recorded():
    def broken(quick):
        raise RuntimeError('no nodes')

    logged = []
    sections = {'fake': lambda quick: {'quick': quick, 'value': 1.0}, 'broken': broken}
    assert core.run_extra_sections(sections, quick=True, log=logged.append) == {
        'fake': {'quick': True, 'value': 1.0},
        'broken': {'error': "RuntimeError('no nodes')"},
    }
    assert any('broken' in line for line in logged)
    assert core.run_extra_sections(sections, skip={'fake', 'broken'}) == {}
    assert core.skip_option('end_to_end') == '--skip-end-to-end'


def test_bench_main_runs_extra_sections_unless_skipped(tmp_path, monkeypatch, capsys):
    # The core's sections are stubbed: this test is about the command line and the document.
    monkeypatch.setattr(core, 'build_problem', lambda **noise: noise)
    monkeypatch.setattr(core, 'bench_identification', lambda problem, *repeats: {'ms': 1.0})
    monkeypatch.setattr(core, 'bench_fk', lambda count, repeats: {'postures': count})
    monkeypatch.setattr(
        core, 'scale_sections', lambda identification, quick, log: {'selection': {'quick': quick}}
    )
    calls = []

    def section(quick):
        calls.append(quick)
        return {'value': np.float64(2.5)}

    output = tmp_path / 'bench.json'
    argv = ['--quick', '--no-merge', '--output', str(output)]
    assert core.main(argv, extra_sections={'end_to_end': section}) == 0
    document = json.loads(output.read_text())
    assert document['end_to_end'] == {'value': 2.5} and calls == [True]
    assert document['fk'] == {'postures': 2000} and document['selection'] == {'quick': True}
    assert json.loads(capsys.readouterr().out) == document
    core.main([*argv, '--skip-end-to-end'], extra_sections={'end_to_end': section})
    assert 'end_to_end' not in json.loads(output.read_text()) and calls == [True]
    with pytest.raises(SystemExit):  # no section, no option
        core.main([*argv, '--skip-end-to-end'])


def test_scaling_fits_the_exponent_and_skips_what_exceeds_the_budget():
    from gsp_bench import scale

    # A zero budget skips every size after the first two whatever their times: with a small one,
    # a load spike in the 16-posture timing (a negative exponent) would let 64000 postures run.
    section = scale.identification_scaling((16, 32, 64000), repeats=1, budget_s=0.0)
    assert section['postures'] == [16, 32] and len(section['ms']) == 2
    assert section['exponent'] == pytest.approx(
        np.log(section['ms'][1] / section['ms'][0]) / np.log(2.0)
    )
    assert section['skipped'][0]['postures'] == 64000 and section['skipped'][0]['predicted_s'] > 0


def test_selection_and_prediction_sections():
    from gsp_bench import scale

    selection = scale.bench_selection(pools=(90,), count=30, repeats=1)
    assert selection['pool_90_s'] > 0 and 1.0 < selection['condition_90'] < np.inf
    # A smoke run of the section (the 25 % target over 20 seeds is the benchmark's): with the
    # calibrator's 51 free parameters, 4 seeds of 40 postures give ratios of the right order.
    prediction = scale.bench_prediction(seeds=4, postures=40, validation_postures=40)
    assert prediction['seeds'] == 4
    assert 0.5 < prediction['position_ratio'] < 2.0
    assert 0.5 < prediction['orientation_ratio'] < 2.0
