"""``collection_rate`` section of ``gsp_bench``: the sensor-message rate the calibrator's
collection sustains on one core (docs/figures.md, docs/architecture.md#synchronisation).

Postures of the calibrator's default settings (and of a 300-sample window) are collected as the
node collects them, in one thread and as fast as it goes: a command, the platform's ``moving``
and ``settled`` statuses, then the four sensor streams at 200 Hz (legs, inclinometer, encoder,
LVDT, each message serialised as on the wire, with the default noise and new device readings at
each posture) until the row is ready. The collection takes each message's CDR bytes as the node
does (``intake`` ``cdr``: read by ``collection.joint_state_cdr``; ``message``: deserialised by
rclpy into a ``JointState``, the intake before the node took its streams raw). While the platform moves, 0.2 s of
samples arrive before the settle. ``messages_per_s`` is the messages decoded and handled per
second of thread CPU time (median of ``repeats`` runs); ``load_factor`` is that rate over the
default load, four streams at 200 Hz (800 messages/s).
"""

import dataclasses
import statistics
import sys
import time

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from gsp_calibrator.collection import protocol, topics
from gsp_calibrator.collection.events import FINAL_EVENTS, RowReady
from gsp_calibrator.settings import CalibratorSettings
from gsp_kinematics.model.device import device_position
from gsp_msgs_py import conversions, names

#: How the collection takes a message's bytes: as the node does (the CDR bytes themselves).
INTAKE = 'cdr' if hasattr(topics, 'sensor_message') else 'message'
SENSOR_RATE_HZ = 200.0
STREAM_COUNT = 4
DEFAULT_LOAD_MSG_S = STREAM_COUNT * SENSOR_RATE_HZ
LARGE_WINDOW = 300
MOVING_S = 0.2  #: samples received while the platform moves, before its settled status
NS_PER_S = 1_000_000_000
T0_NS = 1_700_000_000 * NS_PER_S
#: Leg lengths (m) and device readings [alpha, beta, phi, d_m] (rad, m) around which the
#: postures lie.
LEGS_M = np.array([0.5, 0.51, 0.52, 0.53, 0.54, 0.55])
READINGS = np.array([0.01, -0.02, 0.3, 0.004])


def _stamp(ns):
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


def posture_messages(rng, first_ns, count, noise_std, offset):
    """``[(topic, CDR bytes, receive ns), ...]``: ``count`` instants of the four streams from
    ``first_ns`` at 200 Hz, the readings ``offset`` away from the base ones."""
    period_ns = int(NS_PER_S / SENSOR_RATE_HZ)
    messages = []
    for j in range(count):
        stamp_ns = first_ns + j * period_ns
        stamp = _stamp(stamp_ns)
        values = np.concatenate([LEGS_M, READINGS + offset]) + rng.normal(size=10) * noise_std
        alpha, beta, phi, d_m = values[6:]
        for topic, msg in (
            (names.TOPIC_LEG_LENGTHS, conversions.leg_lengths_to_msg(values[:6], stamp)),
            (names.TOPIC_INCLINOMETER, conversions.inclinometer_to_msg(alpha, beta, stamp)),
            (names.TOPIC_ENCODER, conversions.encoder_to_msg(phi, stamp)),
            (names.TOPIC_LVDT, conversions.lvdt_to_msg(d_m, stamp)),
        ):
            messages.append((topic, serialize_message(msg), stamp_ns + 1_000_000))
    return messages


