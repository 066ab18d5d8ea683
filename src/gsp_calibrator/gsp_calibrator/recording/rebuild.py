"""Rebuilding a run from its recording, offline (pure, no rclpy node or context).
See docs/data.md#offline-re-identification-gsp_reidentify."""

import collections
import os
from pathlib import Path

from gsp_calibrator.collection import events, protocol, topics
from gsp_calibrator.collection.approach import ApproachTracker
from gsp_calibrator.files.run_directory import Rows
from gsp_calibrator.recording.mcap_format import RecordingError
from gsp_calibrator.recording.mcap_io import read_recording, recording_info, recording_options
from gsp_calibrator.recording.recorder import (
    KEPT,
    OUTCOMES_METADATA_NAME,
    POSTURE_END_METADATA_NAME,
    POSTURE_METADATA_NAME,
)
from gsp_kinematics.estimation.noise_estimate import DEFAULT_REST_SIGMAS
from gsp_kinematics.model.geometry import GeometryError, default_geometry, load_geometry
from gsp_kinematics.model.sensor_noise import SensorNoiseError
from gsp_msgs_py import conversions, names
from gsp_msgs_py.noise_parameters import noise_from_parameters


def feed_recording(path, collection, extra_topics=(), on_message=None):
    """Feed every command, status and sensor message of the recording ``path`` to ``collection``
    (a :class:`~gsp_calibrator.collection.protocol.CollectionProtocol`), receive time = log time;
    yields its events."""
    wanted = (
        (names.TOPIC_POSE_COMMAND, names.TOPIC_PLATFORM_STATUS)
        + topics.SENSOR_TOPICS
        + tuple(extra_topics)
    )
    order = _CausalOrder(collection, collection_notes(recording_info(path), path))
    for topic, _, log_time, msg, _ in _commands_in_time(path, wanted):
        if on_message is not None:
            on_message(topic, log_time, msg)
        yield from order.message(topic, log_time, msg)
    yield from order.advance(final=True)
    yield from collection.finish()


def _commands_in_time(path, topics):
    """The messages of ``topics`` in ``path`` in log order, except that a pose command logged
    after a message logged later than the command's own stamp comes before that message, with
    its stamp as its log time."""
    commands = [  # (stamp ns or None, message), in log order
        (_stamp_ns(message.message), message)
        for message in read_recording(path, topics=(names.TOPIC_POSE_COMMAND,))
    ]
    ahead = 0  # commands given so far (some before their place in the log)
    seen = 0  # commands met at their place in the log
    for message in read_recording(path, topics=topics):
        if message.topic == names.TOPIC_POSE_COMMAND:
            seen += 1
            if seen > ahead:  # not given ahead of its place
                ahead = seen
                yield message
            continue
        log_time = message.log_time_ns
        while ahead < len(commands):
            stamp, command = commands[ahead]
            if stamp is None or not stamp < log_time < command.log_time_ns:
                break
            ahead += 1
            yield command._replace(log_time_ns=stamp)
        yield message


