"""Faults without the full suite of processes: crash-safe recordings, state.json refusals, one
source per topic, a second calibrator, an unwritable output root, signals during shutdown
(docs/faults.md). The runs with killed node processes are in test_fault_processes.py."""

import os
import re
import subprocess
import sys
import threading

import numpy as np
import pytest
from calibrator_suite import make_suite, perturbed_truth
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from gsp_calibrator.collection.single_source import SingleSourceGuard
from gsp_calibrator.files.run_directory import SAMPLES_FILE, Rows, read_samples, write_samples
from gsp_calibrator.recording.mcap_format import RecordingError
from gsp_calibrator.recording.mcap_io import (
    McapRecorder,
    read_recording,
    recording_info,
    recover_recording,
    recover_recordings,
)
from gsp_calibrator.recording.recorder import next_recording_file, recording_parts
from gsp_calibrator.report.data import settle_line, settle_statistics
from gsp_calibrator.run.record import (
    PHASE_COLLECTING,
    PHASE_DONE,
    PHASE_FAILED,
    STATE_FILE,
    ResumeRefused,
    RunRecord,
    RunState,
    latest_unfinished_run,
    postures_to_collect,
    read_state,
    resumable,
    selection_options,
    validate_resume,
)
from gsp_calibrator.settings import CalibratorSettings
from gsp_kinematics.fileio import to_json
from gsp_msgs_py import conversions, names, qos

WRITER = r"""
import sys
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from gsp_calibrator.recording.recorder import McapRecorder
recorder = McapRecorder(sys.argv[1], crash_safe=True)
for n in range(1, 100000):
    recorder.write('/gsp/device/encoder', JointState(name=['phi'], position=[n * 1e-3]), n)
    print(n, flush=True)
"""


def test_a_recording_killed_by_sigkill_yields_every_message_up_to_the_kill(tmp_path):
    path = tmp_path / 'recording.mcap'
    child = subprocess.Popen(
        [sys.executable, '-c', WRITER, str(path)], stdout=subprocess.PIPE, text=True
    )
    written = 0
    for line in child.stdout:  # the child reports each message once it is written
        written = int(line)
        if written >= 500:
            break
    child.kill()
    child.wait()
    assert not path.exists() and (tmp_path / 'recording.mcap.tmp').stat().st_size > 0
    recovered = recover_recording(tmp_path / 'recording.mcap.tmp')
    assert recovered['path'] == str(path) and not (tmp_path / 'recording.mcap.tmp').exists()
    messages = list(read_recording(path))
    assert recovered['message_count'] == len(messages) >= written
    # In order and complete: message n carries n.
    assert [m.log_time_ns for m in messages] == list(range(1, len(messages) + 1))
    assert recording_info(path)['message_count'] == len(messages)


def test_recovery_keeps_every_complete_record_of_a_truncated_file(tmp_path):
    path = tmp_path / 'r.mcap'
    recorder = McapRecorder(path, crash_safe=True)
    for n in range(1, 21):
        recorder.write('/gsp/device/lvdt', JointState(name=['d_m'], position=[0.1]), n)
    data = (tmp_path / 'r.mcap.tmp').read_bytes()
    recorder.abort()
    counts = []
    for cut in (len(data), len(data) - 3, len(data) - 400, 9):
        target = tmp_path / f'cut{cut}'
        target.mkdir()
        (target / 'recording.mcap.tmp').write_bytes(data[:cut])
        counts.append(recover_recordings(target)[0]['message_count'])
        assert len(list(read_recording(target / 'recording.mcap'))) == counts[-1]
    assert counts[0] == 20 and counts[1] == 19 and 10 < counts[2] < 19 and counts[3] == 0
    with pytest.raises(RecordingError, match='exists already'):
        (target / 'recording.mcap.tmp').write_bytes(data)
        recover_recording(target / 'recording.mcap.tmp')


