"""The calibrator's check without ROS (gsp_calibrator.upkeep.check_run): what is checked, the
plan, the verdict from collected rows, check.json and its place in the history."""

import json
import shutil

import numpy as np
import pytest
from upkeep_runs import RUNS, write_runs

from gsp_bench.sensor_errors import SAMPLES, SIGMAS, collect
from gsp_bench.upkeep import UpkeepDesign, changed_truth
from gsp_calibrator.files import history
from gsp_calibrator.files.calibration_files import load_calibration
from gsp_calibrator.files.run_directory import Rows
from gsp_calibrator.upkeep import check_run
from gsp_kinematics.estimation.verdict import acceptance
from gsp_kinematics.fileio import write_json
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.motion import MotionLimits
from gsp_kinematics.upkeep import check

REQUIRED = acceptance.Requirement(position_mm=0.05, orientation_deg=0.01)


@pytest.fixture(scope='module')
def root(tmp_path_factory):
    root = tmp_path_factory.mktemp('runs')
    write_runs(root)
    history.rebuild(history.database_path(root), root)
    return root


def collected(true, reference, plan, seed):
    legs, readings, _, commanded = collect(true, reference.geometry, plan.poses, seed)
    count = len(commanded)
    return Rows(
        np.arange(1, count + 1), commanded, legs, readings, np.full(count, SAMPLES), np.zeros(count)
    )


def test_the_reference_is_the_platforms_latest_calibration(root, tmp_path):
    reference = check_run.check_reference(root, 'hexapod-7')
    assert reference.run_dir == str((root / RUNS[-1][0]).resolve())
    assert reference.calibration is not None and len(reference.calibration.names) == 51
    assert reference.noise is None  # these runs were written without a noise estimate
    with pytest.raises(check_run.CheckError, match="no calibration of platform 'other'"):
        check_run.check_reference(tmp_path, 'other')
    # Without a history: the newest run directory with a result.yaml.
    assert check_run.latest_calibration(root / 'missing', 'x') is None


def test_a_check_of_the_calibrated_platform_then_of_a_moved_leg(root, tmp_path):
    design = UpkeepDesign.default()
    reference = check_run.check_reference(root, 'hexapod-7')
    plan = check_run.check_plan(reference, home_pose(), 600, 0, SIGMAS, SAMPLES, MotionLimits())
    assert plan.platform_time_s <= check.CHECK_BUDGET_S
    # The last calibration saw Loff3 + 20 um: that platform is what it describes.
    platform = changed_truth(design.true, 'Loff3', 20e-6)
    data = check_run.evaluate_check(
        reference, collected(platform, reference, plan, 7), SIGMAS, REQUIRED, 'hexapod-7', 55.0
    )
    assert data['verdict'] == 'within tolerance', data['reasons']
    # Then leg 5 moves by 20 um.
    moved = changed_truth(platform, 'Loff5', 20e-6)
    data = check_run.evaluate_check(
        reference, collected(moved, reference, plan, 8), SIGMAS, REQUIRED, 'hexapod-7', 55.0
    )
    assert data['verdict'] == 'recalibrate' and data['moved_legs'] == [5]
    text = check_run.check_summary(data)
    assert text.startswith('check: RECALIBRATE') and 'moved: Loff5 +0.0' in text
    run_dir = tmp_path / '20261120T080000Z'
    run_dir.mkdir()
    write_json(run_dir / 'check.json', data)
    # A check compares with a calibration, and enters the history with its verdict.
    assert load_calibration(run_dir).names == check.CHECK_PARAMETERS
    database = tmp_path / 'history.sqlite'
    history.record(database, root / RUNS[-1][0])
    history.record(database, run_dir)
    last = history.runs(database, 'hexapod-7')[-1]
    assert (last['kind'], last['verdict']) == ('check', 'recalibrate')
    assert [change['parameter'] for change in last['changes']] == ['Loff5']


def test_legs_grown_alike_within_the_requirement_are_a_note(root):
    # Every leg +10 um since the calibration (a warmer platform): about 0.011 mm on the pose,
    # within 0.05 mm. Within tolerance, no leg named, and the summary says why in a note.
    design = UpkeepDesign.default()
    reference = check_run.check_reference(root, 'hexapod-7')
    plan = check_run.check_plan(reference, home_pose(), 600, 0, SIGMAS, SAMPLES, MotionLimits())
    platform = changed_truth(design.true, 'Loff3', 20e-6)  # what the last calibration saw
    for leg in range(1, 7):
        platform = changed_truth(platform, f'Loff{leg}', 10e-6)
    data = check_run.evaluate_check(
        reference, collected(platform, reference, plan, 9), SIGMAS, REQUIRED, 'hexapod-7', 55.0
    )
    assert (data['verdict'], data['moved_legs']) == ('within tolerance', []), data['reasons']
    text = check_run.check_summary(data)
    assert text.startswith('check: WITHIN TOLERANCE')
    assert '\n  note: warm up / common growth: all six leg offsets changed alike' in text


def test_too_few_rows_are_refused(root):
    reference = check_run.check_reference(root, 'hexapod-7')
    with pytest.raises(check_run.CheckError, match='at least 2 postures, 1 collected'):
        check_run.evaluate_check(
            reference,
            Rows([1], np.zeros((1, 6)), np.zeros((1, 6)), np.zeros((1, 4)), [10], [0.0]),
            SIGMAS,
            REQUIRED,
            'hexapod-7',
        )


def test_the_rows_noise_is_the_calibrations_estimate_with_its_unmodelled_error(root, tmp_path):
    data = json.loads((root / RUNS[-1][0] / 'result.json').read_text())
    data['noise_estimates'] = {
        channel: {'estimated': 4.0 * value, 'unmodelled': 0.5 * value}
        for channel, value in SIGMAS.channels().items()
    }
    run_dir = tmp_path / 'run'
    run_dir.mkdir()
    (run_dir / 'result.json').write_text(json.dumps(data))
    shutil.copy(root / RUNS[-1][0] / 'result.yaml', run_dir)
    reference = check_run.check_reference(root, 'x', geometry_file=run_dir / 'result.yaml')
    rows = check_run.row_noise(reference, SIGMAS, [16])
    for channel, value in SIGMAS.channels().items():  # (4 s / 4)^2 + (0.5 s)^2
        assert np.isclose(getattr(rows, channel), value * np.hypot(1.0, 0.5), rtol=1e-12)


def test_a_check_commands_its_own_plan_without_the_runs_workspace_postures():
    """A calibrator set for workspace postures (a calibration's verdict) still checks with its
    plan alone: the posture count the progress and the result give is the plan's."""
    import logging
    import types

    from gsp_calibrator.settings import CalibratorSettings
    from gsp_calibrator.upkeep.check_flow import new_check

    settings = CalibratorSettings.from_values({'workspace_postures': 5, 'stop_when_accurate': True})
    run = new_check(types.SimpleNamespace(log=logging.getLogger('check')), settings)
    assert run.settings.workspace_postures == 0 and not run.settings.stop_when_accurate
    assert run.settings.commanded_posture_count == settings.posture_count
