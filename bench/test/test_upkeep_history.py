"""The platform history (gsp_calibrator.files.history, gsp_history): indexing, queries, the plot,
the schema version, and a writer killed in the middle of a transaction."""

import json
import shutil
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from upkeep_runs import RUNS, write_runs

import gsp_calibrator.tools.history
from gsp_calibrator.files import history


@pytest.fixture(scope='module')
def root(tmp_path_factory):
    root = tmp_path_factory.mktemp('runs')
    write_runs(root)
    return root


def test_each_calibration_is_indexed_with_the_changes_since_the_one_before(root, tmp_path):
    database = tmp_path / 'history.sqlite'
    indexed, skipped = history.rebuild(database, root)
    assert len(indexed) == 3 and skipped == []
    found = history.runs(database, 'hexapod-7')
    assert [entry['time_utc'][:10] for entry in found] == ['2026-11-01', '2026-11-08', '2026-11-15']
    assert all(
        entry['kind'] == 'calibration' and entry['verdict'] == 'identified' for entry in found
    )
    assert found[0]['changes'] == [] and found[0]['compared_with'] is None
    assert found[1]['changes'] == [] and found[1]['compared_with'] == found[0]['id']
    assert [change['parameter'] for change in found[2]['changes']] == ['Loff3']
    assert 0.01 < found[2]['changes'][0]['change_report'] < 0.03  # mm
    assert found[2]['accuracy_source'] == 'predicted' and 0 < found[2]['position_mm'] < 0.05
    assert history.platforms(database) == [('hexapod-7', 3)]
    series = history.estimates(database, 'hexapod-7', ['Loff3'])['Loff3']
    assert len(series) == 3 and 15e-6 < series[2][1] - series[1][1] < 25e-6


def test_indexing_a_run_again_replaces_it(root, tmp_path):
    database = tmp_path / 'history.sqlite'
    history.rebuild(database, root)
    history.record(database, root / RUNS[2][0])
    assert len(history.runs(database)) == 3
    with sqlite3.connect(database) as connection:
        assert connection.execute('SELECT count(*) FROM changes').fetchone()[0] == 1


def test_gsp_history_lists_plots_and_refuses_a_missing_database(root, tmp_path, capsys):
    database = str(tmp_path / 'history.sqlite')
    assert (
        gsp_calibrator.tools.history.main(['rebuild', '--database', database, '--root', str(root)])
        == 0
    )
    assert (
        gsp_calibrator.tools.history.main(
            ['list', '--database', database, '--platform', 'hexapod-7']
        )
        == 0
    )
    text = capsys.readouterr().out
    assert 'moved: Loff3 +0.0' in text and text.count('calibration') == 3
    output = tmp_path / 'history.png'
    command = ['plot', '--database', database, '--platform', 'hexapod-7', '--output', str(output)]
    assert gsp_calibrator.tools.history.main(command) == 0
    assert output.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    missing = ['list', '--database', str(tmp_path / 'none.sqlite')]
    assert gsp_calibrator.tools.history.main(missing) == gsp_calibrator.tools.history.EXIT_BAD_INPUT
    assert 'no history at' in capsys.readouterr().err


def test_a_newer_schema_is_refused(tmp_path):
    database = tmp_path / 'history.sqlite'
    with sqlite3.connect(database) as connection:
        connection.execute(f'PRAGMA user_version={history.SCHEMA_VERSION + 1}')
    with pytest.raises(history.HistoryError, match='newer than this suite'):
        history.runs(database)


#: A writer that indexes one run, then a second one but is held inside its transaction (after the
#: run's row and its estimates are written, before its changes and the commit) until killed.
_WRITER = textwrap.dedent(
    """
    import sys
    from gsp_calibrator.files import history

    database, first, second = sys.argv[1:]
    history.record(database, first)
    original = history._insert_changes

    def held(connection, run_id, changes):
        original(connection, run_id, changes)
        print('inside the transaction', flush=True)
        sys.stdin.readline()  # until the test kills this process

    history._insert_changes = held
    history.record(database, second)
    """
)


