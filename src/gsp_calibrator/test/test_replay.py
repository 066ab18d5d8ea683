"""Replay of a recorded run: RecordedRun (pure), the replay node, and replay == original."""

import json
import math

import gsp_testing
import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from recorded_runs import MS, T0, write_recording
from replay_suite import CALIBRATION, TIMEOUT_S, live_run, replay_run
from sensor_msgs.msg import JointState

from gsp_calibrator.files.run_directory import Rows, write_samples
from gsp_calibrator.recording.recorder import RECORDING_FILE
from gsp_calibrator.replay.recorded_run import (
    SOURCE_RECORDING,
    SOURCE_SAMPLES,
    RecordedRun,
    ReplayError,
)
from gsp_calibrator.replay.replay_node import REASON_NOT_RECORDED, ReplayNode
from gsp_msgs_py import conversions, names, qos
from gsp_msgs_py.diagnostics import DiagnosticsListener
from gsp_msgs_py.health import OK, Health
from gsp_msgs_py.interfaces.check_tool import PoseCommandProbe
from gsp_msgs_py.parameter_specs import ConfigurationError

# --- recorded runs for the tests -------------------------------------------------------------------


def _samples(count=3):
    rows = Rows.empty()
    for k in range(1, count + 1):
        rows.append(
            k,
            [0.01 * k, -0.02 * k, 1.0, 0.01 * k, -0.02, 0.3 * k],
            0.5 + 0.01 * np.arange(6) + 1e-3 * k,
            [0.01 * k, -0.02, 0.3 * k, 1e-3 * k],
            10,
            100.0 + k,
        )
    return rows


def _poses(count):
    return [
        np.array([0.01 * k, -0.01 * k, 1.0 + 0.001 * k, 0.02, -0.01 * k, 0.1 * k])
        for k in range(1, count + 1)
    ]


# --- RecordedRun -----------------------------------------------------------------------------------


def test_from_samples_one_row_per_posture_and_match(tmp_path):
    rows = _samples(3)
    write_samples(tmp_path / 'samples.csv', rows)
    run = RecordedRun.load(tmp_path)  # a run directory: its samples.csv
    assert run.kind == SOURCE_SAMPLES and len(run) == 3 and not run.has_true_pose
    assert run.source == tmp_path / 'samples.csv'
    for m, posture in enumerate(run.postures):
        assert posture.posture == m + 1 and len(posture.stream) == 1
        np.testing.assert_array_equal(posture.commanded_pose, rows.commanded_poses[m])
        q, r, truth = posture.stream.sample(7)  # cyclic: always the averaged row
        np.testing.assert_array_equal(q, rows.leg_lengths[m])
        np.testing.assert_array_equal(r, rows.readings[m])
        assert truth is None
    # Before the first command: where the recorded run left the platform.
    np.testing.assert_array_equal(run.initial_stream.leg_lengths, rows.leg_lengths[-1:])

    pose = rows.commanded_poses[1]
    assert run.match(pose) is run.postures[1]
    # Through a PoseStamped (quaternion) and back: still the same posture.
    again = conversions.pose_stamped_to_pose(conversions.pose_to_pose_stamped(pose))
    assert run.match(again) is run.postures[1]
    # phi and phi - 2 pi are one orientation.
    assert run.match(pose - [0, 0, 0, 0, 0, 2 * math.pi]) is run.postures[1]
    assert run.match(pose + [5e-7, 0, 0, 0, 0, 0]) is run.postures[1]
    assert run.match(pose + [2e-6, 0, 0, 0, 0, 0]) is None  # position off by 2 um
    assert run.match(pose + [0, 0, 0, 0, 2e-6, 0]) is None  # orientation off by 2 urad
    assert run.match(pose + [0, 0, 0, 0, 2e-6, 0], tolerance=1e-5) is run.postures[1]
    with pytest.raises(ValueError, match='non-finite'):
        run.match(pose + [math.nan, 0, 0, 0, 0, 0])
    with pytest.raises(ValueError, match='shape'):
        run.match(pose[:3])


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(ReplayError, match='no run given'):
        RecordedRun.load('')
    with pytest.raises(ReplayError, match='missing'):
        RecordedRun.load(tmp_path / 'missing')
    with pytest.raises(ReplayError, match='without samples.csv or recording.mcap'):
        RecordedRun.load(tmp_path)
    write_samples(tmp_path / 'samples.csv', Rows.empty())
    with pytest.raises(ReplayError, match='no posture rows'):
        RecordedRun.load(tmp_path / 'samples.csv')
    (tmp_path / 'bad.csv').write_text('a,b\n1,2\n')
    with pytest.raises(ReplayError, match='bad.csv'):
        RecordedRun.load(tmp_path / 'bad.csv')
    (tmp_path / 'bad.mcap').write_bytes(b'not an mcap file')
    with pytest.raises(ReplayError, match='bad.mcap'):
        RecordedRun.load(tmp_path / 'bad.mcap')


