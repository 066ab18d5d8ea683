"""``recording.mcap``: every message on the suite's topics during a run, as rosbag2 writes it.

The file is an MCAP file with profile ``ros2``: one schema per message type (encoding ``ros2msg``,
the complete concatenated ``.msg`` definition exactly as rosbag2's local definition source builds
it), one channel per topic (message encoding ``cdr``, rosbag2's ``offered_qos_profiles`` channel
metadata), ``log_time`` = receive time and ``publish_time`` in nanoseconds. ``ros2 bag info
recording.mcap``, ``ros2 bag play recording.mcap`` (storage ``mcap``) and Foxglove read it.

* :class:`McapRecorder` writes one file atomically (``<path>.tmp``, then ``os.replace`` on close).
* :func:`read_recording` iterates over ``(topic, type_name, log_time_ns, message)``.
* :func:`samples_from_recording` rebuilds the ``samples.csv`` rows of a run by feeding the
  recorded pose commands, statuses and sensor messages to the calibrator's own
  :class:`gsp_calibrator.collection.protocol.CollectionProtocol` (:func:`feed_recording`).
* :class:`RunRecorder` records the suite's topics from inside a node (raw CDR subscriptions).

Nothing here needs a ROS context except :class:`RunRecorder`. The MCAP writer and reader are
:mod:`gsp_calibrator.recording.mcap_io`; message definitions and QoS metadata are in
:mod:`gsp_calibrator.recording.mcap_format` (both re-exported here).
"""

import json
import os
import re
import threading
import time

from gsp_calibrator.collection import protocol
from gsp_calibrator.recording.mcap_format import (  # noqa: F401 (the recording API, re-exported)
    DEFINITION_SEPARATOR,
    MessageDefinitionError,
    RecordingError,
    message_class,
    message_definition,
    message_type_name,
    msg_file,
    normalise_type_name,
    qos_profiles_yaml,
    split_type_name,
)
from gsp_calibrator.recording.mcap_io import (  # noqa: F401 (the recording API, re-exported)
    MESSAGE_ENCODING,
    PROFILE,
    RUN_METADATA_NAME,
    SCHEMA_ENCODING,
    McapRecorder,
    read_recording,
    recording_info,
    recording_options,
    recover_recording,
    recover_recordings,
)
from gsp_calibrator.run.directory import Samples
from gsp_kinematics.fileio import json_safe
from gsp_kinematics.noise import SensorNoise, SensorNoiseError
from gsp_msgs_py import names

RECORDING_FILE = 'recording.mcap'
#: A resumed run records into ``recording-2.mcap``, ``recording-3.mcap`` ... (a finished MCAP
#: file cannot be appended to); offline tools read the parts in this order.
RECORDING_PART_PATTERN = re.compile(r'^recording(?:-(\d+))?\.mcap$')


def recording_parts(directory):
    """The recordings of a run directory in order: ``recording.mcap``, ``recording-2.mcap`` ..."""
    parts = []
    for name in os.listdir(directory):
        match = RECORDING_PART_PATTERN.match(name)
        if match:
            parts.append((int(match.group(1) or 1), os.path.join(directory, name)))
    return [path for _, path in sorted(parts)]


def next_recording_file(directory):
    """The file the next (resumed) session of a run records into (no part, no ``.tmp`` of it)."""
    for number in range(1, 10_000):
        name = RECORDING_FILE if number == 1 else f'recording-{number}.mcap'
        path = os.path.join(directory, name)
        if not os.path.exists(path) and not os.path.exists(path + '.tmp'):
            return path
    raise RecordingError(f'{directory}: too many recording parts')


#: MCAP metadata record of one posture's collection start (see :meth:`RunRecorder.note_collection_start`).
POSTURE_METADATA_NAME = 'gsp_posture'

#: Topics :class:`RunRecorder` records by default: every topic of the suite.
SUITE_TOPICS = dict(names.TOPIC_TYPES)

