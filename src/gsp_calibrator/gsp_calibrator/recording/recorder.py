"""``recording.mcap``: every message on the suite's topics during a run, as rosbag2 writes it.
See docs/data.md#recordingmcap."""

import json
import os
import re
import threading
import time

from rclpy.exceptions import InvalidHandle

from gsp_calibrator.recording.mcap_format import RecordingError, message_class
from gsp_calibrator.recording.mcap_io import RUN_METADATA_NAME, McapRecorder
from gsp_calibrator.settings import STORED_PARAMETERS
from gsp_kinematics.fileio import json_safe
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
#: MCAP metadata record of one posture's outcome (see :meth:`RunRecorder.note_posture_end`).
POSTURE_END_METADATA_NAME = 'gsp_posture_end'
#: MCAP metadata record written when a recording starts: its postures' outcomes are noted, so a
#: posture with no ``kept`` note gave no row (a recording without it: every rebuilt row counts).
OUTCOMES_METADATA_NAME = 'gsp_posture_outcomes'
#: The outcomes of a posture in a ``gsp_posture_end`` record.
KEPT, SKIPPED, IN_PROGRESS = 'kept', 'skipped', 'in_progress'

#: Topics :class:`RunRecorder` records by default: every topic of the suite.
SUITE_TOPICS = dict(names.TOPIC_TYPES)


#: Most messages a batched callback takes at one wake-up (a bound on the work between two
#: looks at the other subscriptions).
MAX_BATCH = 1000


class BatchedCallback:
    """A raw subscription's callback: ``callback([(CDR bytes, message info), ...])`` with the
    message the executor took and every further one waiting (:data:`MAX_BATCH` at most), in
    order. Set :attr:`subscription` to the subscription it serves before it is called."""

    def __init__(self, callback):
        self.callback = callback
        self.subscription = None

    def __call__(self, raw, info):
        messages = [(raw, info)]
        subscription = self.subscription
        try:
            with subscription.handle:
                while len(messages) < MAX_BATCH:
                    taken = subscription.handle.take_message(subscription.msg_type, True)
                    if taken is None:
                        break
                    messages.append(taken)
        except InvalidHandle:  # destroyed meanwhile (the node is going down)
            pass
        self.callback(messages)


class RunRecorder:
    """Records the suite's topics from inside a node into ``recording.mcap``."""

    def __init__(self, node, topics=None, callback_group=None, persistent=False, forward=None):
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

        #: ``{topic: callback([(CDR bytes, info), ...])}``: after its batch is recorded (or
        #: dropped, not recording), a topic's batch goes on to its callback, so the calibrator
        #: collects from the very messages its recording holds (one subscription each)
        self.forward = dict(forward or {})
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
            callback = BatchedCallback(self._callback(topic))
            callback.subscription = self.node.create_subscription(
                message_class(type_name),
                topic,
                callback,
                profile,
                callback_group=self.callback_group,
                raw=True,
            )
            self._subscriptions.append(callback.subscription)

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
        """Start recording to ``path`` (e.g. ``run_dir / 'recording.mcap'``)."""
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
            recorder.add_metadata(OUTCOMES_METADATA_NAME, {'noted': 'true'})
        except BaseException:
            recorder.abort()
            raise
        with self._lock:
            self._recorder = recorder
        if not self.persistent:
            self._subscribe()
        return recorder.path

    def note_collection_start(self, command_id, start_ns, posture=None):
        """Note that the samples of command ``command_id`` count from ``start_ns`` (node clock)."""
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

    def note_posture_end(self, command_id, posture, outcome, reason=''):
        """Note how the posture of command ``command_id`` ended: ``outcome`` is ``kept`` (its
        row is in samples.csv), ``skipped`` (``reason`` says why) or ``in_progress`` (the run
        stopped during its collection). :func:`.rebuild.samples_from_recording` keeps exactly the rows
        noted ``kept``, so the rebuild gives the rows of samples.csv."""
        with self._lock:
            if self._recorder is not None:
                note_posture_end(self._recorder, command_id, posture, outcome, reason)

    def stop(self, drain_s=0.0):
        """Stop recording and close the file (atomic); returns its path, or None if idle.

        ``drain_s``: first wait this long (s) so that messages published just before (the last
        progress, the result) are received; the recorder's callbacks must be able to run
        meanwhile (a multi-threaded executor: they have their own callback group)."""
        if drain_s > 0.0 and self._recorder is not None:
            time.sleep(drain_s)
        if not self.persistent:
            subscriptions, self._subscriptions = self._subscriptions, []
            for subscription in subscriptions:
                self.node.destroy_subscription(subscription)
        with self._lock:
            recorder, self._recorder = self._recorder, None
        if recorder is None:
            return None
        return recorder.close()

    def _callback(self, topic):
        clock, forward = self.node.get_clock(), self.forward.get(topic)

        def on_messages(batch):  # [(CDR bytes, info), ...] taken at once (BatchedCallback)
            with self._lock:
                if self._recorder is not None:  # else not recording: nothing to write
                    now = clock.now().nanoseconds
                    for data, _ in batch:
                        self._recorder.write(topic, data, now)
            if forward is not None:
                forward(batch)

        return on_messages


def note_posture_end(recorder, command_id, posture, outcome, reason=''):
    """Note in ``recorder`` (a :class:`McapRecorder`) how a posture ended (see
    :meth:`RunRecorder.note_posture_end`)."""
    recorder.add_metadata(
        POSTURE_END_METADATA_NAME,
        {
            'posture': int(posture),
            'command_id': str(command_id),
            'outcome': str(outcome),
            'reason': str(reason),
        },
    )


def settings_options(settings):
    """Options of a calibrator run worth storing in its recording (see :meth:`RunRecorder.start`):
    those of ``settings`` (a :class:`gsp_calibrator.settings.CalibratorSettings`) marked
    :data:`gsp_calibrator.settings.STORED`; :func:`.rebuild.samples_from_recording` and ``gsp_reidentify``
    read them back."""
    return settings.options(STORED_PARAMETERS)