def test_from_recording_streams_the_samples_after_each_settle(tmp_path):
    poses = _poses(3)
    path = tmp_path / 'recording.mcap'
    sent = write_recording(path, poses, per_posture=4, rejected={2})
    run = RecordedRun.load(tmp_path)  # a run directory without samples.csv: its recording
    assert run.kind == SOURCE_RECORDING and run.source == path
    assert [p.posture for p in run.postures] == [1, 3] and run.has_true_pose
    assert run.skipped == ((2, 'rejected: out of reach'),)
    assert run.options['sync_tolerance'] == 0.0025
    for posture in run.postures:
        legs, readings, truths = sent[posture.posture]
        np.testing.assert_allclose(posture.commanded_pose, poses[posture.posture - 1], atol=1e-12)
        # In order, paired like the calibrator pairs them; the moving samples are left out.
        np.testing.assert_array_equal(posture.stream.leg_lengths, legs)
        np.testing.assert_array_equal(posture.stream.readings, readings)
        np.testing.assert_allclose(posture.stream.true_poses, truths, atol=1e-12)
        q, _, _ = posture.stream.sample(len(legs))  # cyclic
        np.testing.assert_array_equal(q, legs[0])
        assert run.match(poses[posture.posture - 1]) is posture
    assert run.match(poses[1]) is None  # rejected when recorded
    assert len(run.initial_stream) == 3  # the idle samples before the first command
    np.testing.assert_allclose(run.initial_stream.leg_lengths[:, 0], 0.7 + np.arange(3) * 1e-6)

    # A noted collection start (before the moving samples) makes them count, as for the
    # calibrator; without a true_pose topic there is no true pose to replay.
    noted = tmp_path / 'noted.mcap'
    write_recording(noted, poses[:1], per_posture=2, true_pose=False, notes=True)
    run = RecordedRun.load(noted)
    assert not run.has_true_pose and len(run.postures[0].stream) == 3
    assert run.postures[0].stream.leg_lengths[0, 0] == 9.0


def test_a_command_sent_again_is_one_posture_in_the_replay_and_the_rebuild(tmp_path):
    """The calibrator sends an unanswered command again with its stamp: both copies are in the
    recording, and the replay and the rebuilt rows are those of a command sent once."""
    from gsp_calibrator.recording import rebuild

    poses = _poses(3)
    runs = {}
    for name, resent in (('once', ()), ('again', (1, 3))):
        (tmp_path / name).mkdir()
        path = tmp_path / name / 'recording.mcap'
        write_recording(path, poses, per_posture=4, notes=True, resent=resent)
        rows = rebuild.samples_from_recording(path, pairs_per_posture=4)
        runs[name] = RecordedRun.load(path), rows
    (once, once_rows), (again, again_rows) = runs['once'], runs['again']
    assert [p.posture for p in again.postures] == [1, 2, 3] and not again.skipped
    for posture, reference in zip(again.postures, once.postures, strict=True):
        np.testing.assert_array_equal(posture.stream.leg_lengths, reference.stream.leg_lengths)
        np.testing.assert_array_equal(posture.stream.readings, reference.stream.readings)
    assert list(again_rows.posture) == list(once_rows.posture) == [1, 2, 3]
    np.testing.assert_array_equal(again_rows.leg_lengths, once_rows.leg_lengths)


