"""Run directory: unique creation, atomic writes, samples.csv and result.yaml round trips."""

import datetime
import errno
import json
import os

import numpy as np
import pytest

from gsp_calibrator.files.run_directory import (
    SAMPLES_COLUMNS,
    Rows,
    RunDirectory,
    RunDirectoryError,
    read_samples,
    samples_from_csv,
    samples_to_csv,
    write_samples,
)
from gsp_kinematics.fileio import atomic_write_text
from gsp_kinematics.model.geometry import default_geometry

NOW = datetime.datetime(2025, 11, 22, 3, 54, 1, tzinfo=datetime.UTC)


def make_samples(count=4, seed=0):
    rng = np.random.default_rng(seed)
    samples = Rows.empty()
    for k in range(count):
        samples.append(
            k + 1 if k < 2 else k + 2,  # a skipped posture leaves a gap
            rng.normal(size=6),
            rng.uniform(0.1, 0.9, 6) + 1e-17 * k,
            rng.normal(size=4) / 3.0,
            10 - k,
            1.7e9 + rng.uniform(),
            None if k == 1 else rng.uniform(size=(4, (10 - k) // 2 + 1)),  # row 2: none
            None if k == 2 else rng.choice([-1.0, 1.0], size=6),  # row 3: unknown
        )
    return samples


def test_columns_are_exactly_the_contract():
    assert SAMPLES_COLUMNS == (
        'posture',
        'x_cmd',
        'y_cmd',
        'z_cmd',
        'psi_cmd',
        'theta_cmd',
        'phi_cmd',
        'leg_1',
        'leg_2',
        'leg_3',
        'leg_4',
        'leg_5',
        'leg_6',
        'alpha',
        'beta',
        'phi',
        'd_m',
        'n_samples',
        'stamp',
        'lag_sums_leg_lengths',
        'lag_sums_inclinometer',
        'lag_sums_encoder',
        'lag_sums_lvdt',
        'approach_leg_1',
        'approach_leg_2',
        'approach_leg_3',
        'approach_leg_4',
        'approach_leg_5',
        'approach_leg_6',
    )


def test_samples_round_trip_at_full_precision(tmp_path):
    samples = make_samples()
    path = write_samples(tmp_path / 'samples.csv', samples)
    assert path.read_text().splitlines()[0] == ','.join(SAMPLES_COLUMNS)
    back = read_samples(path)
    np.testing.assert_array_equal(back.posture, samples.posture)
    np.testing.assert_array_equal(back.commanded_poses, samples.commanded_poses)  # bit for bit
    np.testing.assert_array_equal(back.leg_lengths, samples.leg_lengths)
    np.testing.assert_array_equal(back.readings, samples.readings)
    np.testing.assert_array_equal(back.n_samples, samples.n_samples)
    np.testing.assert_array_equal(back.stamps, samples.stamps)
    np.testing.assert_array_equal(back.lag_sums, samples.lag_sums)  # NaN where none
    np.testing.assert_array_equal(back.directions, samples.directions)  # 0 where unknown
    assert np.all(back.directions[2] == 0) and np.all(np.abs(back.directions[[0, 1, 3]]) == 1)
    assert back.lag_sums.shape == (4, 4, 6) and np.isnan(back.lag_sums[1]).all()
    assert np.isnan(back.lag_sums[3, :, 4:]).all()  # 7 samples: lags 0..3
    read = read_samples(path)
    assert read.commanded_poses.shape == (4, 6) and read.leg_lengths.shape == (4, 6)
    assert read.readings.shape == (4, 4)
    assert read.n_samples.tolist() == [10, 9, 8, 7] and read.stamps.shape == (4,)


def test_empty_samples_round_trip(tmp_path):
    path = write_samples(tmp_path / 'samples.csv', Rows.empty())
    read = read_samples(path)
    assert read.commanded_poses.shape == (0, 6) and read.readings.shape == (0, 4)
    assert read.n_samples.size == 0


@pytest.mark.parametrize(
    'text, match',
    [
        ('', 'empty'),
        ('a,b\n', 'columns'),
        (','.join(SAMPLES_COLUMNS) + '\n1,2\n', ':2: 2 values'),
        (
            ','.join(SAMPLES_COLUMNS) + '\n' + ','.join(['1'] * 18 + ['x'] + [''] * 10),
            'column stamp',
        ),
        (
            ','.join(SAMPLES_COLUMNS)
            + '\n'
            + ','.join(['1'] * 10 + ['nan'] + ['1'] * 8 + [''] * 10),
            'column leg_4 is not finite',
        ),
        (
            ','.join(SAMPLES_COLUMNS)
            + '\n'
            + ','.join(['1'] * 19 + ['1 2', '3 x', '', ''] + [''] * 6),
            'column lag_sums_inclinometer',
        ),
        (
            ','.join(SAMPLES_COLUMNS)
            + '\n'
            + ','.join(['1'] * 19 + [''] * 4 + ['1', '0.5'] + [''] * 4),
            'column approach_leg_2',
        ),
    ],
)
def test_malformed_samples_are_reported(text, match):
    with pytest.raises(RunDirectoryError, match=match):
        samples_from_csv(text)


@pytest.mark.parametrize('dropped', [6, 10], ids=['no approach directions', 'no lag sums'])
def test_a_samples_file_of_other_columns_is_refused(tmp_path, dropped):
    samples = make_samples()
    path = tmp_path / 'samples.csv'
    cut = [line.split(',')[:-dropped] for line in samples_to_csv(samples).splitlines()]
    path.write_text('\n'.join(','.join(row) for row in cut) + '\n')
    with pytest.raises(RunDirectoryError, match='differ from the expected'):
        read_samples(path)


def test_missing_samples_file_is_reported(tmp_path):
    with pytest.raises(RunDirectoryError, match='cannot read'):
        read_samples(tmp_path / 'nope.csv')


def test_run_directories_are_unique_within_a_second(tmp_path):
    first, second, third = (RunDirectory.create(tmp_path / 'runs', NOW) for _ in range(3))
    assert first.path.name == '20251122T035401Z'
    assert second.path.name == '20251122T035401Z_2' and third.path.name == '20251122T035401Z_3'
    assert first.path.is_dir() and second.path.is_dir() and third.path.is_dir()


def test_run_directory_files(tmp_path):
    run = RunDirectory.create(tmp_path, NOW)
    samples = make_samples(2)
    run.write_samples(samples)
    np.testing.assert_array_equal(run.read_samples().readings, samples.readings)
    geometry = default_geometry('true')
    path = run.write_geometry(geometry, comment='calibrated')
    assert path.name == 'result.yaml' and path.read_text().startswith('# calibrated')
    np.testing.assert_array_equal(run.read_geometry().to_vector(), geometry.to_vector())
    run.write_json('summary.json', {'a': np.float64(1.5), 'b': np.arange(3), 'c': run.path})
    assert json.loads(run.file('summary.json').read_text()) == {
        'a': 1.5,
        'b': [0, 1, 2],
        'c': str(run.path),
    }
    run.write_text('report.md', '# report\n')
    run.write_bytes('recording.mcap', b'\x89MCAP')
    assert sorted(p.name for p in run.path.iterdir()) == [
        'recording.mcap',
        'report.md',
        'result.yaml',
        'samples.csv',
        'summary.json',
    ]
    assert os.fspath(run) == str(run.path)
    with pytest.raises(RunDirectoryError, match='plain file name'):
        run.file('../escape.txt')


def test_atomic_write_leaves_no_temporary_file_and_keeps_the_old_file_on_error(small_disk):
    directory = small_disk.path / 'run'
    path = directory / 'out.json'
    atomic_write_text(path, json.dumps({'v': 1}))
    with pytest.raises(TypeError):  # not serialisable: nothing is written
        RunDirectory(directory).write_json('out.json', {'v': object()})
    small_disk.fill()
    # A full disk: the kernel refuses the new content (more than the old file's page, so that
    # a rewrite in place would be torn, not refused).
    new = {'v': 2, 'text': 'x' * 2 * 4096}
    with pytest.raises(OSError) as raised:
        RunDirectory(directory).write_json('out.json', new)
    assert raised.value.errno == errno.ENOSPC
    assert json.loads(path.read_text()) == {'v': 1}
    assert [p.name for p in directory.iterdir()] == ['out.json']
    small_disk.free()
    RunDirectory(directory).write_json('out.json', new)
    assert json.loads(path.read_text()) == new
    assert [p.name for p in directory.iterdir()] == ['out.json']


def test_csv_text_uses_repr_floats():
    samples = Rows.empty()
    samples.append(1, [0.1] * 6, [1 / 3] * 6, [2 / 3] * 4, 10, 1.7e9 + 0.123456789)
    row = samples_to_csv(samples).splitlines()[1].split(',')
    assert row[7] == repr(1 / 3) and row[18] == repr(1.7e9 + 0.123456789) and row[17] == '10'
    assert row[19:] == [''] * 10
