"""Keeping a platform calibrated through the nodes (issue 25's 'done when'): a calibration, one leg
offset of platform_sim's truth moved by 20 um, a check that says recalibrate and names the leg, a
second calibration, and the change in the drift comparison and the history. In-process nodes,
as test_calibrator_node runs them."""

import json
from pathlib import Path

from calibrator_suite import make_suite, perturbed_truth
from std_srvs.srv import Trigger

import gsp_calibrator.tools.history
from gsp_calibrator.tools import compare
from gsp_calibrator.upkeep import history
from gsp_experiments.bench_upkeep import changed_truth
from gsp_msgs_py import names

PLATFORM = 'hexapod-test'
#: Guard of each call (s): four runs of 16 postures on a machine that may be loaded.
CALL_TIMEOUT_S = 600.0
CALIBRATOR = {
    'apply_result': True,
    'platform_id': PLATFORM,
    'samples_per_posture': 10,
    'posture_count': 16,
}


def call(suite, service):
    client = suite.client_node.create_client(Trigger, service)
    assert client.wait_for_service(timeout_sec=CALL_TIMEOUT_S)
    return suite.wait(client.call_async(Trigger.Request()), CALL_TIMEOUT_S)


def test_check_after_a_leg_moved_then_recalibrate_and_compare(ros_context, tmp_path, capsys):
    truth = perturbed_truth(tmp_path / 'true.yaml')
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
        moved = changed_truth(truth, 'Loff3', 20e-6)
        platform._simulator._true_geometry = moved  # the test reaches into the simulation
        response = call(suite, names.SERVICE_CHECK)
        assert response.success, response.message
        assert response.message.startswith('check: RECALIBRATE'), response.message
        assert 'moved: Loff3 +0.0' in response.message
        check_dir = response.message.rsplit('run directory: ', 1)[1].strip()
        data = json.loads((Path(check_dir) / 'check.json').read_text())
        assert data['moved_legs'] == [3] and data['verdict'] == 'recalibrate'

        second = suite.wait(suite.call(), CALL_TIMEOUT_S)
        assert second.success, second.message
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
    calibrations = [entry['run_dir'] for entry in found if entry['kind'] == 'calibration']
    assert compare.main(calibrations) == compare.EXIT_CHANGED
    assert 'significant: Loff3 +0.0' in capsys.readouterr().out
    assert (
        gsp_calibrator.tools.history.main(['list', '--root', str(runs), '--platform', PLATFORM])
        == 0
    )
    assert 'moved: Loff3' in capsys.readouterr().out