def test_recording_parts_are_read_in_order(tmp_path):
    for name in ('recording-10.mcap', 'recording.mcap', 'recording-2.mcap', 'other.mcap'):
        (tmp_path / name).write_bytes(b'')
    assert [os.path.basename(p) for p in recording_parts(tmp_path)] == [
        'recording.mcap',
        'recording-2.mcap',
        'recording-10.mcap',
    ]
    (tmp_path / 'recording-3.mcap.tmp').write_bytes(b'')
    assert os.path.basename(next_recording_file(tmp_path)) == 'recording-4.mcap'


# --- state.json ------------------------------------------------------------------------------


def _settings(**values):
    return CalibratorSettings.from_values({'posture_count': 4, 'pool_size': 40, **values})


def _state(settings):
    poses = np.arange(24, dtype=float).reshape(4, 6) * 1e-3
    state = RunState(selection_options(settings), poses.tolist())
    state.phase = PHASE_FAILED
    return state, poses


def write_state(directory, state):
    (directory / STATE_FILE).write_text(to_json(state.to_dict()))


def test_state_round_trips_and_lists_what_is_left(tmp_path):
    settings = _settings()
    state, poses = _state(settings)
    state.record_skip(3, 'not settled')
    state.record_done(1)
    run = tmp_path / 'runs' / 'a_run'
    run.mkdir(parents=True)
    write_state(run, state)
    again = read_state(run)
    assert again == state
    samples = Rows.empty()
    samples.append(1, poses[0], np.ones(6), np.ones(4), 5, 0.0)
    validate_resume(again, settings, samples)
    assert postures_to_collect(again, samples) == [2, 3, 4]
    assert latest_unfinished_run(tmp_path / 'runs') == run


def test_settle_waits_survive_a_resume_and_give_the_statistics(tmp_path):
    from gsp_calibrator.collection.synchroniser import PostureRow

    state, _ = _state(_settings())
    rows = {1: (0.004, 0), 2: (0.6, 110), 4: (0.2, 30)}
    for posture, (wait, pairs) in rows.items():
        zeros = np.zeros(6)
        state.record_done(
            posture, PostureRow(zeros, zeros[:4], 10, 0, zeros, zeros[:4], wait, pairs)
        )
    run = tmp_path / 'a_run'
    run.mkdir()
    write_state(run, state)
    again = read_state(run)
    assert again.rest_waits == state.rest_waits
    statistics = settle_statistics(again.rest_waits)
    assert statistics == {
        'rows': 3,
        'median_s': 0.2,
        'max_s': 0.6,
        'mean_s': 0.268,
        'waited': 2,
        'per_posture_s': {'1': 0.004, '2': 0.6, '4': 0.2},
    }
    assert settle_statistics({})['rows'] == 0
    # The response and report.md say it in one line.
    assert settle_line(statistics) == (
        'rest wait (settled to averaged window): median 0.2 s, max 0.6 s over 3 rows; '
        '2 waited for a moving channel'
    )
    assert settle_line(settle_statistics({})) == ''


def test_a_resume_keeps_the_order_and_the_replacements(tmp_path):
    settings = _settings()
    state, poses = _state(settings)
    # Posture 2 was rejected and replaced by posture 5, appended; posture 4 never came.
    state.poses.append((poses[1] + 0.5).tolist())
    state.record_skip(2, 'rejected by the platform: stroke')
    state.replacements.append({'rejected': 2, 'replacement': 5, 'reason': 'stroke'})
    run = tmp_path / 'a_run'
    run.mkdir()
    write_state(run, state)
    again = read_state(run)
    assert again.replacements == state.replacements and again.poses == state.poses
    samples = Rows.empty()
    samples.append(1, poses[0], np.ones(6), np.ones(4), 5, 0.0)
    samples.append(3, poses[2], np.ones(6), np.ones(4), 5, 0.0)
    # In the recorded order, without the replaced posture.
    assert postures_to_collect(again, samples) == [4, 5]


