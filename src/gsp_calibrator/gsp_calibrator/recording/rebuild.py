"""Rebuilding a run from its recording, offline (pure, no rclpy node or context).

:func:`samples_from_recording` feeds every recorded command, status and sensor message to the
shared collection protocol (:func:`feed_recording`), in receive-time order, so the rows are the
ones the calibrator collected online; ``gsp_reidentify`` and replay use it.
"""

import os

from gsp_calibrator.collection import protocol
from gsp_calibrator.recording.mcap_format import RecordingError
from gsp_calibrator.recording.mcap_io import read_recording, recording_info, recording_options
from gsp_calibrator.recording.recorder import POSTURE_METADATA_NAME
from gsp_calibrator.run.directory import Samples
from gsp_kinematics.sensors.noise import SensorNoise, SensorNoiseError
from gsp_msgs_py import names


def noise_std_from_options(options):
    """The collector's 10 channel noise stds ``[q_1..q_6, alpha, beta, phi, d_m]`` (m, rad).

    From ``options['noise_std']`` (10 values), else the ``sigma_*`` options, else the calibrator's
    default sigmas (the calibrator builds its collector from its sigma parameters).
    """
    try:
        if options.get('noise_std') is not None:
            return SensorNoise.from_channel_std(options['noise_std']).channel_std()
        return SensorNoise.from_parameters(options).channel_std()
    except SensorNoiseError as error:
        raise RecordingError(str(error)) from None


def feed_recording(path, collection, notes=None, extra_topics=(), on_message=None):
    """Feed every recorded command, status and sensor message to ``collection`` (a
    :class:`~gsp_calibrator.collection.protocol.CollectionProtocol`), receive time = log time; yields its
    events. ``path``: one recording, or the parts of a resumed run in order
    (:func:`recording_parts`).

    Each ``pose_command`` starts the next posture: its number is the one noted with it
    (:meth:`RunRecorder.note_collection_start`), else its rank among the commands; the noted
    start is the collection start of its ``settled`` status (else the status's receive time).
    ``on_message(topic, log_time_ns, message)``, if given, sees every message read first
    (``extra_topics`` are read for it alone). Malformed messages are dropped, as the calibrator
    drops them.

    A command takes effect at the first later sensor message stamped at or after it (or its
    ``settled`` or ``rejected`` status, or the next command): the calibrator commands the next
    posture as soon as a row is complete, and the recorder, subscriptions of its own, may log
    the row's last samples after that command and its ``moving`` status; they still belong to
    the posture before it. So does the posture's own ``settled`` status when logged that late
    (a loaded machine: the calibrator had collected from the start it noted).
    """
    from gsp_msgs_py import conversions

    paths = [path] if isinstance(path, (str, os.PathLike)) else list(path)
    notes = _notes_of(paths) if notes is None else notes
    wanted = (
        (names.TOPIC_POSE_COMMAND, names.TOPIC_PLATFORM_STATUS)
        + protocol.SENSOR_TOPICS
        + tuple(extra_topics)
    )
    count = 0
    pending = None  # (number, pose, command_id, log time) of a command not yet in effect
    moving = []  # (status, log time) of the pending command: fed once it takes effect

    def status_now(status, log_time):
        return collection.status(status, log_time, notes.get(status.command_id, (None, None))[1])

    def command_now():
        nonlocal pending
        if pending is None:
            return []
        events, pending = collection.command(*pending), None
        for status, log_time in moving:
            events += status_now(status, log_time)
        moving.clear()
        return events

    messages = (m for part in paths for m in read_recording(part, topics=wanted))
    for topic, _, log_time, msg, _ in messages:
        if on_message is not None:
            on_message(topic, log_time, msg)
        if topic in protocol.TOPIC_STREAMS:
            if pending is not None and not _stamped_before(msg, int(pending[2])):
                yield from command_now()
            events = collection.sensor(topic, msg, log_time)
        elif topic == names.TOPIC_POSE_COMMAND:
            try:
                command_id, pose = _read_command(msg)
            except (ValueError, TypeError):
                continue
            yield from command_now()
            count += 1
            number = notes.get(command_id, (None, None))[0] or count
            pending = (number, pose, command_id, log_time)
            continue
        elif topic == names.TOPIC_PLATFORM_STATUS:
            try:
                status = conversions.parse_status(msg)
            except ValueError:
                continue
            if pending is not None and status.command_id == pending[2]:
                if not (status.settled or status.rejected):
                    moving.append((status, log_time))
                    continue
                yield from command_now()
            events = status_now(status, log_time)
        else:
            continue
        yield from events
    yield from command_now()
    yield from collection.finish()


