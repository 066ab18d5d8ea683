"""The history of each platform: every calibration and check, indexed by platform id in SQLite
(docs/upkeep.md)."""

import contextlib
import datetime
import math
import sqlite3
from pathlib import Path

from gsp_calibrator.files.calibration_files import (
    CalibrationFileError,
    calibration_from_check,
    calibration_from_result,
    read_json,
    run_file,
)
from gsp_calibrator.files.run_directory import TIMESTAMP_FORMAT
from gsp_kinematics.upkeep import drift

DATABASE_NAME = 'history.sqlite'
SCHEMA_VERSION = 1
DEFAULT_PLATFORM = 'default'
KINDS = ('calibration', 'check')

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY,
    platform TEXT NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('calibration', 'check')),
    run_dir TEXT NOT NULL UNIQUE,
    time_utc TEXT NOT NULL,
    success INTEGER NOT NULL,
    verdict TEXT,
    position_mm REAL,
    orientation_deg REAL,
    accuracy_source TEXT,
    compared_with INTEGER REFERENCES runs(id) ON DELETE SET NULL
);
CREATE INDEX IF NOT EXISTS runs_by_platform ON runs (platform, time_utc);
CREATE TABLE IF NOT EXISTS changes (
    run_id INTEGER NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    parameter TEXT NOT NULL,
    change_report REAL NOT NULL,
    sigma_report REAL,
    unit TEXT NOT NULL,
    w REAL
);
CREATE TABLE IF NOT EXISTS estimates (
    run_id INTEGER NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    parameter TEXT NOT NULL,
    estimate_si REAL NOT NULL,
    sigma_si REAL,
    PRIMARY KEY (run_id, parameter)
);
"""


class HistoryError(RuntimeError):
    """The history database cannot be used; the message says why."""


def database_path(output_root='runs'):
    return Path(output_root) / DATABASE_NAME


def connect(path):
    """An open connection to the history at ``path`` (created and migrated as needed)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    connection = sqlite3.connect(path, timeout=30.0)
    connection.row_factory = sqlite3.Row
    try:
        connection.execute('PRAGMA journal_mode=WAL')
        connection.execute('PRAGMA synchronous=FULL')
        connection.execute('PRAGMA foreign_keys=ON')
        version = connection.execute('PRAGMA user_version').fetchone()[0]
        if version < SCHEMA_VERSION:
            with connection:
                connection.executescript(_SCHEMA)
                connection.execute(f'PRAGMA user_version={SCHEMA_VERSION}')
    except sqlite3.DatabaseError as error:
        connection.close()
        raise HistoryError(f'{path}: {error}') from None
    if version > SCHEMA_VERSION:
        connection.close()
        raise HistoryError(
            f'{path}: schema version {version} is newer than this suite ({SCHEMA_VERSION})'
        )
    return connection


def opened(path):
    """:func:`connect`, closed at the end of a ``with`` block."""
    return contextlib.closing(connect(path))


def run_time(run_dir):
    """The run's UTC time (ISO 8601): its directory's timestamp name (``<stamp>`` or
    ``<stamp>_2`` ... for runs started in the same second), else the file's mtime."""
    stamp_text = Path(run_dir).name.split('_', 1)[0]
    try:
        stamp = datetime.datetime.strptime(stamp_text, TIMESTAMP_FORMAT)
        return stamp.replace(tzinfo=datetime.UTC).isoformat()
    except ValueError:
        pass
    modified = run_file(run_dir).stat().st_mtime
    return datetime.datetime.fromtimestamp(modified, datetime.UTC).isoformat()


def calibration_accuracy(data):
    """``(position_mm, orientation_deg, source)`` of a ``result.json``: the accuracy measured
    by cross-validation (``accuracy.calibrated``, the verdict's) when the run has it, else the
    predicted accuracy (mean over the workspace)."""
    measured = ((data.get('accuracy') or {}).get('calibrated')) or {}
    position = (measured.get('position_mm') or {}).get('mean')
    if position is not None:
        return position, (measured.get('phi_deg') or {}).get('mean'), 'cross-validated'
    predicted = data.get('predicted_accuracy') or {}
    if predicted.get('position_mm_mean') is not None:
        return predicted['position_mm_mean'], predicted.get('orientation_deg_mean'), 'predicted'
    return None, None, None


def calibration_verdict(data):
    """``(usable, verdict)`` of a ``result.json``: identified and, when the run was judged,
    accepted against the required accuracy (``accepted``, ``not accepted``), else
    ``identified`` or ``failed``."""
    success = bool(data.get('success'))
    if not success:
        return False, 'failed'
    if 'accepted' in data:
        return bool(data['accepted']), 'accepted' if data['accepted'] else 'not accepted'
    return True, 'identified'


def _previous_calibration(connection, platform, time_utc, run_dir):
    return connection.execute(
        "SELECT id, run_dir FROM runs WHERE platform = ? AND kind = 'calibration' "
        'AND success = 1 AND time_utc <= ? AND run_dir != ? ORDER BY time_utc DESC, id DESC '
        'LIMIT 1',
        (platform, time_utc, str(Path(run_dir).resolve())),
    ).fetchone()


