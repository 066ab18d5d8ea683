"""The calibrator's health on ``/diagnostics`` (status ``calibrator: calibration``), from the
state of its run, the age of the sensor topics and how far behind them the calibrator is
(pure, no rclpy; docs/nodes.md#diagnostics)."""

from gsp_msgs_py import names
from gsp_msgs_py.health import ERROR, OK, WARN, Health, worst

#: Processing lag (s) of a sensor topic above which the status warns: the calibrator is behind
#: its streams (a busy machine), and its decisions on the postures come that much later.
LAG_WARN_S = 1.0


def topic_age_key(topic):
    """The key of ``topic``'s age (s since its latest message) in the status."""
    return f'{topic} age_s'


def topic_lag_key(topic):
    """The key of ``topic``'s processing lag (s, the largest since the previous status)."""
    return f'{topic} lag_s'


class ProcessingLags:
    """Each sensor topic's processing lag: from a message's receipt off the wire (the
    middleware's receive time) to the calibrator's decision on it, s. :meth:`note` at each
    message (any thread), :meth:`take` at each status: the largest lag since the previous one."""

    def __init__(self, topics):
        self._largest = dict.fromkeys(topics)

    def note(self, topic, received_ns, decided_ns):
        """The lag (s) of a message of ``topic`` received at ``received_ns`` and decided on at
        ``decided_ns`` (ns, one clock); None (not counted) when the receive time is unknown."""
        if not received_ns:
            return None
        lag = (int(decided_ns) - int(received_ns)) * 1e-9
        largest = self._largest.get(topic)
        if largest is None or lag > largest:
            self._largest[topic] = lag
        return lag

    def take(self):
        """``{topic: largest lag (s) since the previous call, or None}``."""
        lags, self._largest = self._largest, dict.fromkeys(self._largest)
        return lags


def calibrator_health(running, progress, run_directory, heard_ns, now_ns, topic_timeout, lags=None):
    """``Health`` of the calibrator.

    ``running``: a run is in progress; ``progress``: the latest published progress
    (``conversions.CalibrationProgress``) or None; ``run_directory``: of the current or last run
    ('' before the first); ``heard_ns``: ``{topic: receive time (ns) of its latest message, or
    None}`` of the sensor topics, on the clock of ``now_ns``; ``topic_timeout`` (s); ``lags``:
    ``{topic: processing lag (s) or None}`` (:meth:`ProcessingLags.take`).

    ERROR while the last run has failed (until the next one starts); WARN while a sensor topic
    has been silent for more than ``topic_timeout`` (a run would fail, or is failing), or while
    the calibrator handles a topic more than :data:`LAG_WARN_S` after its receipt; else OK.
    """
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