def test_a_resumed_run_is_replayed_from_every_recording_part(tmp_path):
    poses = _poses(4)
    run_dir = tmp_path / 'run'
    run_dir.mkdir()
    # Session 1: postures 1-3, posture 2 rejected; posture 3 is collected again in session 2.
    first = write_recording(run_dir / 'recording.mcap', poses[:3], per_posture=4, rejected={2})
    # Session 2 (resumed, 10 s later): postures 2 (accepted now), 3 again and 4, as noted.
    second = write_recording(
        run_dir / 'recording-2.mcap',
        poses[1:],
        per_posture=6,
        notes=True,
        start_ns=T0 + 10_000 * MS,
        numbers=[2, 3, 4],
        note_after_ns=10 * MS,
    )
    for given in (run_dir, run_dir / 'recording.mcap'):
        run = RecordedRun.load(given)
        assert run.parts == (run_dir / 'recording.mcap', run_dir / 'recording-2.mcap')
        assert run.source == run_dir / 'recording.mcap' and run.kind == SOURCE_RECORDING
        assert [p.posture for p in run.postures] == [1, 2, 3, 4]
        assert run.skipped == ()  # posture 2, rejected in session 1, was collected in session 2
        for posture in run.postures:
            legs, readings, truths = (first if posture.posture == 1 else second)[posture.posture]
            np.testing.assert_array_equal(posture.stream.leg_lengths, legs)
            np.testing.assert_array_equal(posture.stream.readings, readings)
            np.testing.assert_allclose(posture.stream.true_poses, truths, atol=1e-12)
            assert run.match(poses[posture.posture - 1]) is posture
        assert len(run.postures[2].stream) == 6  # session 2's segment of posture 3, not 4 samples
        assert len(run.initial_stream) == 3  # session 1's idle samples
        assert run.initial_stream.true_poses[0, 2] == 1.0

    # A later part given by name is read alone.
    alone = RecordedRun.load(run_dir / 'recording-2.mcap')
    assert alone.parts == (run_dir / 'recording-2.mcap',)
    assert [p.posture for p in alone.postures] == [2, 3, 4]


# --- the replay node -------------------------------------------------------------------------------


class NodeHarness:
    """The replay node plus a test node that commands poses and records what comes back."""

    def __init__(self, context, overrides):
        self.replay = ReplayNode(context=context, parameter_overrides=list(overrides))
        self.node = rclpy.create_node('replay_test', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.replay)
        self.executor.add_node(self.node)
        self.commands = PoseCommandProbe(self.node)
        self.diagnostics = DiagnosticsListener(self.node)
        self.received = {
            topic: []
            for topic in (
                names.TOPIC_LEG_LENGTHS,
                names.TOPIC_INCLINOMETER,
                names.TOPIC_ENCODER,
                names.TOPIC_LVDT,
            )
        }
        self.true_poses = []
        for topic, messages in self.received.items():
            self.node.create_subscription(JointState, topic, messages.append, qos.TOPIC_QOS[topic])
        self.node.create_subscription(
            PoseStamped,
            names.TOPIC_TRUE_POSE,
            self.true_poses.append,
            qos.TOPIC_QOS[names.TOPIC_TRUE_POSE],
        )
        assert self.spin_until(
            lambda: self.commands.listened() and self.received[names.TOPIC_LVDT]
        ), 'no discovery'

    def spin_until(self, predicate, timeout=TIMEOUT_S):
        return gsp_testing.spin_until(self.executor, predicate, timeout)

    def command(self, pose, frame_id=names.FRAME_BASE):
        return self.commands.send(pose, frame_id)

    def final_states(self, command_id):
        """Every status of ``command_id`` once it is settled or rejected."""
        assert self.spin_until(lambda: self.commands.final_status(command_id) is not None)
        return self.commands.answers(command_id)

    def instants_after(self, stamp_ns, count):
        """``count`` replayed instants stamped after ``stamp_ns``: ``[(stamp, {topic: msg})]``."""

        def instants():
            by_stamp = {}
            for topic, messages in self.received.items():
                for msg in messages:
                    stamp = conversions.stamp_to_nanoseconds(msg.header.stamp)
                    if stamp > stamp_ns:
                        by_stamp.setdefault(stamp, {})[topic] = msg
            return sorted((s, m) for s, m in by_stamp.items() if len(m) == 4)

        assert self.spin_until(lambda: len(instants()) >= count)
        return instants()[:count]

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.replay.destroy_node()


