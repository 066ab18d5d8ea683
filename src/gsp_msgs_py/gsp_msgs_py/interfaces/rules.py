"""The conformance rules of the suite's sensor topics, applied to recorded messages (pure)."""

import dataclasses
import math

import numpy as np

from .. import names
from ..diagnostics import node_of_status
from ..health import ERROR, LEVEL_NAMES


@dataclasses.dataclass(frozen=True)
class Received:
    """One JointState as received: ``receive_s`` and ``stamp_s`` (s), names and positions."""

    receive_s: float
    stamp_s: float
    names: tuple
    values: tuple


@dataclasses.dataclass(frozen=True)
class Limits:
    """Thresholds of the checks (SI)."""

    min_rate_hz: float = 50.0
    #: Plausible magnitudes: above them the unit is wrong (degrees for radians, mm for metres).
    max_tilt_rad: float = 1.0  # alpha, beta: the platform never tilts the device 57 deg
    max_phi_rad: float = 2 * math.pi
    max_lvdt_m: float = 2.0
    max_leg_stroke_m: float = 3.0
    #: Largest static noise std: above it the sensor (or its unit) is suspect.
    max_angle_noise_rad: float = 1e-3
    max_length_noise_m: float = 1e-4
    #: Receive time minus stamp: above max_delay_s the stamps lag (or clocks disagree); below
    #: -max_clock_lead_s the stamps are in the future (the publisher's clock is ahead).
    max_delay_s: float = 0.05
    max_clock_lead_s: float = 0.005
    min_shared_stamps: float = 0.9  #: share of device instants that carry all three readings


#: The sensor topics and their joint names.
SENSOR_TOPICS = {
    names.TOPIC_LEG_LENGTHS: names.LEG_JOINT_NAMES,
    names.TOPIC_INCLINOMETER: names.INCLINOMETER_JOINT_NAMES,
    names.TOPIC_ENCODER: names.ENCODER_JOINT_NAMES,
    names.TOPIC_LVDT: names.LVDT_JOINT_NAMES,
}


def _unit_problem(topic, values, limits):
    """Why the magnitudes of ``values`` (N, k) say the unit is wrong ('' if plausible)."""
    peak = np.max(np.abs(values), axis=0)
    if topic == names.TOPIC_INCLINOMETER and np.any(peak > limits.max_tilt_rad):
        return f'tilts up to {peak.max():.3g} "rad" are implausible: degrees instead of radians?'
    if topic == names.TOPIC_ENCODER and peak[0] > limits.max_phi_rad:
        return f'phi up to {peak[0]:.3g} "rad" is beyond one turn: degrees instead of radians?'
    if topic == names.TOPIC_LVDT and peak[0] > limits.max_lvdt_m:
        return f'd_m up to {peak[0]:.3g} "m" is implausible: millimetres instead of metres?'
    if topic == names.TOPIC_LEG_LENGTHS and peak.max() > limits.max_leg_stroke_m:
        return f'leg strokes up to {peak.max():.3g} "m" are implausible: millimetres instead of metres?'
    return ''


def topic_summary(received):
    """``{'count', 'rate_hz', 'delay_s' (median receive - stamp), 'noise_std' (per value)}``."""
    summary = {'count': len(received), 'rate_hz': 0.0, 'delay_s': math.nan, 'noise_std': []}
    if len(received) >= 2:
        span = received[-1].receive_s - received[0].receive_s
        summary['rate_hz'] = (len(received) - 1) / span if span > 0 else math.inf
    if received:
        summary['delay_s'] = float(np.median([r.receive_s - r.stamp_s for r in received]))
        widths = {len(r.values) for r in received}
        if len(widths) == 1 and len(received) >= 2:
            values = np.array([r.values for r in received], dtype=float)
            finite = np.all(np.isfinite(values), axis=1)
            if finite.sum() >= 2:
                summary['noise_std'] = np.std(values[finite], axis=0).tolist()
    return summary