def test_a_writer_killed_inside_its_transaction_leaves_a_consistent_history(root, tmp_path):
    database = tmp_path / 'history.sqlite'
    first, second = (str(root / name) for name, *_ in RUNS[:2])
    writer = subprocess.Popen(
        [sys.executable, '-c', _WRITER, str(database), first, second],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert writer.stdout.readline().strip() == 'inside the transaction'
        writer.kill()
        writer.wait()
    finally:
        if writer.poll() is None:
            writer.kill()
            writer.wait()
    # The first run is whole; nothing of the second is there; the file is intact.
    with sqlite3.connect(database) as connection:
        assert connection.execute('PRAGMA integrity_check').fetchone()[0] == 'ok'
        assert connection.execute('PRAGMA foreign_key_check').fetchall() == []
    found = history.runs(database)
    assert [entry['run_dir'] for entry in found] == [str((root / RUNS[0][0]).resolve())]
    with sqlite3.connect(database) as connection:
        counts = connection.execute(
            'SELECT count(*), count(DISTINCT run_id) FROM estimates'
        ).fetchone()
    assert counts == (
        len(json.loads((root / RUNS[0][0] / 'result.json').read_text())['free_parameters']),
        1,
    )
    # A later writer carries on.
    history.record(database, second)
    assert len(history.runs(database)) == 2


def test_a_judged_calibration_gives_its_cross_validated_accuracy_and_its_acceptance():
    judged = {
        'success': True,
        'accepted': False,
        'accuracy': {'calibrated': {'position_mm': {'mean': 0.048}, 'phi_deg': {'mean': 0.002}}},
        'predicted_accuracy': {'position_mm_mean': 0.0116, 'orientation_deg_mean': 0.001},
    }
    assert history.calibration_accuracy(judged) == (0.048, 0.002, 'cross-validated')
    assert history.calibration_verdict(judged) == (False, 'not accepted')
    assert history.calibration_verdict({'success': False, 'accepted': True}) == (False, 'failed')


def test_a_rank_deficient_calibration_is_indexed_without_its_meaningless_sigmas(root, tmp_path):
    data = json.loads((root / RUNS[0][0] / 'result.json').read_text())
    covariance = data['covariance']['si']
    covariance[0][0] = -1e-12  # what the pseudo-inverse of a singular information can give
    data['success'] = False
    run_dir = tmp_path / '20261201T080000Z'
    run_dir.mkdir()
    (run_dir / 'result.json').write_text(json.dumps(data))
    database = tmp_path / 'history.sqlite'
    history.record(database, run_dir)
    (entry,) = history.runs(database)
    assert (entry['success'], entry['verdict']) == (0, 'failed')
    name = data['free_parameters'][0]
    assert history.estimates(database, entry['platform'], [name])[name] == []  # not usable
    with sqlite3.connect(database) as connection:
        sigma = connection.execute(
            'SELECT sigma_si FROM estimates WHERE parameter = ?', (name,)
        ).fetchone()[0]
    assert sigma is None


def test_runs_started_in_the_same_second_keep_their_order(root, tmp_path):
    # The calibrator names a second run of the same second <stamp>_2.
    for index, (name, *_) in enumerate(RUNS[:2]):
        target = tmp_path / ('20261101T080000Z' + ('_2' if index else ''))
        shutil.copytree(root / name, target)
    database = tmp_path / 'history.sqlite'
    history.rebuild(database, tmp_path)
    found = history.runs(database)
    assert [entry['time_utc'] for entry in found] == ['2026-11-01T08:00:00+00:00'] * 2
    assert [Path(entry['run_dir']).name for entry in found] == [
        '20261101T080000Z',
        '20261101T080000Z_2',
    ]
    assert found[1]['compared_with'] == found[0]['id']
