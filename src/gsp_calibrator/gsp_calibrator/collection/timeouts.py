"""The collection protocol's timeouts: who spoke when, the caller's stalls (pure, no rclpy).
See docs/architecture.md#synchronisation."""

import math

import numpy as np

from gsp_calibrator.collection.events import CommandAgain, NoSynchronisedPair, TopicSilent
from gsp_calibrator.collection.synchroniser import LEG_LENGTHS
from gsp_calibrator.collection.topics import SENSOR_TOPICS
from gsp_kinematics.model.motion import move_time, posture_leg_lengths
from gsp_msgs_py import names

#: A gap between two calls of at least this fraction of ``topic_timeout`` is the caller's stall.
STALL_FRACTION = 0.5

#: Unanswered for this fraction of ``topic_timeout``, a command is sent again (architecture.md).
RESEND_FRACTION = 0.25


class CollectionTimeouts:
    """The timeouts (s) of one run; ``sync_tolerance`` and ``pairs_per_posture`` appear in the
    messages only; ``planned_move``: ``move_s(start_legs, pose)`` (s), or None: no move time."""

    def __init__(
        self, topic_timeout, settle_timeout, sync_tolerance, pairs_per_posture, planned_move=None
    ):
        self.topic_timeout = float(topic_timeout)
        self.planned_move = planned_move
        self.settle_timeout = float(settle_timeout)
        self.sync_tolerance = float(sync_tolerance)
        self.pairs_per_posture = int(pairs_per_posture)
        self.last_heard = {}  #: topic -> receive time (ns) of its latest message
        self._attended_ns = None  # receive time of the latest call
        self._stall_end_ns = -(2**62)  # end of the latest stall of the caller
        self.checked_ns = None  #: None, or :meth:`checked_until`'s latest time (ns)

    def attend(self, now_ns):
        """Note a call at ``now_ns``; a long gap since the previous one is a stall."""
        now_ns = int(now_ns)
        if self._attended_ns is not None and now_ns > self._attended_ns:
            if elapsed(self._attended_ns, now_ns) >= STALL_FRACTION * self.topic_timeout:
                self._stall_end_ns = now_ns
        self._attended_ns = now_ns if self._attended_ns is None else max(self._attended_ns, now_ns)

    def hear(self, topic, now_ns):
        """``topic`` said something at ``now_ns`` (off the wire, when known)."""
        self.last_heard[topic] = max(self.last_heard.get(topic, int(now_ns)), int(now_ns))

    def checked_until(self, checked_ns):
        """The caller has taken every sensor message received off the wire before
        ``checked_ns`` (ns): silence is judged up to then (a starved listener's is not the
        topic's)."""
        checked_ns = int(checked_ns)
        self.checked_ns = (
            checked_ns if self.checked_ns is None else max(self.checked_ns, checked_ns)
        )

    def since(self, reference_ns, now_ns):
        """Seconds from ``reference_ns`` to ``now_ns``, counted again from the latest stall."""
        return elapsed(max(int(reference_ns), self._stall_end_ns), now_ns)

    def status_overdue(self, posture, now_ns):
        """First status overdue: :class:`TopicSilent`; to send again: :class:`CommandAgain`."""
        if self.since(posture.commanded_ns, now_ns) < self.topic_timeout:
            sent_ns = posture.sent_ns or posture.commanded_ns
            if self.since(sent_ns, now_ns) < RESEND_FRACTION * self.topic_timeout:
                return None
            posture.sent_ns = int(now_ns)
            return CommandAgain(posture.command_id)
        doing = f'waiting for the status of posture {posture.number} (command {posture.command_id})'
        return TopicSilent(
            names.TOPIC_PLATFORM_STATUS,
            doing,
            f'topic {names.TOPIC_PLATFORM_STATUS} is silent: no status for posture '
            f'{posture.number} (command {posture.command_id}) within {self.topic_timeout:g} s',
        )

    def settle_overdue(self, posture, now_ns):
        """The skip reason if the settle is overdue, else ''."""
        limit = self.settle_timeout + posture.move_s
        if self.since(posture.first_status_ns, now_ns) >= limit:
            return (
                f'not settled within {limit:g} s (the planned move {posture.move_s:g} s '
                f'+ settle_timeout {self.settle_timeout:g} s)'
            )
        return ''

    def collection_overdue(self, posture, collector, now_ns):
        """The collection's verdict at ``now_ns``: ``(failure event or None, skip reason or '')``."""
        # Silence on the wire: up to when the caller has looked at its queues, if it says so.
        heard_ns = now_ns if self.checked_ns is None else min(int(now_ns), self.checked_ns)
        silences = {  # s, since the topic's latest message (or the settle, or a stall)
            topic: self.since(max(self.last_heard.get(topic, 0), posture.started_ns), heard_ns)
            for topic in SENSOR_TOPICS
        }
        topic = max(silences, key=silences.get)  # the first to fall silent is the cause
        doing = f'collecting posture {posture.number}'
        # >= as for the progress timeout below: a topic that died at the collection start
        # expires together with the progress, and the silent topic is the cause to name.
        if silences[topic] >= self.topic_timeout:
            text = f'topic {topic} is silent: no message for {self.topic_timeout:g} s while {doing}'
            return TopicSilent(topic, doing, text), ''
        count = collector.pair_count()
        data_ns = posture.data_ns()
        if posture.progress_data_ns is None:
            posture.progress_data_ns = data_ns
        if count != posture.progress:
            posture.progress, posture.progress_ns = count, posture.received_ns
            posture.progress_data_ns = data_ns
        # The pairs' progress in the samples' receive times (a listener that falls behind
        # delays it) and in their stamps.
        stalled_s = self.since(posture.progress_ns, posture.received_ns)
        if data_ns is not None and posture.progress_data_ns is not None:
            stalled_s = max(stalled_s, (data_ns - posture.progress_data_ns) * 1e-9)
        if stalled_s >= self.topic_timeout:
            # The pairs stopped: if a topic stopped too (a dead node whose last messages still
            # paired a little later), it is the cause to name.
            if silences[topic] >= 0.5 * self.topic_timeout:
                text = (
                    f'topic {topic} is silent: no message for {silences[topic]:.3g} s while '
                    f'{doing} (and no synchronised sample for {self.topic_timeout:g} s)'
                )
                return TopicSilent(topic, doing, text), ''
            counts = collector.counts()
            return NoSynchronisedPair(
                posture.number,
                f'no synchronised sample for {self.topic_timeout:g} s at posture '
                f'{posture.number}: {counts[LEG_LENGTHS]} leg-length and {counts["device"]} '
                f'complete device samples since settling, {counts["pairs"]} within '
                f'sync_tolerance {self.sync_tolerance:g} s, consistent: {counts["consistent"]} '
                f'(non-finite readings dropped so far: {collector.non_finite})',
            ), ''
        # The bounds below count in the data's time (docs/architecture.md#synchronisation), a
        # tolerance later: the windows ending at a bound have been judged on final pairs.
        data_s = 0.0 if data_ns is None else (data_ns - posture.start_ns) * 1e-9
        data_s -= self.sync_tolerance
        if collector.not_at_rest is not None and data_s >= self.settle_timeout:
            return None, (
                f'readings not settled within settle_timeout {self.settle_timeout:g} s of the '
                f"platform's settled status: {collector.not_at_rest.describe()}"
            )
        # The collection is bounded as a whole: pairs that keep coming without a consistent
        # window would otherwise restart the progress timeout for ever.
        limit = self.settle_timeout + self.topic_timeout
        if data_s >= limit:
            counts = collector.counts()
            return None, (
                f'no {self.pairs_per_posture} consistent synchronised samples within '
                f"{limit:g} s (settle_timeout + topic_timeout) of settling, in the samples' "
                'stamps: '
                f'{counts[LEG_LENGTHS]} leg-length and {counts["device"]} complete device '
                f'samples, {counts["pairs"]} within sync_tolerance {self.sync_tolerance:g} s'
            )
        return None, ''


def planned_move(nominal, limits):
    """``move_s(start_legs, pose)``: the time (s) a controller with geometry ``nominal`` takes
    to move its legs from ``start_legs`` (6,) m to ``pose`` at the leg ``limits``."""

    def move_s(start_legs, pose):
        end_legs = posture_leg_lengths(nominal, pose)[0]
        seconds = float(move_time(np.asarray(start_legs, dtype=float), end_legs, limits))
        return seconds if math.isfinite(seconds) else 0.0  # an unreachable pose: refused

    return move_s


def elapsed(since_ns, now_ns):
    """Seconds from ``since_ns`` to ``now_ns``."""
    return (int(now_ns) - int(since_ns)) * 1e-9
