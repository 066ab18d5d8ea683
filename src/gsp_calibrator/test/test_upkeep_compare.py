"""gsp_compare on the result.json of two simulated calibrations (gsp_calibrator.upkeep)."""

import json

import numpy as np
import pytest
from upkeep_runs import RUNS, write_runs

from gsp_calibrator.tools import compare
from gsp_calibrator.upkeep.calibration_files import CalibrationFileError, load_calibration


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    """Three run directories: a calibration, one of the unchanged platform, one after Loff3 +20 um."""
    written = write_runs(tmp_path_factory.mktemp('runs'))
    paths = {}
    for key, (name, *_) in zip(('first', 'same', 'changed'), RUNS, strict=True):
        paths[key], paths[key, 'result'] = written[name]
    return paths


def test_result_json_keeps_the_covariance_of_the_free_parameters(runs):
    calibration = load_calibration(runs['first'])
    result = runs['first', 'result']
    assert calibration.names == tuple(result.free_names)
    np.testing.assert_allclose(calibration.covariance, result.covariance, rtol=1e-12, atol=0)
    np.testing.assert_allclose(calibration.estimates, result.parameters[result.free], atol=1e-15)


def test_gsp_compare_names_the_changed_leg_offset_and_exits_1(runs, capsys, tmp_path):
    output = tmp_path / 'drift.json'
    code = compare.main([str(runs['first']), str(runs['changed']), '--json', str(output)])
    text = capsys.readouterr().out
    assert code == compare.EXIT_CHANGED
    assert 'significant: Loff3 +0.0' in text and 'CHANGED' in text
    data = json.loads(output.read_text())
    assert [entry['parameter'] for entry in data['significant']] == ['Loff3']


def test_gsp_compare_finds_no_change_on_an_unchanged_platform(runs, capsys):
    assert compare.main([str(runs['first']), str(runs['same'])]) == compare.EXIT_UNCHANGED
    assert 'no significant change' in capsys.readouterr().out


def test_an_older_result_without_covariance_falls_back_to_the_sigmas(runs, tmp_path):
    data = json.loads((runs['first'] / 'result.json').read_text())
    del data['covariance']
    (tmp_path / 'result.json').write_text(json.dumps(data))
    calibration = load_calibration(tmp_path)
    result = runs['first', 'result']
    np.testing.assert_allclose(
        np.sqrt(np.diag(calibration.covariance)),
        result.standard_deviations[result.free],
        rtol=1e-12,
    )
    assert np.count_nonzero(calibration.covariance - np.diag(np.diag(calibration.covariance))) == 0


def test_bad_input_names_the_file_and_exits_2(tmp_path, capsys):
    with pytest.raises(CalibrationFileError, match='neither result.json nor check.json'):
        load_calibration(tmp_path)
    (tmp_path / 'result.json').write_text('{"free_parameters": []}')
    assert compare.main([str(tmp_path), str(tmp_path)]) == compare.EXIT_BAD_INPUT
    assert 'no free_parameters' in capsys.readouterr().err