def _describe(connection, run_dir, data, platform):
    """The row, changes and estimates of a run (read from its files, before any write)."""
    run_file_path = run_file(run_dir)
    time_utc = run_time(run_dir)
    if data.get('kind') == 'check':
        calibration = calibration_from_check(data, run_file_path)
        accuracy = data.get('accuracy') or {}
        row = {
            'kind': 'check',
            'success': 1,
            'verdict': data.get('verdict'),
            'position_mm': accuracy.get('position_mm_mean'),
            'orientation_deg': accuracy.get('orientation_deg_mean'),
            'accuracy_source': 'check',
        }
        changes, compared_with = list(data.get('moved') or []), None
    else:
        calibration = calibration_from_result(data, run_file_path)
        position, orientation, source = calibration_accuracy(data)
        success, verdict = calibration_verdict(data)
        row = {
            'kind': 'calibration',
            'success': int(success),
            'verdict': verdict,
            'position_mm': position,
            'orientation_deg': orientation,
            'accuracy_source': source,
        }
        changes, compared_with = [], None
        previous = _previous_calibration(connection, platform, time_utc, run_dir)
        if previous is not None and success:
            try:
                before = calibration_from_result(read_json(run_file(previous['run_dir'])))
                changes = drift.compare(before, calibration)['significant']
                compared_with = previous['id']
            except (CalibrationFileError, ValueError):
                pass  # the earlier run's files are gone or unusable: no comparison
    # A rank-deficient fit can leave a variance negative or not finite: no sigma then.
    sigmas = [
        math.sqrt(value) if math.isfinite(value) and value >= 0.0 else None
        for value in map(float, calibration.covariance.diagonal())
    ]
    estimates = list(zip(calibration.names, calibration.estimates.tolist(), sigmas, strict=True))
    row |= {'platform': platform, 'run_dir': str(Path(run_dir).resolve()), 'time_utc': time_utc}
    row['compared_with'] = compared_with
    return row, changes, estimates


def record(path, run_dir, platform=None):
    """Index the calibration or check in ``run_dir`` for ``platform`` (default: the run's own
    ``platform_id``, else :data:`DEFAULT_PLATFORM`) in the history at ``path``, in one
    transaction (a run indexed before is replaced). Returns the run's row id."""
    data = read_json(run_file(run_dir))
    platform = platform or (data.get('options') or {}).get('platform_id') or data.get('platform_id')
    platform = platform or DEFAULT_PLATFORM
    with opened(path) as connection:
        row, changes, estimates = _describe(connection, run_dir, data, platform)
        with connection:  # one transaction: the whole run or nothing
            connection.execute('DELETE FROM runs WHERE run_dir = ?', (row['run_dir'],))
            columns = ', '.join(row)
            cursor = connection.execute(
                f'INSERT INTO runs ({columns}) VALUES ({", ".join("?" * len(row))})',
                tuple(row.values()),
            )
            run_id = cursor.lastrowid
            connection.executemany(
                'INSERT INTO estimates (run_id, parameter, estimate_si, sigma_si) '
                'VALUES (?, ?, ?, ?)',
                [(run_id, *entry) for entry in estimates],
            )
            _insert_changes(connection, run_id, changes)
    return run_id


def _insert_changes(connection, run_id, changes):
    connection.executemany(
        'INSERT INTO changes (run_id, parameter, change_report, sigma_report, unit, w) '
        'VALUES (:run_id, :parameter, :change_report, :sigma_report, :unit, :w)',
        [{'sigma_report': None, 'w': None} | entry | {'run_id': run_id} for entry in changes],
    )


def runs(path, platform=None, kind=None):
    """The indexed runs (dicts, oldest first), each with its ``changes``; filtered by
    ``platform`` and ``kind`` when given."""
    query = (
        'SELECT * FROM runs WHERE (:platform IS NULL OR platform = :platform) '
        'AND (:kind IS NULL OR kind = :kind) ORDER BY time_utc, id'
    )
    arguments = {'platform': platform, 'kind': kind}
    with opened(path) as connection:
        found = [dict(row) for row in connection.execute(query, arguments)]
        for entry in found:
            entry['changes'] = [
                dict(row)
                for row in connection.execute(
                    'SELECT parameter, change_report, sigma_report, unit, w FROM changes '
                    'WHERE run_id = ? ORDER BY abs(w) DESC',
                    (entry['id'],),
                )
            ]
    return found


def platforms(path):
    """``[(platform, runs)]`` of every platform in the history."""
    with opened(path) as connection:
        return [
            tuple(row)
            for row in connection.execute(
                'SELECT platform, count(*) FROM runs GROUP BY platform ORDER BY platform'
            )
        ]


def estimates(path, platform, parameters):
    """``{parameter: [(time_utc, estimate_si, sigma_si)]}`` over the platform's calibrations."""
    series = {name: [] for name in parameters}
    with opened(path) as connection:
        for row in connection.execute(
            'SELECT r.time_utc, e.parameter, e.estimate_si, e.sigma_si FROM estimates e '
            "JOIN runs r ON r.id = e.run_id WHERE r.platform = ? AND r.kind = 'calibration' "
            'AND r.success = 1 ORDER BY r.time_utc, r.id',
            (platform,),
        ):
            if row['parameter'] in series:
                series[row['parameter']].append(
                    (row['time_utc'], row['estimate_si'], row['sigma_si'])
                )
    return series


def rebuild(path, output_root, platform=None):
    """Index every run directory under ``output_root`` (oldest first, so each calibration is
    compared with the one before it). Returns ``(indexed, skipped)``: run directories and
    ``(run_dir, reason)`` pairs."""
    indexed, skipped = [], []
    for run_dir in sorted(Path(output_root).iterdir()):
        if not run_dir.is_dir():
            continue
        try:
            record(path, run_dir, platform)
            indexed.append(run_dir)
        except (CalibrationFileError, ValueError) as error:
            skipped.append((run_dir, str(error)))
    return indexed, skipped
