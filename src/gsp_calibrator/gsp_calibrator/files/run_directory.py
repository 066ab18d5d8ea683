"""The run directory of a calibration: ``<root>/<UTC timestamp>/`` (pure, no rclpy).
See docs/data.md."""

import csv
import dataclasses
import datetime
import io
import math
import os
from pathlib import Path

import numpy as np

from gsp_kinematics import channels
from gsp_kinematics.estimation.noise_from_data import LAG_SUMS_CHANNELS
from gsp_kinematics.fileio import atomic_write_bytes, atomic_write_text, to_json
from gsp_kinematics.model.geometry import load_geometry, save_geometry

SAMPLES_FILE = 'samples.csv'
RESULT_FILE = 'result.yaml'
#: The rigid geometry, the identified effects folded in (a controller that cannot compensate them).
RIGID_RESULT_FILE = 'result_rigid.yaml'
SUMMARY_FILE = 'summary.json'
TRUE_GEOMETRY_FILE = 'true_geometry.yaml'

POSE_COLUMNS = ('x_cmd', 'y_cmd', 'z_cmd', 'psi_cmd', 'theta_cmd', 'phi_cmd')
LEG_COLUMNS = channels.LEG_JOINT_NAMES
READING_COLUMNS = channels.READING_NAMES
#: The lag sums of each row's window per noise channel (m^2 and rad^2, space-separated).
LAG_SUM_COLUMNS = tuple(f'lag_sums_{channel}' for channel in LAG_SUMS_CHANNELS)
#: The columns of a row's numbers (m, rad, s), before its lag sums.
ROW_COLUMNS = ('posture',) + POSE_COLUMNS + LEG_COLUMNS + READING_COLUMNS + ('n_samples', 'stamp')
#: Each leg's approach direction: 1 extending, -1 retracting, empty when unknown.
APPROACH_COLUMNS = tuple(f'approach_{leg}' for leg in LEG_COLUMNS)
#: Columns of ``samples.csv`` (docs/data.md), exactly.
SAMPLES_COLUMNS = ROW_COLUMNS + LAG_SUM_COLUMNS + APPROACH_COLUMNS

TIMESTAMP_FORMAT = '%Y%m%dT%H%M%SZ'


class RunDirectoryError(ValueError):
    """A run-directory file is missing or malformed; the message names the file and row."""


# --- samples.csv ---------------------------------------------------------------------------------


@dataclasses.dataclass
class Rows:
    """The rows of ``samples.csv``: M averaged postures, SI units."""

    posture: np.ndarray  #: (M,) int, posture number k (1-based, in commanded order)
    commanded_poses: np.ndarray  #: (M, 6) [x, y, z, psi, theta, phi] commanded, m and rad
    leg_lengths: np.ndarray  #: (M, 6) mean q_i, m
    readings: np.ndarray  #: (M, 4) mean [alpha, beta, phi, d_m], rad and m
    n_samples: np.ndarray  #: (M,) int, synchronised pairs averaged
    stamps: np.ndarray  #: (M,) float, mean stamp, s
    #: (M, 4, L) each row's window lag sums per noise channel (``LAG_SUM_COLUMNS``), NaN where a
    #: row has none or fewer lags; None: no row has them
    lag_sums: np.ndarray | None = None
    #: (M, 6) each leg's approach direction (+1 extending, -1 retracting, 0 unknown); None: all
    #: unknown
    directions: np.ndarray | None = None

    def __post_init__(self):
        self.posture = np.asarray(self.posture, dtype=int).reshape(-1)
        count = self.posture.shape[0]
        self.commanded_poses = np.asarray(self.commanded_poses, dtype=float).reshape(count, 6)
        self.leg_lengths = np.asarray(self.leg_lengths, dtype=float).reshape(count, 6)
        self.readings = np.asarray(self.readings, dtype=float).reshape(count, 4)
        self.n_samples = np.asarray(self.n_samples, dtype=int).reshape(count)
        self.stamps = np.asarray(self.stamps, dtype=float).reshape(count)
        lag_sums = np.full((count, 4, 0), np.nan) if self.lag_sums is None else self.lag_sums
        lag_sums = np.asarray(lag_sums, dtype=float)
        if lag_sums.ndim != 3 or lag_sums.shape[:2] != (count, len(LAG_SUM_COLUMNS)):
            raise ValueError(f'lag_sums must be ({count}, 4, lags), got shape {lag_sums.shape}')
        self.lag_sums = lag_sums
        directions = np.zeros((count, 6)) if self.directions is None else self.directions
        self.directions = np.asarray(directions, dtype=float).reshape(count, 6)

    def __len__(self):
        return int(self.posture.shape[0])

    @classmethod
    def empty(cls):
        return cls([], [], [], [], [], [])

    def append(
        self,
        posture,
        commanded_pose,
        leg_lengths,
        readings,
        n_samples,
        stamp,
        lag_sums=None,
        directions=None,
    ):
        """Add one row (in place); ``lag_sums`` (4, L) or None: its window's lag sums;
        ``directions`` (6,) or None (unknown): the legs' approach directions."""
        row = Rows(
            [posture],
            commanded_pose,
            leg_lengths,
            readings,
            [n_samples],
            [stamp],
            None if lag_sums is None else np.asarray(lag_sums, dtype=float)[None],
            directions,
        )
        width = max(self.lag_sums.shape[2], row.lag_sums.shape[2])
        for table in (self, row):
            pad = ((0, 0), (0, 0), (0, width - table.lag_sums.shape[2]))
            table.lag_sums = np.pad(table.lag_sums, pad, constant_values=np.nan)
        for field in dataclasses.fields(self):
            joined = [getattr(self, field.name), getattr(row, field.name)]
            setattr(self, field.name, np.concatenate(joined))

    def rows(self, keep):
        """The rows ``keep`` (a slice or an index array) as a new :class:`Rows`."""
        return Rows(*(getattr(self, field.name)[keep] for field in dataclasses.fields(self)))


