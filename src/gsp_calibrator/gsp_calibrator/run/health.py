"""The calibrator's health on ``/diagnostics`` (pure, no rclpy; docs/nodes.md#diagnostics)."""

import bisect
import itertools
import math
import threading

from gsp_msgs_py import names
from gsp_msgs_py.health import ERROR, OK, WARN, Health, worst

#: Processing lag (s) of a sensor topic above which the status warns (behind its streams).
LAG_WARN_S = 1.0


def topic_age_key(topic):
    """The key of ``topic``'s age (s since its latest message) in the status."""
    return f'{topic} age_s'


def topic_lag_key(topic):
    """The key of ``topic``'s processing lag (s, the largest since the previous status)."""
    return f'{topic} lag_s'


#: The lag histogram's geometric bins, from :data:`LAG_FLOOR_S` to :data:`LAG_CEILING_S` (the
#: first and last take the smaller and larger lags): 1 % resolution in a few kB per topic.
LAG_FLOOR_S = 1e-5
LAG_CEILING_S = 1e3
LAG_BIN_RATIO = 1.01
_LAG_BINS = math.ceil(math.log(LAG_CEILING_S / LAG_FLOOR_S) / math.log(LAG_BIN_RATIO)) + 1


class LagHistogram:
    """The distribution of one topic's processing lags (s) in fixed geometric bins."""

    def __init__(self):
        self.counts = [0] * _LAG_BINS
        self.count = 0
        self.largest = None

    def add(self, lag_s):
        """Count one lag (s; a negative one, from clock steps, counts as 0)."""
        lag_s = max(0.0, float(lag_s))
        index = 0
        if lag_s > LAG_FLOOR_S:
            index = min(_LAG_BINS - 1, math.ceil(math.log(lag_s / LAG_FLOOR_S, LAG_BIN_RATIO)))
        self.counts[index] += 1
        self.count += 1
        self.largest = lag_s if self.largest is None else max(self.largest, lag_s)

    def percentile(self, percent):
        """The nearest-rank ``percent`` percentile (s) to within one bin (1 %, never above the
        largest lag); None before the first lag."""
        if not self.count:
            return None
        rank = max(1, math.ceil(percent / 100.0 * self.count))
        index = bisect.bisect_left(list(itertools.accumulate(self.counts)), rank)
        if index >= _LAG_BINS - 1:  # the last bin has no upper edge
            return self.largest
        return min(self.largest, LAG_FLOOR_S * LAG_BIN_RATIO**index)

    def summary(self):
        """``{count, p50_s, p99_s, max_s}`` (the figures None before the first lag)."""
        return {
            'count': self.count,
            'p50_s': self.percentile(50),
            'p99_s': self.percentile(99),
            'max_s': self.largest,
        }


class ProcessingLags:
    """Each sensor topic's processing lag (s): from a message's receipt off the wire to the
    calibrator's decision on it (thread-safe); those of the run per topic in a histogram
    (:meth:`reset` at its start, :meth:`summary` into its ``result.json``)."""

    def __init__(self, topics):
        self._largest = dict.fromkeys(topics)
        self._lock = threading.Lock()
        self.reset()

    def reset(self):
        with self._lock:
            self._histograms = {topic: LagHistogram() for topic in self._largest}

    def note(self, topic, received_ns, decided_ns, in_run=False):
        """The lag (s) of a message of ``topic`` (ns, one clock); None when not received."""
        if not received_ns:
            return None
        lag = (int(decided_ns) - int(received_ns)) * 1e-9
        with self._lock:
            if in_run:
                self._histograms[topic].add(lag)
            largest = self._largest.get(topic)
            if largest is None or lag > largest:
                self._largest[topic] = lag
        return lag

    def take(self):
        """``{topic: largest lag (s) since the previous call, or None}``."""
        with self._lock:
            lags, self._largest = self._largest, dict.fromkeys(self._largest)
        return lags

    def summary(self):
        """The run's ``{topic: {count, p50_s, p99_s, max_s}}``."""
        with self._lock:
            return {topic: h.summary() for topic, h in self._histograms.items()}


def calibrator_health(running, progress, run_directory, heard_ns, now_ns, topic_timeout, lags=None):
    """``Health`` of the calibrator: ``progress``, its latest (or None); ``heard_ns``: ``{sensor
    topic: receive time (ns) of its latest message, or None}`` on the clock of ``now_ns``;
    ``lags``: :meth:`ProcessingLags.take`."""
    phase = progress.phase if progress is not None else names.PHASE_IDLE
    index, count = (progress.posture_index, progress.posture_count) if progress else (0, 0)
    values = {
        'state': 'running' if running else 'idle',
        'phase': phase,
        'run': str(run_directory),
        'posture': f'{index} of {count}',
        'topic_timeout_s': f'{topic_timeout:g}',
    }
    silent = []
    for topic, heard in heard_ns.items():
        age_s = None if heard is None else (now_ns - heard) * 1e-9
        values[topic_age_key(topic)] = 'never' if age_s is None else f'{age_s:.3f}'
        if age_s is None or age_s > topic_timeout:
            silent.append(topic)
    levels, messages = [OK], []
    if phase == names.PHASE_FAILED and not running:
        levels.append(ERROR)
        messages.append(f'the last run failed: {progress.message}')
    elif running:
        messages.append(f'running, posture {index} of {count}: {phase}')
    else:
        messages.append(f'idle (last run {phase})' if progress else 'idle')
    if silent:
        levels.append(WARN)
        messages.append(f'silent for more than {topic_timeout:g} s: {", ".join(silent)}')
    behind = {}
    for topic, lag in (lags or {}).items():
        values[topic_lag_key(topic)] = 'none' if lag is None else f'{lag:.3f}'
        if lag is not None and lag > LAG_WARN_S:
            behind[topic] = lag
    if behind:
        levels.append(WARN)
        listed = ', '.join(f'{topic} {lag:.3g} s' for topic, lag in behind.items())
        messages.append(f'behind its streams by more than {LAG_WARN_S:g} s: {listed}')
    return Health(worst(levels), '; '.join(messages), values)