class _CausalOrder:
    """Feeds recorded messages to a collection protocol in causal order (see
    :func:`feed_recording`): holds the messages logged after a command until it takes effect."""

    def __init__(self, collection, notes):
        self.collection = collection
        self.notes = notes  # {command_id: (posture or None, start_ns)}
        self.count = 0  # commands so far
        self.active = None  # command id of the posture in effect
        self.final_status = True  # whether the posture in effect has its settled/rejected
        self.pending = collections.deque()  # (number, pose, command_id, log time), not in effect
        self.held = []  # (topic, log time, message or status) logged after pending[0]
        self.reached = set()  # sensor topics heard at or after pending[0]'s stamp

    def message(self, topic, log_time, msg):
        """Events of one recorded message (in log order)."""
        if topic == names.TOPIC_POSE_COMMAND:
            try:
                command_id = conversions.command_id_from_stamp(msg.header.stamp)
                pose = conversions.pose_stamped_to_pose(msg)
            except (ValueError, TypeError):
                return []
            self.count += 1
            number = self.notes.get(command_id, (None, None))[0] or self.count
            self.pending.append((number, pose, command_id, log_time))
            return self.advance()
        if topic == names.TOPIC_PLATFORM_STATUS:
            try:
                msg = conversions.parse_status(msg)
            except ValueError:
                return []
        elif topic not in topics.TOPIC_STREAMS:
            return []
        return self._route(topic, log_time, msg) + self.advance()

    def advance(self, final=False):
        """Put the waiting commands into effect while they may (``final``: all of them)."""
        events = []
        while self.pending and (
            final or (self.final_status and self.reached.issuperset(topics.SENSOR_TOPICS))
        ):
            number, pose, command_id, log_time = self.pending.popleft()
            events += self.collection.command(number, pose, command_id, log_time)
            self.active, self.final_status = command_id, False
            self.reached.clear()
            backlog, self.held = self.held, []
            for item in backlog:
                events += self._route(*item)
        return events

    def _route(self, topic, log_time, item):
        """Feed a sensor message or parsed status to the posture in effect, or hold it."""
        if topic in topics.TOPIC_STREAMS:
            stamp_ns = _stamp_ns(item)
            if stamp_ns is not None:
                if self.pending and (topic in self.reached or stamp_ns >= int(self.pending[0][2])):
                    self.reached.add(topic)
                    self.held.append((topic, log_time, item))
                    return []
            return self.collection.sensor(topic, item, log_time)
        if any(item.command_id == command[2] for command in self.pending):
            self.held.append((topic, log_time, item))
            return []
        if item.command_id == self.active and (item.settled or item.rejected):
            self.final_status = True
        start_ns = self.notes.get(item.command_id, (None, None))[1]
        return self.collection.status(item, log_time, start_ns)


def _stamp_ns(msg):
    """``msg``'s header stamp (int ns), or None if it has none."""
    try:
        return conversions.stamp_to_nanoseconds(msg.header.stamp)
    except (AttributeError, ValueError, TypeError):
        return None


def samples_from_recording(
    path, sync_tolerance=None, pairs_per_posture=None, noise_std=None, nominal=None
):
    """Rebuild the ``samples.csv`` rows (:class:`~gsp_calibrator.files.run_directory.Rows`) of one
    recording or of the parts of a resumed run (a list, see :func:`.recorder.recording_parts`).

    ``sync_tolerance`` (s), ``pairs_per_posture``, ``noise_std`` (the 10 channel stds, m and
    rad) and ``nominal`` default to the recording's stored options; :class:`RecordingError` if
    the first two are not known."""
    samples = Rows.empty()
    for event, directions in _rows(path, sync_tolerance, pairs_per_posture, noise_std, nominal):
        sample = event.sample
        samples.append(
            event.posture,
            event.pose,
            sample.leg_lengths,
            sample.readings,
            sample.n_samples,
            sample.stamp,
            sample.lag_sums,
            directions,
        )
    return samples


def _stored_nominal(stored):
    """The geometry the run commanded through: its stored nominal file, else the shipped one."""
    name = stored.get('nominal_geometry_file')
    if name and Path(name).is_file():
        try:
            return load_geometry(name)
        except (GeometryError, OSError):
            pass
    return default_geometry('nominal')


class _ApproachTap:
    """A collection protocol that tells an :class:`ApproachTracker` each command as it takes
    effect (with the legs heard before it) and each posture the platform rejected, as the
    calibrator's session does online."""

    def __init__(self, collection, tracker):
        self._collection, self.tracker = collection, tracker

    def __getattr__(self, name):
        return getattr(self._collection, name)

    def command(self, posture, pose, command_id, now_ns):
        self.tracker.command(posture, pose, self._collection.latest_leg_lengths())
        return self._seen(self._collection.command(posture, pose, command_id, now_ns))

    def sensor(self, *args, **kwargs):
        return self._seen(self._collection.sensor(*args, **kwargs))

    def status(self, *args, **kwargs):
        return self._seen(self._collection.status(*args, **kwargs))

    def finish(self):
        return self._seen(self._collection.finish())

    def _seen(self, found):
        found = list(found)
        for event in found:
            if isinstance(event, events.PostureSkipped) and event.rejected_by_platform:
                self.tracker.rejected(event.posture)
        return found