def test_node_replays_a_recorded_posture_like_the_live_suite(ros_context, tmp_path):
    poses = _poses(2)
    path = tmp_path / 'recording.mcap'
    sent = write_recording(path, poses, per_posture=3)
    harness = NodeHarness(
        ros_context,
        [
            Parameter('run', value=str(path)),
            Parameter('settle_time', value=0.02),
            Parameter('publish_rate', value=20.0),
            Parameter('diagnostics_period', value=0.05),
        ],
    )
    try:
        # Before any command: the idle samples recorded before the first command.
        first = harness.instants_after(0, 1)[0][1]
        assert conversions.msg_to_leg_lengths(first[names.TOPIC_LEG_LENGTHS])[0] == pytest.approx(
            0.7, abs=1e-5
        )

        # The replay's own time from which the stream restarts after 'settled' (however late
        # this test sees the status): noted where the node restarts it.
        restarts = []
        commands = harness.replay._commands
        restart_stream = commands._on_settled

        def noted_restart(command_id):
            restart_stream(command_id)
            restarts.append(harness.replay._resume_ns)

        commands._on_settled = noted_restart
        command_id = harness.command(poses[1])
        assert [s.state for s in harness.final_states(command_id)] == ['moving', 'settled']
        assert restarts
        legs, readings, truths = sent[2]
        # From the first recorded sample, in order, cyclically; one stamp per instant.
        instants = harness.instants_after(restarts[-1] - 1, 4)
        for j, (_, messages) in enumerate(instants):
            np.testing.assert_array_equal(
                conversions.msg_to_leg_lengths(messages[names.TOPIC_LEG_LENGTHS]), legs[j % 3]
            )
            alpha, beta = conversions.msg_to_inclinometer(messages[names.TOPIC_INCLINOMETER])
            assert [
                alpha,
                beta,
                conversions.msg_to_encoder(messages[names.TOPIC_ENCODER]),
                conversions.msg_to_lvdt(messages[names.TOPIC_LVDT]),
            ] == list(readings[j % 3])
            assert all(m.header.frame_id == names.FRAME_BASE for m in messages.values())
        stamps = [s for s, _ in instants]
        assert harness.spin_until(
            lambda: any(
                conversions.stamp_to_nanoseconds(m.header.stamp) == stamps[1]
                for m in harness.true_poses
            )
        )
        truth = next(
            m
            for m in harness.true_poses
            if conversions.stamp_to_nanoseconds(m.header.stamp) == stamps[1]
        )
        np.testing.assert_allclose(conversions.pose_stamped_to_pose(truth), truths[1], atol=1e-9)

        # Not recorded, or wrong: rejected with the reason; the node keeps going.
        unknown = harness.command(poses[1] + [0.01, 0, 0, 0, 0, 0])
        assert [(s.state, s.reason) for s in harness.final_states(unknown)] == [
            ('rejected', REASON_NOT_RECORDED)
        ]
        wrong_frame = harness.command(poses[0], frame_id='elsewhere')
        (status,) = harness.final_states(wrong_frame)
        assert status.rejected and 'elsewhere' in status.reason
        again = harness.command(poses[0])
        assert [s.state for s in harness.final_states(again)] == ['moving', 'settled']

        # Run-time parameters are validated.
        assert not harness.replay.set_parameters([Parameter('settle_time', value=-1.0)])[
            0
        ].successful
        assert not harness.replay.set_parameters([Parameter('pose_tolerance', value=0.0)])[
            0
        ].successful
        assert harness.replay.set_parameters([Parameter('pose_tolerance', value=0.05)])[
            0
        ].successful
        near = harness.command(poses[1] + [0.01, 0, 0, 0, 0, 0])
        assert harness.final_states(near)[-1].settled

        # /diagnostics counts them as platform_sim does: 5 commands, 3 settled, 2 refused.
        reports = harness.diagnostics.reports
        assert harness.spin_until(
            lambda: reports.get('replay: commands', Health(OK, '')).values.get('settled') == '3'
        ), reports
        health = reports['replay: commands']
        assert health.level == OK and health.values['refused'] == '2'
        assert health.values['commands'] == '5' and REASON_NOT_RECORDED not in health.message
    finally:
        harness.close()


