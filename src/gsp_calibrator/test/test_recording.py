"""recording.mcap: message definitions, MCAP format, atomic writes, round trips, RunRecorder."""

import math
import os
import time

import numpy as np
import pytest
import yaml
from recorded_runs import write_command

from gsp_calibrator.collection.synchroniser import SampleCollector
from gsp_calibrator.collection.topics import SENSOR_TOPICS
from gsp_calibrator.files.run_directory import read_samples, write_samples
from gsp_calibrator.recording import rebuild
from gsp_calibrator.recording.mcap_format import (
    MessageDefinitionError,
    RecordingError,
    message_definition,
    msg_file,
)
from gsp_calibrator.recording.mcap_io import (
    RUN_METADATA_NAME,
    McapRecorder,
    read_recording,
    recording_info,
    recording_options,
)
from gsp_calibrator.recording.recorder import (
    OUTCOMES_METADATA_NAME,
    POSTURE_METADATA_NAME,
    SUITE_TOPICS,
    RunRecorder,
    note_posture_end,
)
from gsp_calibrator.replay.recorded_run import RecordedRun
from gsp_msgs_py import conversions, names
from gsp_msgs_py.qos import TOPIC_QOS

MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000
SEPARATOR = '=' * 80 + '\n'


def _msg_text(package, name):
    with open(msg_file(f'{package}/msg/{name}'), encoding='utf-8') as stream:
        return stream.read()


# --- message definitions -------------------------------------------------------------------------


def test_definition_is_rosbag2_concatenation():
    text = message_definition('sensor_msgs/msg/JointState')
    assert text.startswith(_msg_text('sensor_msgs', 'JointState'))
    header = '\n' + SEPARATOR + 'MSG: std_msgs/Header\n' + _msg_text('std_msgs', 'Header')
    time_part = (
        '\n'
        + SEPARATOR
        + 'MSG: builtin_interfaces/Time\n'
        + _msg_text('builtin_interfaces', 'Time')
    )
    assert text == _msg_text('sensor_msgs', 'JointState') + header + time_part
    # pkg/Type and pkg/msg/Type name the same type
    assert message_definition('sensor_msgs/JointState') == text


def test_definition_nested_types_once():
    text = message_definition('visualization_msgs/msg/MarkerArray')
    headers = [line for line in text.splitlines() if line.startswith('MSG: ')]
    assert len(headers) == len(set(headers))
    for nested in (
        'visualization_msgs/Marker',
        'std_msgs/Header',
        'builtin_interfaces/Time',
        'builtin_interfaces/Duration',
        'geometry_msgs/Pose',
        'geometry_msgs/Point',
        'geometry_msgs/Quaternion',
        'geometry_msgs/Vector3',
        'std_msgs/ColorRGBA',
    ):
        assert f'MSG: {nested}' in headers
    assert text.count(SEPARATOR) == len(headers)


def test_definition_errors_name_the_type():
    with pytest.raises(MessageDefinitionError, match='no_such_pkg/msg/Thing'):
        message_definition('no_such_pkg/msg/Thing')
    with pytest.raises(MessageDefinitionError, match='std_msgs/msg/NoSuchType'):
        message_definition('std_msgs/msg/NoSuchType')
    with pytest.raises(MessageDefinitionError, match='not of the form'):
        message_definition('JointState')


# --- writing and reading -------------------------------------------------------------------------


