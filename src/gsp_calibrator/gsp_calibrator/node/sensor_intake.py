"""The calibrator's intake of its sensor topics: batches of raw messages, from the recorder's
listener thread, to the run's collection protocol."""

import collections
import time

from gsp_calibrator.collection import protocol
from gsp_calibrator.collection.single_source import SingleSourceGuard
from gsp_calibrator.collection.topics import SENSOR_TOPICS, sensor_message
from gsp_calibrator.run.health import ProcessingLags

LISTENER_TICK_S = 0.1  #: the listener's tick (silence on the wire, :meth:`SensorIntake.tick`)


class SensorIntake:
    """The sensor batches of a calibrator node: ``now_ns()`` its clock (ns),
    ``wire_times_on_clock()``: whether the middleware's receive times are on it. Set
    :attr:`postures` (the node's ``PostureLink``) before a run starts."""

    def __init__(self, now_ns, count_publishers, wire_times_on_clock=lambda: True):
        self.now_ns = now_ns
        self.wire_times_on_clock = wire_times_on_clock
        self.count_publishers = count_publishers
        self.postures = None
        self.sources = SingleSourceGuard()  # reset at each run's first reading
        #: For /diagnostics: monotonic ns of each sensor topic's latest batch, run or not.
        self.heard_ns = dict.fromkeys(SENSOR_TOPICS)
        self.lags = ProcessingLags(SENSOR_TOPICS)
        self._ticks = collections.deque(maxlen=3)  # node clock, ns

    def callbacks(self):
        """``{topic: callback(batch)}`` of the sensor topics."""
        return {topic: self._callback(topic) for topic in SENSOR_TOPICS}

    def _callback(self, topic):
        lags = self.lags

        def callback(batch):
            self.heard_ns[topic] = time.monotonic_ns()
            postures = self.postures
            in_run = postures is not None and postures.active  # else dropped at once
            if in_run:
                messages = [(sensor_message(raw), info) for raw, info in batch]
                postures.feed(lambda collection: self._step(collection, topic, messages))
            decided_ns = time.time_ns()
            for _, info in batch:
                lags.note(topic, info.get('received_timestamp'), decided_ns, in_run=in_run)

        return callback

    def _step(self, collection, topic, messages):
        """Feed ``messages`` of ``topic`` to ``collection`` (the posture link's lock held)."""
        taken = []
        for msg, info in messages:
            failure = self.sources.validate_reading(
                topic,
                msg,
                info.get('publication_sequence_number'),
                lambda: self.count_publishers(topic),
            )
            if failure is not None:  # a second source: the run ends, naming the topic
                self.postures.fail(failure)
                return []
            taken.append((topic, msg, info.get('received_timestamp')))
        now_ns = self.now_ns()
        if not self.wire_times_on_clock():  # system time against a simulated clock
            taken = [(t, m, None) for t, m, _ in taken]
        taken = [(t, m, protocol.wire_receipt_ns(r, now_ns)) for t, m, r in taken]
        return collection.sensors(taken, now_ns)

    def tick(self):
        """The listener's own tick (its thread): every message received before the tick two back
        has been taken, so silence is judged up to then (a starved listener is no silent topic)."""
        self._ticks.append(self.now_ns())
        postures = self.postures
        if postures is not None and len(self._ticks) == self._ticks.maxlen:
            checked_ns = self._ticks[0]

            def step(collection):
                collection.timeouts.checked_until(checked_ns)
                return collection.poll(self.now_ns())

            postures.feed(step)