# --- samples from a recording -------------------------------------------------------------------


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

    A command takes effect at the first later sensor message stamped at or after it (or the
    next status or command): the calibrator commands the next posture as soon as a row is
    complete, and the recorder, a subscription of its own, may log the row's last samples after
    that command; they still belong to the posture before it.
    """
    from gsp_msgs_py import conversions

    paths = [path] if isinstance(path, (str, os.PathLike)) else list(path)
    if notes is None:
        notes = {}
        for part in paths:
            notes.update(collection_notes(recording_info(part), part))
    wanted = (
        (names.TOPIC_POSE_COMMAND, names.TOPIC_PLATFORM_STATUS)
        + protocol.SENSOR_TOPICS
        + tuple(extra_topics)
    )
    count = 0
    pending = None  # (number, pose, command_id, log time) of a command not yet in effect

    def command_now():
        nonlocal pending
        if pending is None:
            return []
        events, pending = collection.command(*pending), None
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
                command_id = conversions.command_id_from_stamp(msg.header.stamp)
                pose = conversions.pose_stamped_to_pose(msg)
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
            yield from command_now()
            events = collection.status(
                status, log_time, notes.get(status.command_id, (None, None))[1]
            )
        else:
            continue
        yield from events
    yield from command_now()
    yield from collection.finish()


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


# --- recording from a node ---------------------------------------------------------------------


class RunRecorder:
    """Records the suite's topics from inside a node into ``recording.mcap``.

    Subscriptions (``raw=True``: CDR bytes, no deserialisation) are created by :meth:`start` with
    each topic's profile of :data:`gsp_msgs_py.qos.TOPIC_QOS` (sensor QoS for the streams, the
    publishers' QoS for the others) and destroyed by :meth:`stop`. Each message is written with
    its receive time on the node's clock, the time base of the calibrator's collector. Callbacks
    run in the recorder's own callback group, so they never wait for the node's other callbacks.

    ``persistent=True``: the subscriptions are created once, here, and kept for the node's
    lifetime (messages outside a recording are dropped at once). Destroying a subscription while
    another thread's executor builds its wait set can raise ``InvalidHandle`` (ros2/rclpy#1206).
    """

    def __init__(self, node, topics=None, callback_group=None, persistent=False):
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

        self.node = node
        self.topics = dict(SUITE_TOPICS if topics is None else topics)
        self.callback_group = callback_group or MutuallyExclusiveCallbackGroup()
        self.persistent = bool(persistent)
        self._recorder = None
        self._subscriptions = []
        self._lock = threading.Lock()
        if self.persistent:
            self._subscribe()

    def _subscribe(self):
        from gsp_msgs_py.qos import SENSOR_QOS, SENSOR_SUBSCRIPTION_QOS, TOPIC_QOS

        for topic, type_name in self.topics.items():
            profile = TOPIC_QOS.get(topic, SENSOR_QOS)
            if profile == SENSOR_QOS:  # the collector's deep queue: record what it may use
                profile = SENSOR_SUBSCRIPTION_QOS
            self._subscriptions.append(
                self.node.create_subscription(
                    message_class(type_name),
                    topic,
                    self._callback(topic),
                    profile,
                    callback_group=self.callback_group,
                    raw=True,
                )
            )

    @property
    def recording(self):
        return self._recorder is not None

    @property
    def path(self):
        return self._recorder.path if self._recorder is not None else None

    @property
    def counts(self):
        """Messages recorded per topic so far (empty when not recording)."""
        recorder = self._recorder
        return dict(recorder.counts) if recorder is not None else {}

    def start(self, path, options=None):
        """Start recording to ``path`` (e.g. ``run_dir / 'recording.mcap'``).

        ``options`` (e.g. ``{'sync_tolerance': 0.002, 'samples_per_posture': 5}``) are stored in
        the file so that offline re-identification uses the same ones by default.
        """
        from gsp_msgs_py.qos import SENSOR_QOS, TOPIC_QOS

        self.stop()
        recorder = McapRecorder(path, crash_safe=True)
        try:
            for topic, type_name in self.topics.items():
                recorder.add_topic(topic, type_name, TOPIC_QOS.get(topic, SENSOR_QOS))
            if options:
                recorder.add_metadata(
                    RUN_METADATA_NAME, {k: json.dumps(json_safe(v)) for k, v in options.items()}
                )
        except BaseException:
            recorder.abort()
            raise
        with self._lock:
            self._recorder = recorder
        if not self.persistent:
            self._subscribe()
        return recorder.path

    def note_collection_start(self, command_id, start_ns, posture=None):
        """Note that the samples of command ``command_id`` count from ``start_ns`` (node clock).

        Optional (an MCAP metadata record, ignored by rosbag2): with it,
        :func:`samples_from_recording` starts each posture exactly where the calibrator's
        collector did, instead of at the receive time of the ``settled`` status.
        """
        with self._lock:
            if self._recorder is not None:
                self._recorder.add_metadata(
                    POSTURE_METADATA_NAME,
                    {
                        'posture': '' if posture is None else int(posture),
                        'command_id': str(command_id),
                        'start_ns': int(start_ns),
                    },
                )

    def stop(self, drain_s=0.0):
        """Stop recording and close the file (atomic); returns its path, or None if idle.

        ``drain_s``: first wait this long (s) so that messages published just before (the last
        progress, the result) are received; the recorder's callbacks must be able to run
        meanwhile (a multi-threaded executor: they have their own callback group).
        """
        if drain_s > 0.0 and self._recorder is not None:
            time.sleep(drain_s)
        if not self.persistent:
            self.close_subscriptions()
        with self._lock:
            recorder, self._recorder = self._recorder, None
        if recorder is None:
            return None
        return recorder.close()

    def close_subscriptions(self):
        """Destroy the subscriptions (with ``persistent``: when the node is destroyed)."""
        subscriptions, self._subscriptions = self._subscriptions, []
        for subscription in subscriptions:
            self.node.destroy_subscription(subscription)

    def _callback(self, topic):
        clock = self.node.get_clock()

        def on_message(data):
            if self._recorder is None:  # not recording: drop at once
                return
            now = clock.now().nanoseconds
            with self._lock:
                recorder = self._recorder
                if recorder is None:
                    return
                try:
                    recorder.write(topic, data, now)
                except RecordingError:
                    return

        return on_message


def settings_options(settings):
    """Options of a calibrator run worth storing in its recording (see :meth:`RunRecorder.start`).

    ``settings``: a :class:`gsp_calibrator.settings.CalibratorSettings` (or anything with the same
    attributes); :func:`samples_from_recording` and ``gsp_reidentify`` read them back.
    """
    options = {}
    for name in (
        'sync_tolerance',
        'samples_per_posture',
        'formulation',
        'loss',
        'posture_count',
        'pool_size',
        'seed',
        'nominal_geometry_file',
    ):
        if hasattr(settings, name):
            options[name] = getattr(settings, name)
    if hasattr(settings, 'free_parameters'):
        options['free_parameters'] = list(settings.free_parameters)
    sigmas = getattr(settings, 'sigmas', None)
    if sigmas is not None:
        options.update(
            sigma_leg_lengths=sigmas.leg_lengths,
            sigma_inclinometer=sigmas.inclinometer,
            sigma_encoder=sigmas.encoder,
            sigma_lvdt=sigmas.lvdt,
        )
    return options