def _notes_of(paths):
    """Command id -> (posture number, collection start) noted in the recordings ``paths``."""
    notes = {}
    for part in paths:
        notes.update(collection_notes(recording_info(part), part))
    return notes


def _read_command(msg):
    """``(command id, pose)`` of a recorded pose command; ValueError/TypeError if malformed."""
    from gsp_msgs_py import conversions

    return conversions.command_id_from_stamp(msg.header.stamp), conversions.pose_stamped_to_pose(
        msg
    )


def _stamped_before(msg, stamp_ns):
    """Whether ``msg``'s header stamp is before ``stamp_ns`` (False if it has none)."""
    from gsp_msgs_py import conversions

    try:
        return conversions.stamp_to_nanoseconds(msg.header.stamp) < stamp_ns
    except (AttributeError, ValueError, TypeError):
        return False


def samples_from_recording(path, sync_tolerance=None, samples_per_posture=None, noise_std=None):
    """Rebuild the ``samples.csv`` rows (:class:`~gsp_calibrator.run.directory.Samples`) of one
    recording or of the parts of a resumed run (a list, see :func:`recording_parts`).

    Feeds every recorded message to the calibrator's own
    :class:`~gsp_calibrator.collection.protocol.CollectionProtocol` (see :func:`feed_recording`), so the
    rows are the ones the calibrator collected online (with no timeouts: the recording holds
    only what the calibrator waited for).

    ``sync_tolerance`` (s), ``samples_per_posture`` and ``noise_std`` (10 channel stds, see
    :func:`noise_std_from_options`) default to the options stored by :meth:`RunRecorder.start`;
    :class:`RecordingError` if the first two are not known.
    """
    first = path if isinstance(path, (str, os.PathLike)) else list(path)[0]
    stored = recording_options(first)
    if sync_tolerance is None:
        sync_tolerance = stored.get('sync_tolerance')
    if samples_per_posture is None:
        samples_per_posture = stored.get('samples_per_posture')
    if sync_tolerance is None or samples_per_posture is None:
        raise RecordingError(
            f'{path}: sync_tolerance and samples_per_posture are not stored in the recording; '
            'give them explicitly'
        )
    if noise_std is None:
        noise_std = noise_std_from_options(stored)
    # Each part is one session of the run, fed to a protocol of its own that continues after
    # the last row so far, as the resumed calibrator did; a posture collected again by a later
    # session (its earlier collection was cut short) keeps its later row.
    rows = {}
    for part in [path] if isinstance(path, (str, os.PathLike)) else list(path):
        collection = protocol.CollectionProtocol(sync_tolerance, samples_per_posture, noise_std)
        if rows:
            collection.continue_after(next(reversed(rows.values())).sample.readings)
        for event in feed_recording(part, collection):
            if isinstance(event, protocol.RowReady):
                rows.pop(event.posture, None)
                rows[event.posture] = event
    samples = Samples.empty()
    for event in rows.values():
        sample = event.sample
        samples.append(
            event.posture,
            event.pose,
            sample.leg_lengths,
            sample.readings,
            sample.n_samples,
            sample.stamp,
        )
    return samples


def collection_notes(info, path='<recording>'):
    """``{command_id: (posture or None, start_ns)}`` noted by :meth:`RunRecorder.note_collection_start`."""
    notes = {}
    for entry in info['metadata'].get(POSTURE_METADATA_NAME, []):
        try:
            posture = entry.get('posture')
            notes[str(entry['command_id'])] = (
                int(posture) if posture not in (None, '', 'None') else None,
                int(entry['start_ns']),
            )
        except (KeyError, ValueError) as error:
            raise RecordingError(
                f'{path}: malformed {POSTURE_METADATA_NAME} metadata {entry}'
            ) from error
    return notes