def test_a_row_state_json_does_not_list_yet_is_kept_once_by_a_resume(tmp_path):
    """A calibrator killed after a row reached samples.csv but before state.json was rewritten
    (it lags by the posture being reported): the resume keeps the row, does not command its
    posture again, and counts it done."""
    settings = _settings(resume_run_directory=str(tmp_path))
    state, poses = _state(settings)
    state.phase, state.pid = PHASE_COLLECTING, 0  # as a SIGKILL leaves it
    state.record_done(1)
    state.record_skip(3, 'not settled')
    write_state(tmp_path, state)
    samples = Rows.empty()
    for posture in (1, 2):  # posture 2's row is not in state.json
        samples.append(posture, poses[posture - 1], np.ones(6), np.ones(4), 5, 0.0)
    write_samples(tmp_path / SAMPLES_FILE, samples)
    record = RunRecord.resume(settings, os.getpid())
    try:
        record.begin(settings, None, os.getpid())
        assert record.remaining == [3, 4]
        assert read_state(tmp_path).done == [1, 2]
    finally:
        record.close()
    assert list(read_samples(tmp_path / SAMPLES_FILE).posture) == [1, 2]


def test_the_replacement_is_the_best_remaining_pool_posture():
    from gsp_calibrator.run.postures import PostureReplacer
    from gsp_kinematics.planning.selection import best_addition

    settings = _settings(posture_count=12, pool_size=60, free_parameters=['paper'])
    replacer = PostureReplacer(settings)
    run_poses = replacer.pool[:12]
    pose = replacer(run_poses, rejected=[3])
    expected = best_addition(replacer.information, [k for k in range(12) if k != 2], [2])
    np.testing.assert_array_equal(pose, replacer.pool[expected])
    assert not np.any(np.all(replacer.pool[:12] == pose, axis=1))


@pytest.mark.parametrize(
    'change, named',
    [
        ({'seed': 5}, 'option seed changed'),
        ({'pool_size': 41}, 'option pool_size changed'),
        ({'posture_count': 3}, 'option posture_count changed'),
        ({'formulation': 'fk'}, 'option formulation changed'),
    ],
)
def test_a_resume_that_would_change_the_selection_is_refused_naming_the_option(change, named):
    state, _ = _state(_settings())
    with pytest.raises(ResumeRefused, match=named):
        validate_resume(state, _settings(**change), Rows.empty())


def test_a_resume_with_another_nominal_device_or_rows_is_refused(tmp_path):
    settings = _settings()
    state, poses = _state(settings)
    other = settings.nominal.replace(device_length=settings.nominal.device_length + 1e-3)
    with pytest.raises(ResumeRefused, match='different device'):
        validate_resume(state, _with_nominal(settings, other), Rows.empty())
    other = settings.nominal.replace(leg_offsets=settings.nominal.leg_offsets + 1e-3)
    with pytest.raises(ResumeRefused, match='nominal geometry changed'):
        validate_resume(state, _with_nominal(settings, other), Rows.empty())
    samples = Rows.empty()
    samples.append(2, poses[0], np.ones(6), np.ones(4), 5, 0.0)  # posture 2 at pose 1
    with pytest.raises(ResumeRefused, match='different selection or nominal'):
        validate_resume(state, settings, samples)
    state.phase = PHASE_DONE
    with pytest.raises(ResumeRefused, match='finished'):
        validate_resume(state, settings, Rows.empty())
    with pytest.raises(ResumeRefused, match='no unfinished run'):
        latest_unfinished_run(tmp_path)


def _with_nominal(settings, nominal):
    import dataclasses

    return dataclasses.replace(settings, nominal=nominal)


def test_a_live_run_is_not_resumed_but_a_killed_one_is():
    state, _ = _state(_settings())
    state.phase = PHASE_COLLECTING
    state.pid = os.getpid()  # alive, and not ours
    assert not resumable(state)
    assert resumable(state, own_pid=os.getpid())
    child = subprocess.Popen([sys.executable, '-c', 'pass'])
    child.wait()
    state.pid = child.pid  # gone
    assert resumable(state)


# --- sources -----------------------------------------------------------------------------------