def validate_topic(topic, received, limits=Limits()):
    """The problems of one sensor topic's messages (a list of sentences)."""
    expected = tuple(SENSOR_TOPICS[topic])
    if not received:
        return [f'{topic}: no message received']
    problems = []
    wrong = sorted({tuple(r.names) for r in received if tuple(r.names) != expected})
    if wrong:
        problems.append(
            f'{topic}: joint names {list(wrong[0])} (expected {list(expected)})'
            + (f' and {len(wrong) - 1} other name set(s)' if len(wrong) > 1 else '')
        )
    usable = [r for r in received if len(r.values) == len(expected)]
    if len(usable) < len(received):
        problems.append(
            f'{topic}: {len(received) - len(usable)} message(s) without {len(expected)} positions'
        )
    if usable:
        values = np.array([r.values for r in usable], dtype=float)
        bad = int(np.sum(~np.all(np.isfinite(values), axis=1)))
        if bad:
            problems.append(f'{topic}: {bad} message(s) with non-finite values (NaN or inf)')
        finite = values[np.all(np.isfinite(values), axis=1)]
        if len(finite):
            unit = _unit_problem(topic, finite, limits)
            if unit:
                problems.append(f'{topic}: {unit}')
            elif len(finite) >= 10:
                std = np.std(finite, axis=0)
                bound = (
                    limits.max_angle_noise_rad
                    if topic in (names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER)
                    else limits.max_length_noise_m
                )
                if np.any(std > bound):
                    problems.append(
                        f'{topic}: static noise std up to {std.max():.3g} exceeds {bound:g} '
                        '(was the platform still?)'
                    )
    summary = topic_summary(received)
    if summary['rate_hz'] < limits.min_rate_hz:
        problems.append(
            f'{topic}: {summary["rate_hz"]:.1f} Hz is below the {limits.min_rate_hz:g} Hz needed'
        )
    delay = summary['delay_s']
    if delay > limits.max_delay_s:
        problems.append(
            f'{topic}: stamps are {delay * 1e3:.1f} ms older than their receipt (median): stamp '
            'at the sample instant, and synchronise the clocks (chrony)'
        )
    elif delay < -limits.max_clock_lead_s:
        problems.append(
            f"{topic}: stamps are {-delay * 1e3:.1f} ms in the future (median): the publisher's "
            'clock is ahead; synchronise the clocks (chrony)'
        )
    return problems


def stamp_sharing(device_received):
    """Share (0..1) of inclinometer stamps also on the encoder and the LVDT topic."""
    stamps = {
        topic: {round(r.stamp_s * 1e9) for r in device_received.get(topic, ())}
        for topic in (names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER, names.TOPIC_LVDT)
    }
    inclinometer = stamps[names.TOPIC_INCLINOMETER]
    if not inclinometer:
        return 0.0
    shared = inclinometer & stamps[names.TOPIC_ENCODER] & stamps[names.TOPIC_LVDT]
    return len(shared) / len(inclinometer)


def validate_topics(received_by_topic, limits=Limits()):
    """Every problem of the recorded sensor topics ``{topic: [Received]}``."""
    problems = []
    for topic in SENSOR_TOPICS:
        problems += validate_topic(topic, received_by_topic.get(topic, []), limits)
    device = {t: received_by_topic.get(t, []) for t in SENSOR_TOPICS if t.startswith('/gsp/device')}
    if all(device.values()):
        share = stamp_sharing(device)
        if share < limits.min_shared_stamps:
            problems.append(
                f'device readings of one instant do not share one stamp: only {share:.0%} of '
                f'{names.TOPIC_INCLINOMETER} stamps are also on {names.TOPIC_ENCODER} and '
                f'{names.TOPIC_LVDT}'
            )
    return problems


def validate_diagnostics(reports, seen_for_s, grace_s):
    """The problems of the latest status of each name heard on ``/diagnostics``
    (``{name: Health}``): a node of :data:`names.DIAGNOSED_NODES` in the graph for at least
    ``grace_s`` (``seen_for_s``: ``{node name: s}``) without a status, and every status at ERROR
    or STALE."""
    topic = names.TOPIC_DIAGNOSTICS
    reported = {node_of_status(name) for name in reports}
    problems = [
        f'{topic}: {node} is running but published no status in {seen_for_s[node]:.1f} s'
        for node in _silent_nodes(reported, seen_for_s)
        if seen_for_s[node] >= grace_s
    ]
    problems += [
        f'{topic}: {name} is {LEVEL_NAMES[health.level]}: {health.message}'
        for name, health in sorted(reports.items())
        if health.level >= ERROR
    ]
    return problems


def _silent_nodes(reported, seen_for_s):
    return sorted(n for n in set(seen_for_s) & set(names.DIAGNOSED_NODES) if n not in reported)


def diagnostics_summary(reports, seen_for_s=None, grace_s=0.0):
    """One line per status heard: ``name: LEVEL message (n keys)``; then one per suite node
    without a status that appeared too recently (less than ``grace_s``) to be judged."""
    lines = [
        f'    {name}: {LEVEL_NAMES[health.level]} {health.message} ({len(health.values)} keys)'
        for name, health in sorted(reports.items())
    ]
    seen_for_s = seen_for_s or {}
    reported = {node_of_status(name) for name in reports}
    lines += [
        f'    {node}: no status yet, started {seen_for_s[node]:.1f} s ago (not judged)'
        for node in _silent_nodes(reported, seen_for_s)
        if seen_for_s[node] < grace_s
    ]
    return lines
