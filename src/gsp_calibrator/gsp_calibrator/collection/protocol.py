"""The posture-collection protocol of a calibration run (pure, no rclpy).
See docs/architecture.md#one-collection-protocol."""

import collections
import functools
import math

import numpy as np

from gsp_calibrator.collection.events import (
    CollectionStarted,
    CommandAgain,
    PairsCollected,
    PlatformElsewhere,
    PostureSkipped,
    RowReady,
    SampleDropped,
)
from gsp_calibrator.collection.posture_state import (
    AWAIT_SETTLE,
    AWAIT_STATUS,
    COLLECTING,
    LatestReadings,
    Posture,
)
from gsp_calibrator.collection.synchroniser import (
    ENCODER,
    INCLINOMETER,
    LEG_LENGTHS,
    LVDT,
    SampleCollector,
    segment_pairs,
)
from gsp_calibrator.collection.timeouts import CollectionTimeouts, planned_move
from gsp_calibrator.collection.topics import (
    SENSOR_TOPICS,
    TOPIC_STREAMS,
    has_non_finite,
    read_sensor,
)
from gsp_kinematics import channels
from gsp_kinematics.estimation.noise_estimate import DEFAULT_REST_SIGMAS
from gsp_kinematics.model.device import distance_from_commands

#: A posture is skipped when this many times pairs_per_posture pairs hold no consistent window.
MAX_PAIRS_PER_SAMPLE = 20
#: Samples kept per stream by the collector (at least 2 * MAX_PAIRS_PER_SAMPLE * samples).
MIN_BUFFER = 2000
#: Pairs handed over per posture with ``keep_pairs`` (the first ones after the settle), and
#: before the first command (the last ones), so a long idle recording stays cheap.
MAX_STREAM_SAMPLES = 2000

_ADDERS = {
    LEG_LENGTHS: SampleCollector.add_leg_lengths,
    INCLINOMETER: SampleCollector.add_inclinometer,
    ENCODER: SampleCollector.add_encoder,
    LVDT: SampleCollector.add_lvdt,
}


def settle_start_ns(published_ns, received_ns, topic_timeout):
    """The collection start (ns) of a ``settled`` status published at ``published_ns`` (None or
    0: unknown) and received at ``received_ns``: the publish instant, or the receipt when that
    is unknown, after the receipt or more than ``topic_timeout`` (s) before it."""
    received_ns = int(received_ns)
    if published_ns and received_ns - topic_timeout * 1e9 <= int(published_ns) <= received_ns:
        return int(published_ns)
    return received_ns


def wire_receipt_ns(received_ns, now_ns):
    """The middleware's receive time ``received_ns`` of a message handled at ``now_ns`` (ns), or
    None if unknown (0) or after ``now_ns`` (another time base)."""
    if not received_ns or int(received_ns) > int(now_ns):
        return None
    return int(received_ns)


def dropped_event(collector, topic, msg, error):
    """The :class:`SampleDropped` of an unusable ``msg`` (a non-finite reading counted)."""
    if has_non_finite(msg):
        stream = TOPIC_STREAMS[topic]
        collector.record_non_finite(stream)
        return SampleDropped(topic, str(error), True, collector.non_finite[stream])
    return SampleDropped(topic, str(error), False)


def platform_elsewhere(nominal, max_posture_error, posture, pose, readings):
    """:class:`PlatformElsewhere` when the device ``readings`` put the platform (eq 9 with the
    ``nominal`` geometry) more than ``max_posture_error`` (m) from the commanded ``pose``."""
    distance = float(distance_from_commands(nominal, pose, readings)[0])
    if distance > max_posture_error:
        return PlatformElsewhere(posture, distance, max_posture_error)
    return None


