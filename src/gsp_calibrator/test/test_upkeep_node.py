"""Keeping a platform calibrated through the nodes (issue 25's 'done when'): a calibration, one leg
offset of platform_sim's truth moved by 20 um, a check that says recalibrate and names the leg, a
second calibration, and the change in the drift comparison and the history. In-process nodes,
as test_calibrator_node runs them."""

import json
from pathlib import Path

import numpy as np
from calibrator_suite import make_suite, perturbed_truth
from std_srvs.srv import Trigger

import gsp_calibrator.tools.history
from gsp_calibrator.files import history
from gsp_calibrator.tools import compare
from gsp_msgs_py import names

PLATFORM = 'hexapod-test'
#: Guard of each call (s): four runs of 16 postures on a machine that may be loaded.
CALL_TIMEOUT_S = 600.0
CALIBRATOR = {
    'apply_result': True,
    'platform_id': PLATFORM,
    'pairs_per_posture': 10,
    'posture_count': 16,
}


def call(suite, service):
    client = suite.client_node.create_client(Trigger, service)
    assert client.wait_for_service(timeout_sec=CALL_TIMEOUT_S)
    return suite.wait(client.call_async(Trigger.Request()), CALL_TIMEOUT_S)


def test_check_after_a_leg_moved_then_recalibrate_and_compare(ros_context, tmp_path, capsys):
    truth = perturbed_truth(tmp_path / 'true.yaml')
    from rclpy.parameter import Parameter

    suite, calibrator, platform, _ = make_suite(
        ros_context, tmp_path, tmp_path / 'true.yaml', CALIBRATOR
    )
    runs = tmp_path / 'runs'
    database = history.database_path(runs)
    try:
        # No calibration yet: the check says what to do.
        response = call(suite, names.SERVICE_CHECK)
        assert not response.success and 'run a calibration first' in response.message

        first = suite.wait(suite.call(), CALL_TIMEOUT_S)
        assert first.success, first.message
        # The calibrated platform, checked at once: within tolerance.
        response = call(suite, names.SERVICE_CHECK)
        assert response.success and response.message.startswith('check: WITHIN TOLERANCE'), (
            response.message
        )

        # Leg 3's offset moves by 20 um (the hardware; the controller keeps its geometry).
        moved = truth.replace(leg_offsets=truth.leg_offsets + np.array([0, 0, 20e-6, 0, 0, 0]))
        platform._simulator._true_geometry = moved  # the test reaches into the simulation
        response = call(suite, names.SERVICE_CHECK)
        assert response.success, response.message
        assert response.message.startswith('check: RECALIBRATE'), response.message
        assert 'moved: Loff3 +0.0' in response.message
        check_dir = response.message.rsplit('run directory: ', 1)[1].strip()
        data = json.loads((Path(check_dir) / 'check.json').read_text())
        assert data['moved_legs'] == [3] and data['verdict'] == 'recalibrate'

        # The recalibration identifies the check's rows with its own (reuse_rows_from).
        check_rows = len((Path(check_dir) / 'samples.csv').read_text().strip().splitlines()) - 1
        reuse = Parameter('reuse_rows_from', value=check_dir)
        assert calibrator.set_parameters([reuse])[0].successful
        second = suite.wait(suite.call(), CALL_TIMEOUT_S)
        assert second.success, second.message
        assert f'{16 + check_rows} posture(s)' in second.message.splitlines()[0], second.message
    finally:
        suite.close()

    found = history.runs(database, PLATFORM)
    assert [(entry['kind'], entry['verdict']) for entry in found] == [
        ('calibration', 'accepted'),
        ('check', 'within tolerance'),
        ('check', 'recalibrate'),
        ('calibration', 'accepted'),
    ]
    assert [change['parameter'] for change in found[2]['changes']] == ['Loff3']
    assert [change['parameter'] for change in found[3]['changes']] == ['Loff3']
    assert 0.015 < found[3]['changes'][0]['change_report'] < 0.025  # mm
    reused = json.loads((Path(found[3]['run_dir']) / 'result.json').read_text())['collection'][
        'reused_rows'
    ]
    assert reused['run_directory'] == found[2]['run_dir'] and reused['rows'] == check_rows
    calibrations = [entry['run_dir'] for entry in found if entry['kind'] == 'calibration']
    assert compare.main(calibrations) == compare.EXIT_CHANGED
    assert 'significant: Loff3 +0.0' in capsys.readouterr().out
    assert (
        gsp_calibrator.tools.history.main(['list', '--root', str(runs), '--platform', PLATFORM])
        == 0
    )
    assert 'moved: Loff3' in capsys.readouterr().out


def _run_directory(runs):
    """The newest calibration run directory under ``runs``."""
    return sorted(path for path in runs.iterdir() if (path / 'result.json').is_file())[-1]


def test_a_run_stops_when_good_enough_or_adds_pool_postures(ros_context, tmp_path):
    from rclpy.parameter import Parameter

    perturbed_truth(tmp_path / 'true.yaml')
    overrides = {
        'posture_count': 16,
        'stop_when_accurate': True,
        'stop_minimum_postures': 6,
        'stop_every': 2,
        'stop_max_added': 2,
    }
    suite, calibrator, _, _ = make_suite(ros_context, tmp_path, tmp_path / 'true.yaml', overrides)
    runs = tmp_path / 'runs'
    try:
        # A loose requirement (the default 0.1 mm): met by the first judgements, long before
        # the plan's 16 postures.
        loose = suite.wait(suite.call(), CALL_TIMEOUT_S)
        assert loose.success, loose.message
        assert 'stopped when accurate: ' in loose.message, loose.message
        loose_dir = _run_directory(runs)
        record = json.loads((loose_dir / 'result.json').read_text())['collection'][
            'run_to_requirement'
        ]
        assert record['met'] and record['added'] == 0 and record['fixed_plan_postures'] == 16
        assert 6 <= record['postures'] < 16
        assert record['platform_time_s'] < record['fixed_plan_time_s']
        assert record['bounds']['position_bound_mm'] <= 0.1
        rows = (loose_dir / 'samples.csv').read_text().strip().splitlines()[1:]
        assert len(rows) == record['postures']

        # A requirement no run can meet: the whole plan of 8, then 2 pool postures, and it
        # says it could not (the result is written, not applied).
        for name, value in (('required_position_accuracy_mm', 1e-6), ('posture_count', 8)):
            assert calibrator.set_parameters([Parameter(name, value=value)])[0].successful
        strict = suite.wait(suite.call(), CALL_TIMEOUT_S)
        assert not strict.success
        assert 'could not meet the required accuracy in 10 postures (2 added from the pool)' in (
            strict.message
        )
    finally:
        suite.close()
    strict_dir = _run_directory(runs)
    assert strict_dir != loose_dir
    record = json.loads((strict_dir / 'result.json').read_text())['collection'][
        'run_to_requirement'
    ]
    assert not record['met'] and record['added'] == 2 and record['postures'] == 10
    assert record['fixed_plan_postures'] == 8
    assert record['platform_time_s'] > record['fixed_plan_time_s']
    state = json.loads((strict_dir / 'state.json').read_text())
    assert state['added'] == 2 and len(state['poses']) == 10
    assert len((strict_dir / 'samples.csv').read_text().strip().splitlines()) == 1 + 10
