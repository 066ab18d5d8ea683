"""gsp_compare on the result.json of two simulated calibrations (gsp_calibrator.upkeep)."""

import json

import numpy as np
import pytest
from upkeep_runs import RUNS, write_runs

from gsp_calibrator.files.calibration_files import CalibrationFileError, load_calibration
from gsp_calibrator.tools import compare


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


def _with_effects(data):
    """``data`` (a result.json dict) as an ``auto`` run writes it: the free effect parameters
    after the others in ``free_parameters`` and the covariance, correlated with them."""
    names = list(data['free_parameters'])
    effects = ['compliance1', 'compliance2', 'backlash1', 'strain_rate1']
    n, m = len(names), len(effects)
    rng = np.random.default_rng(3)
    square = rng.normal(size=(n + m, n + m)) * 1e-6
    covariance = np.zeros((n + m, n + m))
    covariance[:n, :n] = data['covariance']['si']
    covariance[n:, :n] = square[n:, :n]
    covariance[:n, n:] = square[n:, :n].T
    covariance[n:, n:] = square[n:, n:] @ square[n:, n:].T + np.eye(m) * 1e-12
    return {
        **data,
        'free_parameters': names + effects,
        'covariance': {'parameters': names + effects, 'si': covariance.tolist()},
    }


def test_an_auto_result_is_compared_over_its_geometry_and_sensor_errors(runs, tmp_path):
    """An ``auto`` calibration's result.json also names the effect parameters it freed (every
    such run once logged 'history not updated ...: tuple.index(x): x not in tuple', and
    gsp_compare refused it). The drift is compared over the others, with their covariance."""
    plain = load_calibration(runs['first'])
    for key in ('first', 'changed'):
        data = json.loads((runs[key] / 'result.json').read_text())
        (tmp_path / key).mkdir()
        (tmp_path / key / 'result.json').write_text(json.dumps(_with_effects(data)))
    calibration = load_calibration(tmp_path / 'first')
    assert calibration.names == plain.names
    np.testing.assert_allclose(calibration.covariance, plain.covariance, rtol=1e-12, atol=0)
    np.testing.assert_allclose(calibration.estimates, plain.estimates, rtol=0, atol=1e-15)
    code = compare.main([str(tmp_path / 'first'), str(tmp_path / 'changed')])
    assert code == compare.EXIT_CHANGED
    # ... and indexed in the history, with the change named against the calibration before.
    from gsp_calibrator.files import history

    database = tmp_path / 'history.sqlite'
    for key in ('first', 'changed'):
        history.record(database, tmp_path / key, 'hexapod-auto')
    found = history.runs(database, 'hexapod-auto')
    assert len(found) == 2
    assert [change['parameter'] for change in found[-1]['changes']] == ['Loff3']