def test_interleaved_sequences_of_two_publishers_are_a_second_source():
    guard = SingleSourceGuard()
    topic = names.TOPIC_ENCODER
    for n in range(100, 110):
        assert guard.check(topic, n, lambda: 1) is None
    assert guard.check(topic, 1, lambda: 1) is None  # one publisher, restarted
    assert guard.check(topic, 2, lambda: 1) is None
    failure = guard.check(topic, 1, lambda: 2)
    assert failure is not None and topic in failure.message and '2 publishers' in failure.message
    assert guard.check(topic, None, lambda: 2) is None  # no sequence numbers: nothing known


# --- the node ----------------------------------------------------------------------------------


@pytest.fixture
def truth_file(tmp_path):
    perturbed_truth(tmp_path / 'true.yaml')
    return tmp_path / 'true.yaml'


def test_a_second_calibrator_on_the_pose_command_is_refused(ros_context, tmp_path, truth_file):
    import rclpy
    from geometry_msgs.msg import PoseStamped

    suite, calibrator, _, _ = make_suite(ros_context, tmp_path, truth_file)
    other = rclpy.create_node(names.NODE_CALIBRATOR, namespace='/second', context=ros_context)
    try:
        other.create_publisher(
            PoseStamped, names.TOPIC_POSE_COMMAND, qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND]
        )
        assert suite.wait_until(
            lambda: any(
                i.node_namespace == '/second'
                for i in calibrator.get_publishers_info_by_topic(names.TOPIC_POSE_COMMAND)
            )
        )
        response = suite.wait(suite.call())
        assert not response.success
        assert 'another calibrator' in response.message and '/second/calibrator' in response.message
        assert not (tmp_path / 'runs').exists()  # refused before anything was written or moved
    finally:
        other.destroy_node()
        suite.close()


def test_an_unwritable_output_root_fails_before_anything_moves(ros_context, tmp_path, truth_file):
    blocked = tmp_path / 'blocked'
    blocked.mkdir()
    (blocked / 'runs').write_text('')  # output_root is blocked/runs: a file, not a directory
    suite, _, _, _ = make_suite(ros_context, blocked, truth_file)
    try:
        response = suite.wait(suite.call())
        assert not response.success
        assert 'cannot write the run directory' in response.message, response.message
        assert not any(p.phase == names.PHASE_MOVING for p in list(suite.progress))
    finally:
        suite.close()


def test_a_flood_from_a_second_publisher_ends_the_run_naming_the_topic(
    ros_context, tmp_path, truth_file
):
    suite, _, _, _ = make_suite(ros_context, tmp_path, truth_file)
    flood = suite.client_node.create_publisher(
        JointState, names.TOPIC_ENCODER, qos.TOPIC_QOS[names.TOPIC_ENCODER]
    )
    stop = threading.Event()

    def publish():  # 1 kHz of valid-looking readings from a second source
        while not stop.wait(0.001):
            stamp = suite.client_node.get_clock().now().to_msg()
            flood.publish(conversions.encoder_to_msg(0.25, stamp))

    thread = threading.Thread(target=publish, daemon=True)
    try:
        thread.start()
        response = suite.wait(suite.call())
        assert not response.success
        assert re.search(f'topic {names.TOPIC_ENCODER} has [2-9] publishers', response.message)
        runs = list((tmp_path / 'runs').iterdir())
        assert read_state(runs[0]).phase == PHASE_FAILED
    finally:
        stop.set()
        thread.join(timeout=5.0)
        suite.close()


def test_parameter_overrides_of_the_resume_directory(ros_context, tmp_path, truth_file):
    """resume_run_directory names the run; a missing state.json is refused with its path."""
    (tmp_path / 'somewhere').mkdir()
    suite, calibrator, _, _ = make_suite(ros_context, tmp_path, truth_file)
    try:
        calibrator.set_parameters(
            [Parameter('resume_run_directory', value=str(tmp_path / 'somewhere'))]
        )
        client = suite.client_node.create_client(Trigger, names.SERVICE_RESUME)
        assert client.wait_for_service(timeout_sec=30.0)
        response = suite.wait(client.call_async(Trigger.Request()))
        assert not response.success
        assert 'resume refused' in response.message and 'state.json' in response.message
    finally:
        suite.close()
