"""The calibrator's health on ``/diagnostics`` (status ``calibrator: calibration``), from the
state of its run and the age of the sensor topics (pure, no rclpy; docs/nodes.md#diagnostics)."""

from gsp_msgs_py import names
from gsp_msgs_py.health import ERROR, OK, WARN, Health, worst


def topic_age_key(topic):
    """The key of ``topic``'s age (s since its latest message) in the status."""
    return f'{topic} age_s'


def calibrator_health(running, progress, run_directory, heard_ns, now_ns, topic_timeout):
    """``Health`` of the calibrator.

    ``running``: a run is in progress; ``progress``: the latest published progress
    (``conversions.CalibrationProgress``) or None; ``run_directory``: of the current or last run
    ('' before the first); ``heard_ns``: ``{topic: receive time (ns) of its latest message, or
    None}`` of the sensor topics, on the clock of ``now_ns``; ``topic_timeout`` (s).

    ERROR while the last run has failed (until the next one starts); WARN while a sensor topic
    has been silent for more than ``topic_timeout`` (a run would fail, or is failing); else OK.
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
    return Health(worst(levels), '; '.join(messages), values)