def test_node_configuration_errors(ros_context, tmp_path):
    with pytest.raises(ConfigurationError, match='run: .*required'):
        ReplayNode(context=ros_context)
    with pytest.raises(ConfigurationError, match='run: .*missing'):
        ReplayNode(
            context=ros_context,
            parameter_overrides=[Parameter('run', value=str(tmp_path / 'missing'))],
        )
    write_samples(tmp_path / 'samples.csv', _samples(2))
    with pytest.raises(ConfigurationError, match='pose_tolerance'):
        ReplayNode(
            context=ros_context,
            parameter_overrides=[
                Parameter('run', value=str(tmp_path)),
                Parameter('pose_tolerance', value=0.0),
            ],
        )
    with pytest.raises(ConfigurationError, match='publish_rate'):
        ReplayNode(
            context=ros_context,
            parameter_overrides=[
                Parameter('run', value=str(tmp_path)),
                Parameter('publish_rate', value=-5.0),
            ],
        )
    node = ReplayNode(
        context=ros_context, parameter_overrides=[Parameter('run', value=str(tmp_path))]
    )
    try:
        # samples.csv has no true pose: nothing is published on true_pose.
        assert node.count_publishers(names.TOPIC_TRUE_POSE) == 0
        assert node.run.kind == SOURCE_SAMPLES
    finally:
        node.destroy_node()


# --- replay == original ----------------------------------------------------------------------------


@pytest.fixture(scope='module')
def original_run(tmp_path_factory):
    """One live calibration through platform_sim, device_driver and the calibrator: its run
    directory (``samples.csv``, ``recording.mcap``, ``result.json``), shared by the replays."""
    return live_run(tmp_path_factory)


def test_replay_gives_a_calibration_equal_to_the_original(ros_context, tmp_path, original_run):
    """From the run directory, i.e. its samples.csv: the averaged rows, republished as they are,
    are averaged again into the same rows, so the calibration is the same by construction."""
    node, replayed = replay_run(ros_context, str(original_run.path), tmp_path / 'replay')
    assert node.run.kind == SOURCE_SAMPLES
    _assert_same_calibration(original_run, replayed)


def _assert_same_calibration(original, replayed):
    """The replayed run collected the original's rows and identified the original's geometry."""
    assert replayed.path != original.path
    before, after = original.read_samples(), replayed.read_samples()
    assert len(before) >= CALIBRATION['posture_count'] - 2
    np.testing.assert_array_equal(after.posture, before.posture)
    np.testing.assert_array_equal(after.n_samples, before.n_samples)
    np.testing.assert_allclose(after.commanded_poses, before.commanded_poses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(after.leg_lengths, before.leg_lengths, rtol=0, atol=1e-12)  # m
    np.testing.assert_allclose(after.readings, before.readings, rtol=0, atol=1e-12)  # rad, m
    np.testing.assert_allclose(
        replayed.read_geometry().to_vector(),
        original.read_geometry().to_vector(),
        rtol=0,
        atol=1e-9,  # m and rad: far below any parameter's 1-sigma (um, urad)
    )


def test_replay_from_the_recording_collects_the_original_raw_samples(
    ros_context, tmp_path, original_run
):
    """From ``recording.mcap``: every posture's raw synchronised samples, one per instant, are
    published again and collected again by a fresh calibrator.

    By design this reproduces the original exactly, not merely within its standard deviations:
    after ``settled`` the replay restarts the posture's stream at the first sample the original
    calibrator counted (replay_node.RESTART_PERIODS), in recorded order, and the calibrator takes
    the first ``pairs_per_posture`` pairs, so it averages the very samples the original
    averaged (measured: identical rows and geometry). A replay that collected other samples
    (another window, a dropped or shifted sample, another pairing) would differ by the sensor
    noise (1 um, 1 mdeg), far above the 1e-12 tolerances. What tells a replay of the raw samples
    from a copy of the averaged rows is the scatter within each posture: the calibrator
    estimates each sensor's noise from it (``noise_estimates``), and a stream that republishes
    one averaged row per posture has none.
    """
    node, replayed = replay_run(
        ros_context, str(original_run.path / RECORDING_FILE), tmp_path / 'replay'
    )
    assert node.run.kind == SOURCE_RECORDING
    assert all(len(p.stream) >= CALIBRATION['pairs_per_posture'] for p in node.run.postures)
    _assert_same_calibration(original_run, replayed)

    noise_before = json.loads(original_run.file('result.json').read_text())['noise_estimates']
    noise_after = json.loads(replayed.file('result.json').read_text())['noise_estimates']
    assert set(noise_after) == {'leg_lengths', 'inclinometer', 'encoder', 'lvdt'}
    for sensor, entry in noise_before.items():
        # The same samples, so the same scatter: about the configured 1 um or 1 mdeg.
        assert entry['estimated'] > 0.1 * entry['configured'], (sensor, entry)
        assert noise_after[sensor]['estimated'] == pytest.approx(entry['estimated'], rel=1e-9), (
            sensor,
            noise_after[sensor],
            entry,
        )