def _rows(path, sync_tolerance=None, pairs_per_posture=None, noise_std=None, nominal=None):
    """``[(RowReady, approach directions (6,))]`` of :func:`samples_from_recording`, in row
    order (each row's ``rest_wait`` with it)."""
    parts = [path] if isinstance(path, (str, os.PathLike)) else list(path)
    stored = recording_options(parts[0])
    if sync_tolerance is None:
        sync_tolerance = stored.get('sync_tolerance')
    if pairs_per_posture is None:
        pairs_per_posture = stored.get('pairs_per_posture')
    if sync_tolerance is None or pairs_per_posture is None:
        raise RecordingError(
            f'{path}: sync_tolerance and pairs_per_posture are not stored in the recording; '
            'give them explicitly'
        )
    if noise_std is None:  # the collector's 10 channel stds (m, rad)
        try:
            noise_std = noise_from_parameters(stored).channel_std()
        except SensorNoiseError as error:
            raise RecordingError(str(error)) from None
    nominal = _stored_nominal(stored) if nominal is None else nominal
    # Each part is one session of the run, fed to a protocol of its own that continues after
    # the last row so far, as the resumed calibrator did; a posture collected again by a later
    # session (its earlier collection was cut short) keeps its later row.
    rows = {}
    for part in parts:
        collection = protocol.CollectionProtocol(
            sync_tolerance,
            pairs_per_posture,
            noise_std,
            # A recording made before the rest rule: the window alone, the default sigmas.
            rest_lookback=float(stored.get('rest_lookback', 0.0)),
            rest_sigmas=float(stored.get('rest_sigmas', DEFAULT_REST_SIGMAS)),
        )
        last = None
        if rows:
            last_event, last = next(reversed(rows.values()))
            collection.continue_after(last_event.sample.readings)
        tracker = ApproachTracker(nominal, last)
        outcomes = posture_outcomes(recording_info(part), part)
        kept = None if outcomes is None else {p for p, (end, _) in outcomes.items() if end == KEPT}
        previous = {}  # posture -> the readings its row was compared to
        for event in feed_recording(part, _ApproachTap(collection, tracker)):
            if isinstance(event, events.CollectionStarted):
                previous[event.posture] = collection.collector.previous_readings
            elif isinstance(event, events.RowReady):
                if kept is not None and event.posture not in kept:
                    # Not kept online (skipped, or in progress at the stop): the next row is
                    # compared to the readings this one was, as online.
                    if previous.get(event.posture) is not None:
                        collection.continue_after(previous[event.posture])
                    continue
                rows.pop(event.posture, None)
                rows[event.posture] = (event, tracker.directions(event.posture))
    return list(rows.values())


def posture_outcomes(info, path='<recording>'):
    """``{posture: (outcome, reason)}`` noted by :meth:`.recorder.RunRecorder.note_posture_end` (the last
    note of a posture wins), or None for a recording made before these notes."""
    metadata = info['metadata']
    if OUTCOMES_METADATA_NAME not in metadata:
        return None
    outcomes = {}
    for entry in metadata.get(POSTURE_END_METADATA_NAME, []):
        try:
            outcomes[int(entry['posture'])] = (str(entry['outcome']), str(entry.get('reason', '')))
        except (KeyError, ValueError) as error:
            raise RecordingError(
                f'{path}: malformed {POSTURE_END_METADATA_NAME} metadata {entry}'
            ) from error
    return outcomes


def collection_notes(info, path='<recording>'):
    """``{command_id: (posture or None, start_ns)}`` noted by :meth:`.recorder.RunRecorder.note_collection_start`."""
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
