"""Replay of a run whose route revisits a reference posture (``free_parameters: [auto]``): several
recorded postures share one commanded pose, and the replay serves them in posture order."""

import json

import numpy as np
import pytest
from recorded_runs import write_recording
from replay_suite import CALIBRATION, live_run, replay_run

from gsp_calibrator.files.run_directory import Rows, write_samples
from gsp_calibrator.recording.recorder import RECORDING_FILE
from gsp_calibrator.replay.recorded_run import (
    SOURCE_RECORDING,
    SOURCE_SAMPLES,
    PostureServer,
    RecordedRun,
)
from gsp_msgs_py import conversions

# --- RecordedRun and PostureServer (pure) ----------------------------------------------------------

A = np.array([0.01, -0.02, 1.0, 0.01, -0.02, 0.3])
B = np.array([0.03, 0.01, 1.02, -0.01, 0.02, -0.2])
C = np.array([-0.02, 0.02, 0.98, 0.02, 0.01, 0.5])


def _revisiting_samples(poses):
    """``samples.csv`` rows of postures 1, 2, ... at ``poses``, each with readings of its own."""
    rows = Rows.empty()
    for k, pose in enumerate(poses, start=1):
        rows.append(k, pose, 0.5 + 1e-3 * k + 0.01 * np.arange(6), [0.01 * k, 0, 0, 0], 3, k)
    return rows


def test_visits_are_the_postures_recorded_at_one_pose_in_posture_order(tmp_path):
    write_samples(tmp_path / 'samples.csv', _revisiting_samples([A, B, A, C, A]))
    run = RecordedRun.load(tmp_path)
    assert run.visits(A) == [0, 2, 4] and run.visits(B) == [1] and run.visits(C) == [3]
    # Through a PoseStamped (quaternion) and back: the same visits.
    again = conversions.pose_stamped_to_pose(conversions.pose_to_pose_stamped(A))
    assert run.visits(again) == [0, 2, 4]
    assert run.visits(A + [2e-6, 0, 0, 0, 0, 0]) == []
    assert run.match(A) is run.postures[0]  # the nearest, the first of equals


def test_successive_commands_of_a_revisited_pose_get_the_visits_in_order(tmp_path):
    write_samples(tmp_path / 'samples.csv', _revisiting_samples([A, B, A, C, A]))
    server = PostureServer(RecordedRun.load(tmp_path))

    def served(pose):
        posture = server.serve(pose)
        return None if posture is None else posture.posture

    assert [served(p) for p in (A, B, A, C, A)] == [1, 2, 3, 4, 5]  # the recorded route
    # The same pose again (a command sent again, a resumed calibrator commanding the posture it
    # was collecting): the same visit; a command of no recorded pose changes nothing.
    assert served(A) == 5 and served(A + [1e-3, 0, 0, 0, 0, 0]) is None and served(A) == 5
    # A second run of the route: the visits again, from the first.
    assert [served(p) for p in (B, A, C, A, A)] == [2, 1, 4, 3, 3]


def test_the_stream_before_the_first_command_is_never_at_the_first_posture(tmp_path):
    """A route with revisits ends at its first posture: the replay rests at the last posture
    away from it, else the calibrator would take the first posture's samples for a device still
    reporting the previous posture and skip it."""
    rows = _revisiting_samples([A, B, A, C, A])
    write_samples(tmp_path / 'samples.csv', rows)
    run = RecordedRun.load(tmp_path)
    np.testing.assert_array_equal(run.initial_stream.leg_lengths, rows.leg_lengths[3:4])  # C
    plain = _revisiting_samples([A, B, C])
    write_samples(tmp_path / 'plain.csv', plain)
    run = RecordedRun.load(tmp_path / 'plain.csv')  # the last posture, as before
    np.testing.assert_array_equal(run.initial_stream.leg_lengths, plain.leg_lengths[2:3])


def test_a_recording_s_revisits_are_served_in_recorded_order(tmp_path):
    sent = write_recording(tmp_path / RECORDING_FILE, [A, B, A], per_posture=3)
    run = RecordedRun.load(tmp_path / RECORDING_FILE)
    assert [p.posture for p in run.postures] == [1, 2, 3] and run.visits(A) == [0, 2]
    server = PostureServer(run)
    for k, pose in ((1, A), (2, B), (3, A)):
        np.testing.assert_array_equal(server.serve(pose).stream.leg_lengths, sent[k][0])


# --- replay == original, with reference revisits ---------------------------------------------------

#: The replay tests' calibration (14 postures: fewer leave the 51 parameters unidentifiable),
#: with the route's reference revisit (``auto``): the first posture is commanded again at the
#: end (posture 15).
REVISITS = dict(CALIBRATION, free_parameters=['auto'])


@pytest.fixture(scope='module')
def revisiting_run(tmp_path_factory):
    """One live ``auto`` calibration through platform_sim, device_driver and the calibrator,
    with reference revisits: its run directory."""
    run = live_run(tmp_path_factory, REVISITS)
    kinds = json.loads(run.file('result.json').read_text())['collection']['route_additions']['kind']
    assert [k for k, kind in enumerate(kinds, start=1) if kind == 'reference'] == [15]
    return run


def _replay(context, run, output_root):
    return replay_run(context, run, output_root, REVISITS)


def _assert_same_calibration(original, replayed):
    """Every posture of the original, the reference revisits included, collected again with
    the original's rows (m, rad: far below the sensor noise), and the original's geometry."""
    before, after = original.read_samples(), replayed.read_samples()
    np.testing.assert_array_equal(before.posture, np.arange(1, REVISITS['posture_count'] + 2))
    np.testing.assert_array_equal(after.posture, before.posture)
    np.testing.assert_allclose(after.commanded_poses, before.commanded_poses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(after.leg_lengths, before.leg_lengths, rtol=0, atol=1e-12)
    np.testing.assert_allclose(after.readings, before.readings, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        replayed.read_geometry().to_vector(),
        original.read_geometry().to_vector(),
        rtol=0,
        atol=1e-9,
    )


def test_a_replayed_recording_serves_each_revisit_its_own_samples(
    ros_context, tmp_path, revisiting_run
):
    node, replayed = _replay(
        ros_context, str(revisiting_run.path / RECORDING_FILE), tmp_path / 'replay'
    )
    assert (
        node.run.kind == SOURCE_RECORDING
        and len(node.run.visits(node.run.postures[0].commanded_pose)) == 2
    )
    _assert_same_calibration(revisiting_run, replayed)
    # From the same start as the original (the recorded idle samples): the same directions.
    np.testing.assert_array_equal(
        replayed.read_samples().directions, revisiting_run.read_samples().directions
    )


def test_a_replayed_samples_csv_with_revisits_gives_the_original(
    ros_context, tmp_path, revisiting_run
):
    node, replayed = _replay(ros_context, str(revisiting_run.path), tmp_path / 'replay')
    assert node.run.kind == SOURCE_SAMPLES
    _assert_same_calibration(revisiting_run, replayed)