def collect(pairs_per_posture, postures, seed=0, rows_out=None):
    """Collect ``postures`` postures of ``pairs_per_posture`` samples (see the module
    docstring); ``(messages handled, thread CPU s, rows)``. ``rows_out``: None or a list that
    gets each ``RowReady``."""
    settings = CalibratorSettings.from_values({'pairs_per_posture': pairs_per_posture})
    collection = protocol.CollectionProtocol.for_settings(settings)
    noise_std = np.asarray(settings.sigmas.channel_std(), dtype=float)
    rng = np.random.default_rng(seed)
    period_ns = int(NS_PER_S / SENSOR_RATE_HZ)
    moving = int(MOVING_S * SENSOR_RATE_HZ)
    # Enough instants for the rest look-back and the window (a few more for the pairs a
    # posture may drop).
    settled = int(settings.rest_lookback * SENSOR_RATE_HZ) + pairs_per_posture + 20
    plan, now_ns = [], T0_NS
    for k in range(postures):
        command_id = f'c{k}'
        offset = rng.uniform(-1.0, 1.0, size=4) * np.array([0.05, 0.05, 1.0, 0.01])
        before = posture_messages(rng, now_ns, moving, noise_std, -offset)
        settle_ns = now_ns + moving * period_ns
        after = posture_messages(rng, settle_ns, settled, noise_std, offset)
        # Commanded where the device measures it (the collection checks max_posture_error).
        alpha, beta, _, d_m = READINGS + offset
        nominal = settings.nominal
        position = device_position(
            alpha, beta, nominal.device_length + d_m, nominal.inclinometer_axes_angle
        )
        pose = np.concatenate([position, [0.0, 0.0, (READINGS + offset)[2]]])
        plan.append((k + 1, command_id, now_ns, settle_ns, before + after, pose))
        now_ns = settle_ns + settled * period_ns
    moving_status = conversions.parse_status(conversions.make_status('', names.STATE_MOVING, ''))
    handled, rows = 0, 0
    start = time.thread_time()
    for posture, command_id, command_ns, settle_ns, messages, pose in plan:
        collection.command(posture, pose, command_id, command_ns)
        collection.status(_with_id(moving_status, command_id), command_ns + 1_000_000)
        settled_status = _with_id(moving_status, command_id, names.STATE_SETTLED)
        settle_sent = False
        for topic, raw, receive_ns in messages:
            if not settle_sent and receive_ns > settle_ns:
                collection.status(settled_status, settle_ns, settle_ns)
                settle_sent = True
            msg = raw if INTAKE == 'cdr' else deserialize_message(raw, JointState)
            events = collection.sensor(topic, msg, receive_ns)
            handled += 1
            if any(isinstance(event, FINAL_EVENTS) for event in events):
                ready = [event for event in events if isinstance(event, RowReady)]
                rows += len(ready)
                if rows_out is not None:
                    rows_out.extend(ready)
                break
    return handled, time.thread_time() - start, rows


def _with_id(status, command_id, state=None):
    changes = {'command_id': command_id}
    if state is not None:
        changes['state'] = state
    return dataclasses.replace(status, **changes)


def measure(pairs_per_posture, postures, repeats):
    """The sustained rate of ``repeats`` runs: median messages/s and the runs' figures."""
    collect(pairs_per_posture, 2)  # warm-up: lazy imports (scipy.stats) of the first row
    runs = [collect(pairs_per_posture, postures, seed) for seed in range(repeats)]
    rates = [handled / seconds for handled, seconds, _ in runs]
    rate = statistics.median(rates)
    return {
        'pairs_per_posture': pairs_per_posture,
        'postures': postures,
        'rows': [rows for _, _, rows in runs],
        'messages': [handled for handled, _, _ in runs],
        'messages_per_s_runs': rates,
        'messages_per_s': rate,
        'load_factor': rate / DEFAULT_LOAD_MSG_S,
    }


def run(quick=False, log=None):
    """The section (see the module docstring)."""
    if log is None:

        def log(message):
            print(message, file=sys.stderr, flush=True)

    default_window = CalibratorSettings.from_values({}).pairs_per_posture
    repeats = 3 if quick else 5
    section = {
        'default_load_msg_s': DEFAULT_LOAD_MSG_S,
        'target_load_factor': 4.0,
        'intake': INTAKE,
    }
    for key, window, postures in (
        ('default_window', default_window, 20 if quick else 60),
        ('window_300', LARGE_WINDOW, 3 if quick else 6),
    ):
        log(f'gsp_bench: collection_rate: {window}-sample window, {repeats} runs ...')
        section[key] = measure(window, postures, repeats)
    return section


if __name__ == '__main__':
    import json

    print(json.dumps(run(quick='--quick' in sys.argv), indent=1))
