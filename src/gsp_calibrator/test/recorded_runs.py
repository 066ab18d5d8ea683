"""Test helper shared by test_recording.py and test_replay.py: a recorded pose command."""

from gsp_calibrator.recording.recorder import POSTURE_METADATA_NAME
from gsp_msgs_py import conversions, names

MS = 1_000_000


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
