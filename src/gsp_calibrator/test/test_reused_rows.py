"""The rows of an earlier run that a calibration identifies with its own (upkeep.reused_rows)."""

import dataclasses

import numpy as np
import pytest

from gsp_calibrator.files.run_directory import Rows, RunDirectory
from gsp_calibrator.run import reused_rows
from gsp_calibrator.run.record import STATE_FILE, RunState, selection_options
from gsp_calibrator.settings import CalibratorSettings
from gsp_kinematics.fileio import atomic_write_text, to_json


def _rows(count, first=1):
    samples = Rows.empty()
    for k in range(first, first + count):
        samples.append(k, np.full(6, 0.01 * k), np.full(6, 0.7), np.zeros(4), 10, 1.7e9 + k)
    return samples


def _run(tmp_path, settings, count=3):
    run = RunDirectory.create(tmp_path)
    run.write_samples(_rows(count))
    state = RunState(selection_options(settings), np.zeros((count, 6)).tolist())
    atomic_write_text(run.file(STATE_FILE), to_json(state.to_dict()))
    return run.path


def test_rows_of_the_same_platform_follow_the_runs_own_renumbered(tmp_path):
    settings = CalibratorSettings.from_values({})
    source = _run(tmp_path, settings)
    reused = reused_rows.load(dataclasses.replace(settings, reuse_rows_from=str(source)))
    together = reused_rows.joined(_rows(2), reused, 5)
    assert list(together.posture) == [1, 2, 5, 6, 7]
    np.testing.assert_allclose(together.commanded_poses[2:], reused.samples.commanded_poses)
    assert reused.record(5) == {'run_directory': str(source), 'rows': 3, 'postures': [5, 6, 7]}
    assert reused_rows.load(settings) is None  # not asked for


def test_rows_of_another_device_are_refused_naming_it(tmp_path):
    settings = CalibratorSettings.from_values({})
    other = settings.nominal.replace(device_length=settings.nominal.device_length + 1e-3)
    source = _run(tmp_path, dataclasses.replace(settings, nominal=other))
    with pytest.raises(reused_rows.ReusedRowsError, match='another device'):
        reused_rows.load(dataclasses.replace(settings, reuse_rows_from=str(source)))
    with pytest.raises(reused_rows.ReusedRowsError, match='reuse_rows_from'):
        reused_rows.load(dataclasses.replace(settings, reuse_rows_from=str(tmp_path / 'none')))
