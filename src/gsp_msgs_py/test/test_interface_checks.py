"""The conformance rules on synthetic recordings: each deliberate fault is named."""

import math

import numpy as np
import pytest

from gsp_msgs_py import names
from gsp_msgs_py.interfaces.rules import Received, stamp_sharing, topic_summary, validate_topics

RATE = 200.0
LEGS = np.array([0.1, 0.2, 0.3, 0.25, 0.15, 0.05])
DEVICE = {'alpha': 0.05, 'beta': -0.03, 'phi': 0.2, 'd_m': 0.3}


def recording(fault=None, count=100, seed=0):
    """``{topic: [Received]}`` of a conforming driver at 200 Hz, or with one ``fault``."""
    rng = np.random.default_rng(seed)
    topics = {
        t: []
        for t in (
            names.TOPIC_LEG_LENGTHS,
            names.TOPIC_INCLINOMETER,
            names.TOPIC_ENCODER,
            names.TOPIC_LVDT,
        )
    }
    angle = math.degrees(1.0) if fault == 'degrees' else 1.0
    length = 1000.0 if fault == 'mm' else 1.0
    for k in range(count):
        stamp = 100.0 + k / RATE
        receive = stamp + 0.001 + (2.0 if fault == 'late' else 0.0)
        legs = (LEGS + rng.normal(0, 1e-6, 6)) * length
        leg_names = list(names.LEG_JOINT_NAMES)
        if fault == 'joint_name':
            leg_names[5] = 'leg6'
        topics[names.TOPIC_LEG_LENGTHS].append(
            Received(receive, stamp, tuple(leg_names), tuple(legs))
        )
        noise = rng.normal(0, 1e-5, 4)
        shift = 0.001 if fault == 'stamps' else 0.0
        topics[names.TOPIC_INCLINOMETER].append(
            Received(
                receive,
                stamp,
                ('alpha', 'beta'),
                ((DEVICE['alpha'] + noise[0]) * angle, (DEVICE['beta'] + noise[1]) * angle),
            )
        )
        topics[names.TOPIC_ENCODER].append(
            Received(receive, stamp + shift, ('phi',), ((DEVICE['phi'] + noise[2]) * angle,))
        )
        d_m = math.nan if fault == 'nan' and k == 5 else DEVICE['d_m'] + 1e-6 * noise[3]
        topics[names.TOPIC_LVDT].append(Received(receive, stamp, ('d_m',), (d_m * length,)))
    return topics


def test_a_conforming_recording_has_no_problem():
    topics = recording()
    assert validate_topics(topics) == []
    summary = topic_summary(topics[names.TOPIC_LEG_LENGTHS])
    assert summary['rate_hz'] == pytest.approx(RATE) and summary['delay_s'] == pytest.approx(0.001)
    assert stamp_sharing(topics) == 1.0


@pytest.mark.parametrize(
    'fault, words',
    [
        ('degrees', ['/gsp/device/inclinometer', 'degrees instead of radians']),
        ('mm', ['/gsp/device/lvdt', 'millimetres instead of metres', '/gsp/platform/leg_lengths']),
        ('stamps', ['do not share one stamp', '0%']),
        ('joint_name', ["joint names ['leg_1', 'leg_2', 'leg_3', 'leg_4', 'leg_5', 'leg6']"]),
        ('nan', ['/gsp/device/lvdt: 1 message(s) with non-finite values']),
        ('late', ['2001.0 ms older than their receipt', 'chrony']),
    ],
)
def test_each_fault_is_named(fault, words):
    problems = '\n'.join(validate_topics(recording(fault)))
    for word in words:
        assert word in problems, problems


def test_a_missing_topic_and_a_low_rate_are_named():
    topics = recording()
    topics[names.TOPIC_ENCODER] = []
    topics[names.TOPIC_LVDT] = topics[names.TOPIC_LVDT][::10]  # 20 Hz
    problems = '\n'.join(validate_topics(topics))
    assert '/gsp/device/encoder: no message received' in problems
    assert '/gsp/device/lvdt: 20.0 Hz is below the 50 Hz needed' in problems


def test_diagnostics_problems_name_a_silent_suite_node_and_a_status_at_error():
    from gsp_msgs_py.health import ERROR, OK, WARN, Health
    from gsp_msgs_py.interfaces.rules import diagnostics_summary, validate_diagnostics

    reports = {
        'platform_sim: commands': Health(OK, 'no command yet', {'commands': '0'}),
        'calibrator: calibration': Health(WARN, 'silent for more than 2 s: /gsp/device/lvdt'),
        'platform_bridge: controller': Health(ERROR, 'stale /joint_states'),
    }
    # Seconds each node has been in the graph: the replay started too recently to be judged.
    seen = {'platform_sim': 5, 'device_driver': 3.0, 'calibrator': 5, 'replay': 0.5, 'rviz2': 5}
    problems = validate_diagnostics(reports, seen, 2.0)
    assert problems == [
        '/diagnostics: device_driver is running but published no status in 3.0 s',
        '/diagnostics: platform_bridge: controller is ERROR: stale /joint_states',
    ]
    lines = diagnostics_summary(reports, seen, 2.0)
    assert '    platform_sim: commands: OK no command yet (1 keys)' in lines
    assert any('calibrator: calibration: WARN silent' in line for line in lines)
    assert '    replay: no status yet, started 0.5 s ago (not judged)' in lines
    assert validate_diagnostics({}, {'rviz2': 9, 'controller_sim': 9}, 2.0) == []
