"""Test helpers shared by test_recording.py, test_replay.py and test_replay_revisits.py: a
recorded pose command, a recorded session."""

import numpy as np

from gsp_calibrator.recording.mcap_io import RUN_METADATA_NAME, McapRecorder
from gsp_calibrator.recording.recorder import POSTURE_METADATA_NAME
from gsp_msgs_py import conversions, names

MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000


def write_command(recorder, t, pose, rejected=False, note=None, posture=None):
    """Record the command of ``pose`` at ``t`` (ns) and its ``moving`` status 1 ms later; if
    ``rejected``, its ``rejected`` status ('out of reach') at 2 ms. ``note``: a collection start
    (ns) noted for the command, as the calibrator does. Returns the command id."""
    command = conversions.pose_to_pose_stamped(pose, t / 1e9)
    command_id = conversions.command_id_from_stamp(command.header.stamp)
    recorder.write(names.TOPIC_POSE_COMMAND, command, t)
    recorder.write(
        names.TOPIC_PLATFORM_STATUS, conversions.make_status(command_id, names.STATE_MOVING), t + MS
    )
    if rejected:
        recorder.write(
            names.TOPIC_PLATFORM_STATUS,
            conversions.make_status(command_id, names.STATE_REJECTED, 'out of reach'),
            t + 2 * MS,
        )
    if note is not None:
        recorder.add_metadata(
            POSTURE_METADATA_NAME,
            {'command_id': command_id, 'start_ns': str(note), 'posture': str(posture)},
        )
    return command_id


def _write_instant(recorder, stamp, q, r, true_pose=None):
    """One platform instant (legs + true pose) and one device instant 0.5 ms later."""
    recorder.write(
        names.TOPIC_LEG_LENGTHS, conversions.leg_lengths_to_msg(q, stamp / 1e9), stamp + MS // 5
    )
    if true_pose is not None:
        recorder.write(
            names.TOPIC_TRUE_POSE,
            conversions.pose_to_pose_stamped(true_pose, stamp / 1e9),
            stamp + MS // 5,
        )
    device = stamp + MS // 2
    recorder.write(
        names.TOPIC_INCLINOMETER,
        conversions.inclinometer_to_msg(r[0], r[1], device / 1e9),
        device + MS // 5,
    )
    recorder.write(
        names.TOPIC_ENCODER, conversions.encoder_to_msg(r[2], device / 1e9), device + MS // 5
    )
    recorder.write(names.TOPIC_LVDT, conversions.lvdt_to_msg(r[3], device / 1e9), device + MS // 5)


def write_recording(
    path,
    poses,
    per_posture=4,
    rejected=(),
    true_pose=True,
    notes=False,
    start_ns=T0,
    numbers=None,
    note_after_ns=2 * MS,
    resent=(),
):
    """A recorded session from ``start_ns``: idle samples, then per pose a command, statuses and
    sensor samples (wrong values while moving). ``numbers``: the posture numbers of ``poses``
    (default 1, 2, ...); ``notes``: note each collection start ``note_after_ns`` after its
    command (the settle is at 10 ms); ``resent``: posture numbers whose command is recorded
    again (same stamp) 0.5 ms after it, before its status, as the calibrator sends an unanswered one. Returns ``{k: (legs, readings, true poses)}`` after
    settling."""
    sent = {}
    numbers = numbers or range(1, len(poses) + 1)
    with McapRecorder(path) as recorder:
        recorder.add_metadata(RUN_METADATA_NAME, {'sync_tolerance': '0.0025'})
        for j in range(3):  # idle at home before the first command
            _write_instant(
                recorder,
                start_ns + 5 * MS * j,
                np.full(6, 0.7 + j * 1e-6),
                np.full(4, 0.07),
                np.array([0, 0, 1.0, 0, 0, 0]) if true_pose else None,
            )
        t = start_ns + 100 * MS
        for k, pose in zip(numbers, poses, strict=True):
            note = t + note_after_ns if notes else None
            command_id = write_command(recorder, t, pose, k in rejected, posture=k, note=note)
            if k in resent:
                command = conversions.pose_to_pose_stamped(pose, t / 1e9)
                recorder.write(names.TOPIC_POSE_COMMAND, command, t + MS // 2)
            if k in rejected:
                t += 100 * MS
                continue
            _write_instant(
                recorder, t + 2 * MS, np.full(6, 9.0), np.full(4, 9.0), pose if true_pose else None
            )  # moving: never replayed
            settled = t + 10 * MS
            recorder.write(
                names.TOPIC_PLATFORM_STATUS,
                conversions.make_status(command_id, names.STATE_SETTLED),
                settled,
            )
            legs, readings, truths = [], [], []
            for j in range(per_posture):
                q = 0.5 + 0.01 * np.arange(6) + k * 1e-3 + j * 1e-7
                r = np.array([0.01 * k, -0.02, 0.1 * k, 1e-3]) + j * 1e-8
                truth = pose + j * 1e-9
                _write_instant(
                    recorder, settled + MS + 5 * MS * j, q, r, truth if true_pose else None
                )
                legs.append(q)
                readings.append(r)
                truths.append(truth)
            sent[k] = (np.array(legs), np.array(readings), np.array(truths))
            t += 100 * MS
    return sent