def _lag_sums_text(values):
    return ' '.join(repr(float(v)) for v in values if math.isfinite(v))


def _cell(text, name, where):
    """The value of ``samples.csv``'s column ``name``: a number, a list of lag sums or an
    approach direction (1, -1, or empty: 0); :class:`RunDirectoryError` names the column."""
    if name in APPROACH_COLUMNS:
        if text.strip() not in ('', '1', '-1'):
            raise RunDirectoryError(f'{where}: column {name}: {text!r} is not 1, -1 or empty')
        return int(text.strip() or 0)
    lags = name in LAG_SUM_COLUMNS
    number = int if name in ('posture', 'n_samples') else float
    try:
        values = [float(v) for v in text.split()] if lags else [number(text)]
    except ValueError:
        what = 'space-separated numbers' if lags else 'a number'
        raise RunDirectoryError(f'{where}: column {name}: {text!r} is not {what}') from None
    if not all(math.isfinite(v) for v in values):
        raise RunDirectoryError(f'{where}: column {name} is not finite')
    return values if lags else values[0]


def samples_to_csv(samples, header=True, rows=None):
    """CSV text of ``samples`` (full float precision, ``repr``): the header (``header``) and the
    rows ``rows`` (a range of row indices; default all)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator='\n')
    if header:
        writer.writerow(SAMPLES_COLUMNS)
    for m in range(len(samples)) if rows is None else rows:
        writer.writerow(
            [str(int(samples.posture[m]))]
            + [repr(float(v)) for v in samples.commanded_poses[m]]
            + [repr(float(v)) for v in samples.leg_lengths[m]]
            + [repr(float(v)) for v in samples.readings[m]]
            + [str(int(samples.n_samples[m])), repr(float(samples.stamps[m]))]
            + [_lag_sums_text(values) for values in samples.lag_sums[m]]
            + [str(int(d)) if d else '' for d in samples.directions[m]]
        )
    return buffer.getvalue()


def samples_from_csv(text, source='<string>'):
    """Parse ``samples.csv`` text; :class:`RunDirectoryError` names the row and column."""
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader)
    except StopIteration:
        raise RunDirectoryError(f'{source}: empty file (expected a header)') from None
    if tuple(header) != SAMPLES_COLUMNS:
        raise RunDirectoryError(
            f'{source}: columns {header} differ from the expected {list(SAMPLES_COLUMNS)}'
        )
    columns, numbers, lags = len(header), len(ROW_COLUMNS), len(ROW_COLUMNS) + len(LAG_SUM_COLUMNS)
    rows, lag_rows, direction_rows = [], [], []
    for line, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(row) != columns:
            raise RunDirectoryError(f'{source}:{line}: {len(row)} values, expected {columns}')
        cells = [
            _cell(text, name, f'{source}:{line}')
            for name, text in zip(SAMPLES_COLUMNS, row, strict=True)
        ]
        rows.append(cells[:numbers])
        lag_rows.append(cells[numbers:lags])
        direction_rows.append(cells[lags:])
    if not rows:
        return Rows.empty()
    table = np.array(rows, dtype=float)
    width = max(len(values) for sums in lag_rows for values in sums)
    lag_sums = np.full((len(rows), len(LAG_SUM_COLUMNS), width), np.nan)
    for m, sums in enumerate(lag_rows):
        for channel, values in enumerate(sums):
            lag_sums[m, channel, : len(values)] = values
    columns = (
        table[:, 0],
        table[:, 1:7],
        table[:, 7:13],
        table[:, 13:17],
        table[:, 17],
        table[:, 18],
    )
    return Rows(*columns, lag_sums, np.array(direction_rows, dtype=float))


def write_samples(path, samples):
    """Write ``samples.csv`` atomically."""
    return atomic_write_text(path, samples_to_csv(samples))


class SamplesAppender:
    """Appends rows to an existing ``samples.csv`` as they are collected (one per posture).

    Each row is one ``write`` to a file opened for appending, so it reaches the operating system
    at once (it survives a killed process, not a power cut) without rewriting the file. A row is
    either complete or absent: when a write fails (a full disk) the file is cut back to its
    previous length and the error (an ``OSError`` naming the file) is raised."""

    def __init__(self, path):
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_RDWR | os.O_APPEND)
        self._size = os.fstat(self._fd).st_size
        if self._size and os.pread(self._fd, 1, self._size - 1) != b'\n':
            # A row cut by a crash or a full disk (no newline yet): drop it, as if never written.
            text = os.pread(self._fd, self._size, 0)
            self._size = text.rfind(b'\n') + 1
            os.ftruncate(self._fd, self._size)

    def append(self, samples, row=-1):
        """Append row ``row`` of ``samples`` (default the last)."""
        row = range(len(samples))[row]
        data = samples_to_csv(samples, header=False, rows=(row,)).encode('utf-8')
        try:
            written = 0
            while written < len(data):
                written += self._write(data[written:])
        except OSError as error:
            try:
                os.ftruncate(self._fd, self._size)  # no half row
            except OSError:
                pass
            raise OSError(error.errno, error.strerror or str(error), str(self.path)) from None
        self._size += len(data)

    def _write(self, data):
        return os.write(self._fd, data)

    def close(self):
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def read_samples(path):
    """:class:`Rows` of a ``samples.csv`` file."""
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as error:
        raise RunDirectoryError(f'{path}: cannot read ({error.strerror})') from error
    return samples_from_csv(text, source=str(path))


# --- the directory -------------------------------------------------------------------------------


class RunDirectory:
    """One run directory; every ``write_*`` is atomic and returns the file's path."""

    def __init__(self, path):
        self.path = Path(path)

    @classmethod
    def create(cls, root='runs', now=None):
        """A new ``root/<UTC timestamp>`` directory (``..._2``, ``_3`` ... if it already exists);
        ``now``: an aware datetime, default the current UTC time."""
        root = Path(root)
        root.mkdir(parents=True, exist_ok=True)
        now = now or datetime.datetime.now(datetime.UTC)
        stem = now.astimezone(datetime.UTC).strftime(TIMESTAMP_FORMAT)
        for attempt in range(1, 10_000):
            path = root / (stem if attempt == 1 else f'{stem}_{attempt}')
            try:
                path.mkdir()
            except FileExistsError:
                continue
            return cls(path.resolve())
        raise RunDirectoryError(f'{root}: cannot create a unique run directory for {stem}')

    def __fspath__(self):
        return os.fspath(self.path)

    def __str__(self):
        return str(self.path)

    def file(self, name):
        """Path of ``name`` inside the directory (no sub-paths)."""
        if os.path.basename(name) != name or name in ('', '.', '..'):
            raise RunDirectoryError(f'{name!r} is not a plain file name')
        return self.path / name

    def write_bytes(self, name, data):
        return atomic_write_bytes(self.file(name), data)

    def write_text(self, name, text):
        return atomic_write_text(self.file(name), text)

    def write_json(self, name, data):
        return self.write_text(name, to_json(data))

    def write_samples(self, samples, name=SAMPLES_FILE):
        return write_samples(self.file(name), samples)

    def read_samples(self, name=SAMPLES_FILE):
        return read_samples(self.file(name))

    def write_geometry(self, geometry, name=RESULT_FILE, comment=None):
        """The canonical params file of ``geometry`` (the core's atomic ``save_geometry``)."""
        path = self.file(name)
        save_geometry(geometry, path, comment=comment)
        return path

    def read_geometry(self, name=RESULT_FILE):
        return load_geometry(self.file(name))
