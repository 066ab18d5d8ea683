"""The row of a posture depends on its samples, not on the order the streams were handled in
(issue 26: under a backlog the calibrator and the rebuild of its recording averaged different
pairs)."""

import numpy as np

from gsp_calibrator.collection.events import RowReady
from gsp_calibrator.collection.protocol import CollectionProtocol
from gsp_calibrator.collection.synchroniser import ENCODER, INCLINOMETER, LEG_LENGTHS, LVDT
from gsp_msgs_py import conversions, names

MS = 1_000_000
S = 1000 * MS
T0 = 1_700_000_000 * S
Q = np.array([0.5, 0.51, 0.52, 0.53, 0.54, 0.55])
R = np.array([0.01, -0.02, 0.3, 0.004])
POSE = np.array([0.01, -0.01, 1.0, 0.01, -0.02, 0.03])
NOISE = [1e-6] * 6 + [1.7e-5, 1.7e-5, 1.7e-5, 1e-6]
START = T0 + 10 * MS


def stream_messages(rng, seconds=0.5):
    """Per stream, its samples in stamp order: ``{stream: [(stamp_ns, values), ...]}``. Leg
    lengths at 100 Hz on the 10 ms grid; the device at 200 Hz, 3 ms before and 2 ms after
    each leg stamp, so a leg stamp's nearest device instant (within the 4 ms tolerance) is the
    one after it: paired with the one before, it gives other readings."""
    streams = {LEG_LENGTHS: [], INCLINOMETER: [], ENCODER: [], LVDT: []}
    for k in range(1, int(seconds * 100)):
        leg = START + 10 * MS * k
        streams[LEG_LENGTHS].append((leg, (Q + rng.normal(size=6) * 1e-6,)))
        for offset in (-3 * MS, 2 * MS):
            r = R + rng.normal(size=4) * np.asarray(NOISE[6:])
            streams[INCLINOMETER].append((leg + offset, (r[0], r[1])))
            streams[ENCODER].append((leg + offset, (r[2],)))
            streams[LVDT].append((leg + offset, (r[3],)))
    return streams


def collect(streams, leads):
    """Feed ``streams`` to a settled posture, each stream handled ``leads[stream]`` ns ahead of
    its stamps (a stream the listener served first), ties in stream order; the row."""
    collection = CollectionProtocol(
        0.004, 5, NOISE, topic_timeout=1.0, settle_timeout=2.0, settle_lookback=0.05
    )
    collection.command(1, POSE, 'c1', T0)
    status = conversions.parse_status(conversions.make_status('c1', names.STATE_SETTLED, ''))
    collection.status(status, START)
    order = sorted(
        (stamp - leads.get(stream, 0), n, stream, stamp, values)
        for n, (stream, messages) in enumerate(streams.items())
        for stamp, values in messages
    )
    for handled, _, stream, stamp, values in order:
        for event in collection.sample(stream, stamp, values, max(handled, START)):
            if isinstance(event, RowReady):
                return event.sample
    raise AssertionError('no row')


def test_the_row_is_the_same_whichever_stream_is_handled_first():
    streams = stream_messages(np.random.default_rng(7))
    in_stamp_order = collect(streams, {})
    legs_first = collect(streams, {LEG_LENGTHS: 40 * MS})  # the device streams handled late
    device_first = collect(streams, {INCLINOMETER: 40 * MS, ENCODER: 40 * MS, LVDT: 40 * MS})
    for row in (legs_first, device_first):
        assert row.stamp_ns == in_stamp_order.stamp_ns
        # m and rad; the pairings differ by ~1e-5 rad
        np.testing.assert_allclose(row.leg_lengths, in_stamp_order.leg_lengths, rtol=0, atol=1e-12)
        np.testing.assert_allclose(row.readings, in_stamp_order.readings, rtol=0, atol=1e-12)