class CollectionProtocol:
    """The collection protocol (module docstring); every input returns a list of events.
    ``sync_tolerance`` (s), ``pairs_per_posture``, ``noise_std`` (10 channel stds or None),
    ``rest_lookback`` (s), ``rest_sigmas``: the collector; the rest: the timeouts (s)."""

    @classmethod
    def for_settings(cls, settings):
        """The protocol of a calibrator run with ``settings`` (a ``CalibratorSettings``)."""
        return cls(
            settings.sync_tolerance,
            settings.pairs_per_posture,
            settings.sigmas.channel_std(),
            topic_timeout=settings.topic_timeout,
            settle_timeout=settings.settle_timeout,
            rest_lookback=settings.rest_lookback,
            rest_sigmas=settings.rest_sigmas,
            planned_move=planned_move(settings.nominal, settings.motion_limits),
            posture_check=functools.partial(
                platform_elsewhere, settings.nominal, settings.max_posture_error
            ),
        )

    def __init__(
        self,
        sync_tolerance,
        pairs_per_posture,
        noise_std=None,
        *,
        topic_timeout=math.inf,
        settle_timeout=math.inf,
        max_pairs_per_sample=MAX_PAIRS_PER_SAMPLE,
        keep_pairs=False,
        rest_lookback=0.0,
        rest_sigmas=DEFAULT_REST_SIGMAS,
        planned_move=None,
        posture_check=None,
    ):
        self.pairs_per_posture = int(pairs_per_posture)
        self.posture_check = posture_check  # (posture, pose, readings) -> failure or None
        self.timeouts = CollectionTimeouts(
            topic_timeout, settle_timeout, sync_tolerance, pairs_per_posture, planned_move
        )
        self.topic_timeout = self.timeouts.topic_timeout  # s
        self.pair_limit = int(max_pairs_per_sample) * self.pairs_per_posture
        self.keep_pairs = bool(keep_pairs)
        buffer = None if keep_pairs else max(MIN_BUFFER, 2 * self.pair_limit)
        settle = {'rest_lookback': rest_lookback, 'rest_sigmas': rest_sigmas}
        self.collector = SampleCollector(
            sync_tolerance, pairs_per_posture, max_buffer=buffer, noise_std=noise_std, **settle
        )
        self._posture = None  # the awaited posture (Posture) or None
        self._previous = None  # device readings of the previous row
        self.latest = LatestReadings()  # the latest readings, the rate heard
        self._recent = collections.deque(maxlen=4 * MIN_BUFFER)  # samples since the command
        self._checked_pairs = None  # the collector's pair revision last checked
        self.skipped = []  #: posture skips of the run: ``[PostureSkipped, ...]``
        self._idle = None  # keep_pairs: the samples before the first command
        if self.keep_pairs:
            self._idle = SampleCollector(sync_tolerance, 1, max_buffer=2 * MAX_STREAM_SAMPLES)
            self._idle.start(-(2**62))

    def heard(self, topic):
        """Whether ``topic`` has said anything yet."""
        return topic in self.timeouts.last_heard

    @property
    def collecting(self):
        return self._posture is not None and self._posture.state == COLLECTING

    def latest_leg_lengths(self):
        """Latest leg-length readings (6,) m received, or None."""
        return self.latest.leg_lengths()

    def summary(self):
        """The ``collection`` of ``result.json``: the run's skips and the samples dropped."""
        keys = ('posture', 'reason', 'rejected_by_platform')
        skipped = [{key: getattr(skip, key) for key in keys} for skip in self.skipped]
        return {'skipped': skipped, **self.collector.dropped()}

    def continue_after(self, readings):
        """Continue a run whose last row had device readings ``readings`` ``[alpha, beta, phi,
        d_m]`` (rad, m): they are the previous posture's for the next row."""
        self._previous = np.asarray(readings, dtype=float).reshape(len(channels.READING_NAMES))

    def command(self, posture, pose, command_id, now_ns):
        """Posture ``posture`` (commanded ``pose``, id ``command_id``) was commanded at ``now_ns``."""
        self.timeouts.attend(now_ns)
        events = self._end_segment() if self.keep_pairs else self._close()
        if self._previous is None:
            # What the device reports before the platform moves (stale readings would match).
            self._previous = self.latest.device_readings()
        self.collector.stop()
        self._recent.clear()
        self._checked_pairs = None
        pose = np.asarray(pose, dtype=float).reshape(6)
        self._posture = Posture(int(posture), pose, str(command_id), int(now_ns))
        legs, planned_move = self.latest_leg_lengths(), self.timeouts.planned_move
        if planned_move is not None and legs is not None:
            self._posture.move_s = planned_move(legs, pose)
        return events + self.poll(now_ns)

    def status(self, status, now_ns, start_ns=None):
        """A platform status (``conversions.PlatformStatus``) received at ``now_ns``;
        ``start_ns``: the collection start if it settles the posture (default ``now_ns``)."""
        self.timeouts.attend(now_ns)
        posture = self._posture
        if posture is None or status.command_id != posture.command_id:
            return self.poll(now_ns)
        if posture.state in (AWAIT_STATUS, AWAIT_SETTLE):
            if posture.first_status_ns is None:
                posture.first_status_ns = int(now_ns)
                posture.state = AWAIT_SETTLE
            if status.rejected:
                reason = status.reason or 'rejected'
                return self._skip(f'rejected by the platform: {reason}', True, reason)
            if status.settled:
                return self._start(now_ns, now_ns if start_ns is None else start_ns)
        return self.poll(now_ns)

    def sensor(self, topic, msg, now_ns, received_ns=None):
        """A sensor message on ``topic`` handled at ``now_ns``, off the wire at ``received_ns``
        (the middleware's receive time on the same clock; None: unknown)."""
        return self.sensors([(topic, msg, received_ns)], now_ns)

    def sensors(self, messages, now_ns):
        """Sensor messages ``[(topic, msg, received_ns), ...]`` (as for :meth:`sensor`) handled
        at ``now_ns``, in order (a listener's batch), the posture judged once, after them."""
        self.timeouts.attend(now_ns)
        events = []
        for topic, msg, received_ns in messages:
            self.timeouts.hear(topic, now_ns if received_ns is None else received_ns)
            try:
                stream, stamp_ns, values = read_sensor(topic, msg)
            except (ValueError, TypeError) as error:
                events.append(dropped_event(self.collector, topic, msg, error))
                continue
            self._take(stream, stamp_ns, values, now_ns, received_ns)
        return events + self._judged(now_ns)

    def sample(self, stream, stamp_ns, values, now_ns, received_ns=None):
        """A parsed sensor sample (``values`` as for the collector's ``add_<stream>``), handled
        at ``now_ns``, off the wire at ``received_ns`` (None: unknown)."""
        self.timeouts.attend(now_ns)
        topic = next(t for t, s in TOPIC_STREAMS.items() if s == stream)
        self.timeouts.hear(topic, now_ns if received_ns is None else received_ns)
        self._take(stream, stamp_ns, values, now_ns, received_ns)
        return self._judged(now_ns)

    def _take(self, stream, stamp_ns, values, now_ns, received_ns):
        """Take one parsed sample (not judged yet)."""
        self.latest.note(stream, stamp_ns, values)
        posture = self._posture
        if posture is None:
            if self._idle is not None:
                _ADDERS[stream](self._idle, stamp_ns, *values)
            return
        if posture.state != COLLECTING:
            self._recent.append((stream, stamp_ns, values))
            return
        received = int(now_ns if received_ns is None else received_ns)
        by_stream = posture.received_by_stream
        by_stream[stream] = max(by_stream.get(stream, received), received)
        if len(by_stream) == len(SENSOR_TOPICS):
            posture.received_ns = max(posture.received_ns, min(by_stream.values()))
        if stamp_ns < posture.start_ns and received_ns is None:
            # Stamped before the start, handled now: the caller may be working through a backlog
            # (its listener fell behind), which is no lack of progress of the pairs (a receive
            # time off the wire shows the backlog itself: received before the settle).
            posture.progress_ns = max(posture.progress_ns, received)
        self._add(posture, stream, stamp_ns, values)

    def _add(self, posture, stream, stamp_ns, values):
        if _ADDERS[stream](self.collector, stamp_ns, *values):
            latest = posture.latest_ns.get(stream, stamp_ns)
            posture.latest_ns[stream] = max(latest, int(stamp_ns))

    def poll(self, now_ns):
        """Events due at ``now_ns`` (timeouts)."""
        self.timeouts.attend(now_ns)
        posture = self._posture
        if posture is None:
            return []
        now_ns = int(now_ns)
        if posture.state == AWAIT_STATUS:
            overdue = self.timeouts.status_overdue(posture, now_ns)
            if overdue is not None:
                return [overdue] if isinstance(overdue, CommandAgain) else self._fail(overdue)
        elif posture.state == AWAIT_SETTLE:
            reason = self.timeouts.settle_overdue(posture, now_ns)
            if reason:
                return self._skip(reason)
        elif posture.state == COLLECTING and not self.keep_pairs:
            return self._collection_timeouts(now_ns)
        return []

    def finish(self, now_ns=None):
        """End of input (recordings): ``keep_pairs`` hands over the last segment."""
        return self._end_segment() if self.keep_pairs else self._close()

    def _close(self):
        """The row of the posture in collection when its data end (the next command, the end of
        a recording: every sample stamped before them given), on all its pairs; [] if none."""
        if not self.collecting:
            return []
        self.collector.set_horizon(None)
        return self._row() if self.collector.ready() else []

    def _start(self, now_ns, start_ns):
        posture = self._posture
        posture.state = COLLECTING
        posture.start_ns, posture.started_ns = int(start_ns), int(now_ns)
        posture.progress, posture.progress_ns = 0, int(now_ns)
        posture.progress_data_ns, posture.received_ns = None, int(now_ns)
        self.collector.start(posture.start_ns, self._previous)
        for stream, stamp_ns, values in self._recent:  # those stamped after the start count
            self._add(posture, stream, stamp_ns, values)
        self._recent.clear()
        events = [CollectionStarted(posture.number, posture.command_id, posture.start_ns)]
        if self.keep_pairs:
            return events
        return events + self._check_collection(now_ns)

    def _judged(self, now_ns):
        return self._check_collection(now_ns) if self.collecting else self.poll(now_ns)

    def _check_collection(self, now_ns):
        if self.keep_pairs:
            return []
        collector = self.collector
        # Windows are judged once their pairs are final in the data's time (set_horizon).
        data_ns = self._posture.data_ns()
        collector.set_horizon(self._posture.start_ns if data_ns is None else data_ns)
        # ready() is a function of the pairs and the horizon: only ask again when they changed.
        checked = (collector.pair_revision, collector.horizon_ns)
        if checked != self._checked_pairs:
            self._checked_pairs = checked
            if collector.ready():
                return self._row()
            # (while the readings still move, settle_timeout bounds the wait: the timeouts)
            count = collector.pair_count()
            if count >= self.pair_limit and collector.not_at_rest is None:
                return self._skip(
                    f'no {self.pairs_per_posture} consistent samples among {count} '
                    'synchronised ones (too noisy, or the device readings did not change from '
                    'the previous posture)'
                )
        return self._collection_timeouts(now_ns)

    def _collection_timeouts(self, now_ns):
        failure, reason = self.timeouts.collection_overdue(self._posture, self.collector, now_ns)
        if failure is not None:
            return self._fail(failure)
        return self._skip(reason) if reason else []

    def _row(self):
        posture, collector = self._posture, self.collector
        dropped_before = collector.inconsistent
        sample = collector.take_posture()
        check = self.posture_check
        failure = check and check(posture.number, posture.pose, sample.readings)
        if failure:
            return self._fail(failure)
        self._previous = sample.readings
        self._posture = None
        return [
            RowReady(posture.number, posture.pose, sample, collector.inconsistent - dropped_before)
        ]

    def _skip(self, reason, rejected=False, platform_reason=''):
        event = PostureSkipped(self._posture.number, reason, rejected, platform_reason)
        self.skipped.append(event)
        self.collector.stop()
        self._posture = None
        return [event]

    def _fail(self, event):
        self.collector.stop()
        self._posture = None
        return [event]

    def _end_segment(self):
        """``keep_pairs``: the pairs of the segment that the next command (or the end) closes."""
        posture = self._posture
        if posture is None:
            if self._idle is None:
                return []
            idle, self._idle = self._idle, None
            stamps, legs, readings = segment_pairs(idle, MAX_STREAM_SAMPLES, last=True)
            return [PairsCollected(None, '', None, stamps, legs, readings)]
        if posture.state != COLLECTING:
            return self._skip('never settled')
        stamps, legs, readings = segment_pairs(self.collector, MAX_STREAM_SAMPLES)
        if len(stamps) == 0:
            return self._skip('no synchronised sample after settling')
        self.collector.stop()
        self._posture = None
        return [
            PairsCollected(posture.number, posture.command_id, posture.pose, stamps, legs, readings)
        ]