def test_mcap_format_atomic_and_round_trip(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rclpy.serialization import serialize_message

    path = tmp_path / 'recording.mcap'
    legs = conversions.leg_lengths_to_msg(np.arange(6) * 0.1, T0 / 1e9)
    status = conversions.make_status('42', names.STATE_SETTLED)
    recorder = McapRecorder(path)
    for topic, type_name in names.TOPIC_TYPES.items():
        recorder.add_topic(topic, type_name)
    recorder.write(names.TOPIC_LEG_LENGTHS, legs, T0 + 1, T0)
    recorder.write(names.TOPIC_PLATFORM_STATUS, serialize_message(status), T0 + 2)  # raw CDR
    recorder.write('/extra', conversions.encoder_to_msg(0.5), T0 + 3)  # added from its type
    assert not path.exists() and os.path.exists(str(path) + '.tmp')
    assert recorder.close() == str(path)
    assert path.exists() and not os.path.exists(str(path) + '.tmp')

    read = list(read_recording(path))
    assert [m.topic for m in read] == [
        names.TOPIC_LEG_LENGTHS,
        names.TOPIC_PLATFORM_STATUS,
        '/extra',
    ]
    assert read[0].type_name == 'sensor_msgs/msg/JointState'
    assert read[0].log_time_ns == T0 + 1 and read[0].publish_time_ns == T0
    assert read[0].message == legs and read[1].message == status
    assert read[2].type_name == 'sensor_msgs/msg/JointState'

    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
        channels = {c.topic: c for c in summary.channels.values()}
        profiles = yaml.safe_load(
            channels[names.TOPIC_LEG_LENGTHS].metadata['offered_qos_profiles']
        )
        assert profiles[0]['reliability'] == 'best_effort'
        assert profiles[0]['depth'] == TOPIC_QOS[names.TOPIC_LEG_LENGTHS].depth
        latched = yaml.safe_load(
            channels[names.TOPIC_CALIBRATION_RESULT].metadata['offered_qos_profiles']
        )
        assert latched[0]['durability'] == 'transient_local'
        # A reader that only knows the schemas (as Foxglove) decodes every message.
        decoded = [m for _, _, _, m in reader.iter_decoded_messages()]
    assert list(decoded[0].position) == pytest.approx(list(legs.position))
    assert decoded[1].values[0].value == '42'

    info = recording_info(path)
    assert info['message_count'] == 3 and info['profile'] == 'ros2'
    assert info['topics'][names.TOPIC_LEG_LENGTHS] == {
        'type': 'sensor_msgs/msg/JointState',
        'count': 1,
    }


def test_abort_and_errors(tmp_path):
    path = tmp_path / 'recording.mcap'
    recorder = McapRecorder(path)
    with pytest.raises(RecordingError, match='add_topic'):
        recorder.write('/unknown', b'\x00\x01\x00\x00', 1)
    recorder.add_topic('/a', 'std_msgs/msg/String')
    with pytest.raises(RecordingError, match='already recorded'):
        recorder.add_topic('/a', 'sensor_msgs/msg/JointState')
    recorder.abort()
    assert not path.exists() and not os.path.exists(str(path) + '.tmp')
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(b'not an mcap file at all')
    with pytest.raises(RecordingError, match='bad.mcap'):
        list(read_recording(bad))
    with pytest.raises(RecordingError, match='missing.mcap'):
        list(read_recording(tmp_path / 'missing.mcap'))


# --- samples from a recording --------------------------------------------------------------------


def _write_sensors(recorder, stamp, q, r, nan_encoder=False, log_delay=0):
    """One instant stamped ``stamp`` (legs; the device 0.5 ms later), logged ``log_delay`` ns
    plus a fraction of a ms after its stamp."""
    seconds = stamp / 1e9
    logged = stamp + log_delay
    recorder.write(
        names.TOPIC_LEG_LENGTHS, conversions.leg_lengths_to_msg(q, seconds), logged + MS // 5
    )
    device = stamp + MS // 2
    recorder.write(
        names.TOPIC_INCLINOMETER,
        conversions.inclinometer_to_msg(r[0], r[1], device / 1e9),
        logged + MS // 2 + MS // 5,
    )
    encoder = conversions.encoder_to_msg(r[2], device / 1e9)
    if nan_encoder:
        encoder.position = [math.nan]
    recorder.write(names.TOPIC_ENCODER, encoder, logged + MS // 2 + MS // 4)
    recorder.write(
        names.TOPIC_LVDT,
        conversions.lvdt_to_msg(r[3], device / 1e9),
        logged + MS // 2 + MS // 3,
    )


def write_session(path, postures, per_posture, rejected=(), nan_at=None, notes=None, options=None):
    """A recorded calibration: commands, statuses and sensor streams (see the test below).

    Returns ``[(k, pose, leg samples, reading samples), ...]`` of the values sent after settling.
    """
    sent = []
    with McapRecorder(path) as recorder:
        if options:
            recorder.add_metadata(RUN_METADATA_NAME, {k: str(v) for k, v in options.items()})
        t = T0
        for k, (pose, q, r) in enumerate(postures, start=1):
            command_id = write_command(
                recorder,
                t,
                pose,
                k in rejected,
                posture=k,
                note=None if notes is None else notes(t),
            )
            if k in rejected:
                t += 100 * MS
                continue
            # Before settling: wrong values (the platform is moving), never averaged.
            _write_sensors(recorder, t + 2 * MS, np.asarray(q) + 1.0, np.asarray(r) + 1.0)
            settled = t + 10 * MS
            recorder.write(
                names.TOPIC_PLATFORM_STATUS,
                conversions.make_status(command_id, names.STATE_SETTLED),
                settled,
            )
            legs, readings = [], []
            for j in range(per_posture + 3):
                stamp = settled + MS + 5 * MS * j
                qj = np.asarray(q) + j * 1e-7
                rj = np.asarray(r) + j * 1e-8
                nan = nan_at == (k, j)
                _write_sensors(recorder, stamp, qj, rj, nan_encoder=nan)
                if not nan:
                    legs.append(qj)
                    readings.append(rj)
            sent.append((k, pose, legs, readings))
            t += 100 * MS
    return sent


def _postures(count, rng):
    return [
        (
            np.array([0.01 * i, -0.01 * i, 1.0, 0.01, -0.02, 0.03 * i]),
            0.4 + rng.random(6) * 0.1,
            np.array([0.01, -0.02, 0.03 * i, 0.002]),
        )
        for i in range(count)
    ]


def test_samples_from_recording_pairs_and_averages_like_the_calibrator(tmp_path):
    rng = np.random.default_rng(3)
    postures = _postures(4, rng)
    per_posture = 3
    path = tmp_path / 'recording.mcap'
    sent = write_session(
        path,
        postures,
        per_posture,
        rejected={2},
        nan_at=(1, 1),
        options={'sync_tolerance': 0.0025, 'pairs_per_posture': per_posture},
    )
    samples = rebuild.samples_from_recording(path)  # options as stored
    assert list(samples.posture) == [1, 3, 4]  # posture 2 rejected, numbers kept
    for row, (k, pose, legs, readings) in enumerate(sent):
        assert samples.posture[row] == k
        np.testing.assert_allclose(samples.commanded_poses[row], pose, atol=1e-12)
        # The first per_posture complete pairs after settling (posture 1: instant j=1 has a NaN
        # encoder reading, so its leg sample stays unpaired and j=0,2,3 are averaged).
        np.testing.assert_allclose(
            samples.leg_lengths[row], np.mean(legs[:per_posture], axis=0), rtol=0, atol=1e-15
        )
        np.testing.assert_allclose(
            samples.readings[row], np.mean(readings[:per_posture], axis=0), rtol=0, atol=1e-15
        )
        assert samples.n_samples[row] == per_posture
    # Same result as driving the collector by hand with the same pairs.
    collector = SampleCollector(0.0025, per_posture)
    collector.start(0)
    for j, (q, r) in enumerate(zip(sent[0][2], sent[0][3], strict=True)):
        collector.add_leg_lengths(j * 5 * MS, q)
        collector.add_inclinometer(j * 5 * MS + MS // 2, r[0], r[1])
        collector.add_encoder(j * 5 * MS + MS // 2, r[2])
        collector.add_lvdt(j * 5 * MS + MS // 2, r[3])
    expected = collector.take_posture()
    # Bit-equal: the recording averages with the same collector code (same operations).
    np.testing.assert_array_equal(samples.leg_lengths[0], expected.leg_lengths)
    np.testing.assert_array_equal(samples.readings[0], expected.readings)

    # CSV round trip: the samples read back from samples.csv are the same, bit for bit.
    write_samples(tmp_path / 'samples.csv', samples)
    again = read_samples(tmp_path / 'samples.csv')
    for field in ('posture', 'commanded_poses', 'leg_lengths', 'readings', 'n_samples', 'stamps'):
        np.testing.assert_array_equal(getattr(again, field), getattr(samples, field))


def test_noted_collection_start_is_used(tmp_path):
    postures = _postures(2, np.random.default_rng(4))
    plain = tmp_path / 'plain.mcap'
    noted = tmp_path / 'noted.mcap'
    write_session(plain, postures, 2)
    # The calibrator noted a start before the moving samples (stamped t + 2 ms): they count.
    write_session(noted, postures, 2, notes=lambda t: t + MS)
    with pytest.raises(RecordingError, match='sync_tolerance'):
        rebuild.samples_from_recording(plain)
    a = rebuild.samples_from_recording(plain, 0.0025, 2)
    b = rebuild.samples_from_recording(noted, 0.0025, 2)
    assert len(a) == len(b) == 2
    # First posture: its window starts with a moving sample (+1 m) stamped after the noted start.
    assert b.leg_lengths[0, 0] > a.leg_lengths[0, 0] + 0.4


def test_a_settle_and_samples_logged_after_the_next_command_stay_with_their_posture(tmp_path):
    """The recorder's subscriptions are served in no causal order: on a loaded machine it may log
    a posture's ``settled`` status and its last samples after the next command and that
    command's ``moving`` status (seen in a live run: replay and gsp_reidentify then lost the
    posture). They belong to the posture the calibrator collected them for."""
    (pose1, q1, r1), (pose2, q2, r2) = _postures(2, np.random.default_rng(5))
    path = tmp_path / 'late.mcap'
    legs = {1: [q1 + j * 1e-7 for j in range(3)], 2: [q2 + j * 1e-7 for j in range(3)]}
    readings = {1: [r1 + j * 1e-8 for j in range(3)], 2: [r2 + j * 1e-8 for j in range(3)]}
    with McapRecorder(path) as recorder:
        first = write_command(recorder, T0, pose1, note=T0 + 10 * MS, posture=1)
        # Posture 1 settled at 10 ms and its 3 samples, stamped from 11 ms, made the calibrator
        # command posture 2 at 30 ms (moving at 31 ms); the recorder logs them from 32 ms.
        second = write_command(recorder, T0 + 30 * MS, pose2, note=T0 + 60 * MS, posture=2)
        recorder.write(
            names.TOPIC_PLATFORM_STATUS,
            conversions.make_status(first, names.STATE_SETTLED),
            T0 + 32 * MS,
        )
        for j in range(3):
            _write_sensors(
                recorder, T0 + (11 + 5 * j) * MS, legs[1][j], readings[1][j], log_delay=25 * MS
            )
        recorder.write(
            names.TOPIC_PLATFORM_STATUS,
            conversions.make_status(second, names.STATE_SETTLED),
            T0 + 60 * MS,
        )
        for j in range(3):
            _write_sensors(recorder, T0 + (61 + 5 * j) * MS, legs[2][j], readings[2][j])
    samples = rebuild.samples_from_recording(path, 0.0025, 3)
    assert list(samples.posture) == [1, 2]
    for row, k in enumerate((1, 2)):
        np.testing.assert_allclose(
            samples.leg_lengths[row], np.mean(legs[k], axis=0), rtol=0, atol=1e-15
        )
        np.testing.assert_allclose(
            samples.readings[row], np.mean(readings[k], axis=0), rtol=0, atol=1e-15
        )


class _LaggingRecorder:
    """Collects a recorder's writes and logs them in log-time order; ``lag(topic, message,
    log_time)`` (ns) delays a message's log time (a recorder thread that fell behind)."""

    def __init__(self, recorder, lag):
        self.recorder, self.lag, self.writes = recorder, lag, []

    def write(self, topic, message, log_time):
        self.writes.append((log_time + self.lag(topic, message, log_time), topic, message))

    def add_metadata(self, name, data):
        self.recorder.add_metadata(name, data)

    def flush(self):
        for log_time, topic, message in sorted(self.writes, key=lambda w: w[0]):
            self.recorder.write(topic, message, log_time)


def _write_stalled_session(path, postures, per_posture, stall_ns=0, lag=None):
    """Postures commanded every 30 ms, settled 10 ms after their command, ``per_posture``
    samples stamped 5 ms apart from 11 ms (the calibrator commands the next posture at 30 ms).
    From 35 ms on the recorder logs the sensor messages and the ``settled`` statuses
    ``stall_ns`` late (commands and ``moving`` statuses on time); ``lag(topic, message,
    log_time)`` (ns), if given, is the delay instead. Returns ``{k: (legs, readings)}`` of the
    samples after settling."""
    sent = {}
    with McapRecorder(path) as recorder:

        def stalled(topic, message, log_time):
            late = topic in SENSOR_TOPICS or (
                topic == names.TOPIC_PLATFORM_STATUS and conversions.parse_status(message).settled
            )
            return stall_ns if late and log_time >= T0 + 35 * MS else 0

        lagging = _LaggingRecorder(recorder, stalled if lag is None else lag)
        for k, (pose, q, r) in enumerate(postures, start=1):
            t = T0 + 30 * MS * (k - 1)
            command_id = write_command(lagging, t, pose, note=t + 10 * MS, posture=k)
            # Moving: other values, stamped before the settle, never averaged.
            _write_sensors(lagging, t + 2 * MS, np.asarray(q) + 1.0, np.asarray(r) + 1.0)
            lagging.write(
                names.TOPIC_PLATFORM_STATUS,
                conversions.make_status(command_id, names.STATE_SETTLED),
                t + 10 * MS,
            )
            legs = [np.asarray(q) + j * 1e-7 for j in range(per_posture)]
            readings = [np.asarray(r) + j * 1e-8 for j in range(per_posture)]
            for j in range(per_posture):
                _write_sensors(lagging, t + (11 + 5 * j) * MS, legs[j], readings[j])
            sent[k] = (legs, readings)
        lagging.flush()
    return sent


def test_a_settle_and_samples_logged_after_two_later_commands_stay_with_their_posture(tmp_path):
    """A recorder thread that stalled 60 ms logs posture 2's ``settled`` status and samples
    (stamped before posture 3's command) after the commands and ``moving`` statuses of postures
    3 and 4 (seen in a loaded replay test: the rebuild closed posture 2 at posture 4's command,
    before its samples, and skipped it). The rebuild and the replay keep them with posture 2."""
    postures = _postures(4, np.random.default_rng(6))
    ordinary, stalled = tmp_path / 'ordinary.mcap', tmp_path / 'stalled.mcap'
    sent = _write_stalled_session(ordinary, postures, 3)
    assert _write_stalled_session(stalled, postures, 3, stall_ns=60 * MS).keys() == sent.keys()
    # The stalled log order: posture 2's settled status after posture 4's command and moving.
    logged = []  # (command id, state or 'command'), in log order
    for m in read_recording(
        stalled, topics=(names.TOPIC_POSE_COMMAND, names.TOPIC_PLATFORM_STATUS)
    ):
        if m.topic == names.TOPIC_POSE_COMMAND:
            logged.append((conversions.command_id_from_stamp(m.message.header.stamp), 'command'))
        else:
            status = conversions.parse_status(m.message)
            logged.append((status.command_id, status.state))
    ids = [command_id for command_id, state in logged if state == 'command']
    assert logged.index((ids[1], names.STATE_SETTLED)) > logged.index((ids[3], names.STATE_MOVING))

    online = rebuild.samples_from_recording(ordinary, 0.0025, 3)
    rebuilt = rebuild.samples_from_recording(stalled, 0.0025, 3)
    assert list(online.posture) == list(rebuilt.posture) == [1, 2, 3, 4]
    for row, k in enumerate(online.posture):
        legs, readings = sent[k]
        for samples in (online, rebuilt):
            np.testing.assert_allclose(
                samples.leg_lengths[row], np.mean(legs, axis=0), rtol=0, atol=1e-12
            )
            np.testing.assert_allclose(
                samples.readings[row], np.mean(readings, axis=0), rtol=0, atol=1e-12
            )
    np.testing.assert_array_equal(rebuilt.stamps, online.stamps)

    # The replay's segments: posture 2 holds exactly its three samples.
    run = RecordedRun.from_recording(stalled, 0.0025)
    assert [p.posture for p in run.postures] == [1, 2, 3, 4]
    legs, readings = sent[2]
    np.testing.assert_allclose(run.postures[1].stream.leg_lengths, legs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.postures[1].stream.readings, readings, rtol=0, atol=1e-12)


def test_a_first_command_logged_after_its_settle_and_samples_keeps_its_row(tmp_path):
    """The recorder's command subscription 25 ms behind at the first posture logs its command
    after its ``settled`` status and its samples (a loaded multi-node test's rebuild then had
    no row for posture 1: the status named no command yet). The rebuild reads the command
    where its stamp puts it: the same rows as the recording logged in order, and the replay's
    segments hold the same samples."""
    postures = _postures(3, np.random.default_rng(7))
    ordinary, late = tmp_path / 'ordinary.mcap', tmp_path / 'late.mcap'
    sent = _write_stalled_session(ordinary, postures, 3)

    def first_command_late(topic, message, log_time):
        return 25 * MS if topic == names.TOPIC_POSE_COMMAND and log_time < T0 + 30 * MS else 0

    assert _write_stalled_session(late, postures, 3, lag=first_command_late).keys() == sent.keys()
    logged = [
        m.topic
        if m.topic != names.TOPIC_PLATFORM_STATUS
        else conversions.parse_status(m.message).state
        for m in read_recording(
            late, topics=(names.TOPIC_POSE_COMMAND, names.TOPIC_PLATFORM_STATUS)
        )
    ]
    assert logged.index(names.STATE_SETTLED) < logged.index(names.TOPIC_POSE_COMMAND), logged

    online = rebuild.samples_from_recording(ordinary, 0.0025, 3)
    rebuilt = rebuild.samples_from_recording(late, 0.0025, 3)
    assert list(online.posture) == list(rebuilt.posture) == [1, 2, 3]
    np.testing.assert_allclose(rebuilt.leg_lengths, online.leg_lengths, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rebuilt.readings, online.readings, rtol=0, atol=1e-12)
    legs, readings = sent[1]
    np.testing.assert_allclose(rebuilt.readings[0], np.mean(readings, axis=0), rtol=0, atol=1e-12)
    run = RecordedRun.from_recording(late, 0.0025)
    assert [p.posture for p in run.postures] == [1, 2, 3]
    np.testing.assert_allclose(run.postures[0].stream.leg_lengths, legs, rtol=0, atol=1e-12)


# --- RunRecorder ---------------------------------------------------------------------------------


def test_run_recorder_records_suite_topics(ros_context, tmp_path):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import String

    source = Node('recording_source', context=ros_context)
    sink = Node('recording_sink', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(source)
    executor.add_node(sink)
    legs_pub = source.create_publisher(
        type(conversions.leg_lengths_to_msg(np.zeros(6))),
        names.TOPIC_LEG_LENGTHS,
        TOPIC_QOS[names.TOPIC_LEG_LENGTHS],
    )
    result_pub = source.create_publisher(
        String, names.TOPIC_CALIBRATION_RESULT, TOPIC_QOS[names.TOPIC_CALIBRATION_RESULT]
    )
    result_pub.publish(String(data='latched geometry'))  # before recording: latched
    recorder = RunRecorder(sink)
    path = tmp_path / 'recording.mcap'
    try:
        recorder.start(path, options={'sync_tolerance': 0.0025, 'pairs_per_posture': 10})
        assert recorder.recording
        deadline = time.monotonic() + 10.0
        sent = 0
        while time.monotonic() < deadline:
            legs_pub.publish(conversions.leg_lengths_to_msg(np.full(6, 0.1 * sent), time.time()))
            sent += 1
            executor.spin_once(timeout_sec=0.02)
            counts = recorder.counts
            if (
                counts.get(names.TOPIC_LEG_LENGTHS, 0) >= 3
                and counts.get(names.TOPIC_CALIBRATION_RESULT, 0) >= 1
            ):
                break
        recorder.note_collection_start('123', T0, posture=1)
        assert recorder.stop() == str(path)
        assert recorder.stop() is None
    finally:
        recorder.stop()
        executor.shutdown()
        source.destroy_node()
        sink.destroy_node()
    info = recording_info(path)
    assert set(info['topics']) == set(SUITE_TOPICS)
    assert info['topics'][names.TOPIC_LEG_LENGTHS]['count'] >= 3
    assert info['topics'][names.TOPIC_CALIBRATION_RESULT]['count'] == 1
    assert recording_options(path) == {
        'sync_tolerance': 0.0025,
        'pairs_per_posture': 10,
    }
    assert info['metadata'][POSTURE_METADATA_NAME] == [
        {'posture': '1', 'command_id': '123', 'start_ns': str(T0)}
    ]
    messages = list(read_recording(path))
    result = [m.message.data for m in messages if m.topic == names.TOPIC_CALIBRATION_RESULT]
    assert result == ['latched geometry']
    legs = [m for m in messages if m.topic == names.TOPIC_LEG_LENGTHS]
    assert all(m.log_time_ns > T0 for m in legs)
    assert list(legs[0].message.name) == list(names.LEG_JOINT_NAMES)


class _OnlineCalibrator:
    """The calibrator's collection as it runs online (a protocol with timeouts behind a
    :class:`PostureLink`, rows kept in a :class:`Rows`), fed each message as it is recorded;
    the link notes each posture's outcome in the same recording, as the node does."""

    def __init__(self, mcap, per_posture, settle_timeout):
        from gsp_calibrator.collection.protocol import CollectionProtocol
        from gsp_calibrator.files.run_directory import Rows
        from gsp_calibrator.node.posture_link import PostureLink

        self.mcap, self.rows, self.commanded = mcap, Rows.empty(), None
        self.ends = []

        class Notes:
            def note_posture_end(_, command_id, posture, outcome, reason=''):
                note_posture_end(mcap, command_id, posture, outcome, reason)

        mcap.add_metadata(OUTCOMES_METADATA_NAME, {'noted': 'true'})
        self.link = PostureLink(
            lambda: _Done(self.ends),
            lambda pose: (*self.commanded, lambda: None),
            Notes(),
            lambda event: None,
        )
        protocol = CollectionProtocol(
            0.0025, per_posture, topic_timeout=1.0, settle_timeout=settle_timeout
        )
        self.link.start(self, protocol)
        self.count = 0

    def end_posture(self, event):  # the RunRecord's part: keep the row
        if hasattr(event, 'sample'):
            s = event.sample
            self.rows.append(
                event.posture,
                event.pose,
                s.leg_lengths,
                s.readings,
                s.n_samples,
                s.stamp,
                s.lag_sums,
            )
        return event

    def write(self, topic, message, log_time):
        self.mcap.write(topic, message, log_time)
        if topic == names.TOPIC_POSE_COMMAND:
            self.count += 1
            self.commanded = (conversions.command_id_from_stamp(message.header.stamp), log_time)
            self.link.command(self.count, conversions.pose_stamped_to_pose(message))
        elif topic == names.TOPIC_PLATFORM_STATUS:
            status = conversions.parse_status(message)
            self.link.feed(lambda collection: collection.status(status, log_time))
        else:
            self.link.feed(lambda collection: collection.sensor(topic, message, log_time))

    def add_metadata(self, name, data):
        self.mcap.add_metadata(name, data)


class _Done:
    """A future completed by the link: its event is appended to ``ends``."""

    def __init__(self, ends):
        self.ends = ends

    def set_result(self, event):
        self.ends.append(event)


def test_the_rebuild_of_a_run_with_skipped_postures_gives_the_rows_of_samples_csv(tmp_path):
    """Online, posture 2 settles after its settle_timeout and is skipped; the recording still
    holds its settled status and enough samples at rest for a row, which the rebuild (no
    timeouts) would take. The recording says posture 2 was skipped: the rebuild gives exactly
    the online rows (issue 26: rebuilt rows samples.csv lacked)."""
    per_posture = 3
    postures = _postures(3, np.random.default_rng(7))
    path = tmp_path / 'recording.mcap'
    with McapRecorder(path) as mcap:
        mcap.add_metadata(RUN_METADATA_NAME, {'sync_tolerance': '0.0025', 'pairs_per_posture': '3'})
        online = _OnlineCalibrator(mcap, per_posture, settle_timeout=0.05)
        for k, (pose, q, r) in enumerate(postures, start=1):
            t = T0 + 200 * MS * (k - 1)
            command_id = write_command(online, t, pose)
            settle_ms = 80 if k == 2 else 10  # posture 2: 79 ms after its first status
            for j in range(2, settle_ms, 5):  # moving until then
                _write_sensors(online, t + j * MS, np.asarray(q) + 1.0, np.asarray(r) + 1.0)
            online.write(
                names.TOPIC_PLATFORM_STATUS,
                conversions.make_status(command_id, names.STATE_SETTLED),
                t + settle_ms * MS,
            )
            for j in range(per_posture + 3):
                stamp = t + (settle_ms + 1 + 5 * j) * MS
                _write_sensors(online, stamp, np.asarray(q) + j * 1e-7, np.asarray(r) + j * 1e-8)
    assert [type(e).__name__ for e in online.ends] == ['RowReady', 'PostureSkipped', 'RowReady']
    assert list(online.rows.posture) == [1, 3]

    rebuilt = rebuild.samples_from_recording(path)
    assert list(rebuilt.posture) == list(online.rows.posture)
    np.testing.assert_array_equal(rebuilt.stamps, online.rows.stamps)
    for field in ('commanded_poses', 'leg_lengths', 'readings'):
        np.testing.assert_allclose(
            getattr(rebuilt, field), getattr(online.rows, field), rtol=0, atol=1e-15
        )
    outcomes = rebuild.posture_outcomes(recording_info(path))
    assert outcomes[1] == ('kept', '') and outcomes[2][0] == 'skipped'
    assert 'settle' in outcomes[2][1]
