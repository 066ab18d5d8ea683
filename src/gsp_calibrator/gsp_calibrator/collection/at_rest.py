"""Is every channel at rest? The verdict on a span of synchronised pairs (pure, no rclpy).

The rule and its parameters are in :mod:`gsp_calibrator.collection.synchroniser` and
docs/sensor_errors.md; the test itself is
:func:`gsp_kinematics.sensors.noise_estimate.settle_test`.
"""

import bisect
import dataclasses
import math

import numpy as np

# The settle test takes scipy.stats, which imports lazily and slowly (about 6 s on a busy
# machine): loaded with the collection, at the calibrator's start, not by the first settle test
# in the sensor listener in the middle of a run's first posture.
import scipy.stats  # noqa: F401

from gsp_kinematics.channels import CHANNEL_NAMES
from gsp_kinematics.sensors.noise_estimate import settle_test

#: Fewest samples the settle test judges (a trend and a bend need some scatter left over).
MIN_SETTLE_SAMPLES = 4
#: Largest part of the look-back, at its start, that may hold no pair: a look-back whose start
#: lacks its pairs (messages lost, a device instant incomplete) is not yet covered.
MAX_UNCOVERED_FRACTION = 0.125


@dataclasses.dataclass(frozen=True)
class Unsettled:
    """Why the latest window judged is not used yet: the look-back is not yet covered
    (``pending``), or ``channel`` moved: its trend ``z`` stds over ``span`` s (``threshold``)."""

    pending: bool
    channel: str = ''
    z: float = 0.0
    threshold: float = 0.0
    span: float = 0.0

    def describe(self):
        if self.pending:
            return 'the settle look-back is not yet covered'
        return (
            f'{self.channel} still moving: trend {self.z:.3g} stds over the last '
            f'{self.span:.3g} s (at most {self.threshold:.3g})'
        )


def span_verdict(values, stamps_ns, sigmas, noise_std=None):
    """None if every channel of ``values`` (n, 10) (``phi`` unwrapped), stamped ``stamps_ns``
    (n,), is at rest (or the span is too short to judge), else :class:`Unsettled` naming the
    channel furthest beyond its threshold. ``noise_std`` (10,): the per-sample noise floor."""
    if len(stamps_ns) < MIN_SETTLE_SAMPLES:
        return None
    times = (np.asarray(stamps_ns, dtype=np.int64) - int(stamps_ns[0])) * 1e-9
    verdict = settle_test(values, times, sigmas, noise_std)
    if verdict.settled.all():
        return None
    worst = int(np.argmax(verdict.z / verdict.threshold))
    return Unsettled(
        False,
        CHANNEL_NAMES[worst],
        float(verdict.z[worst]),
        float(verdict.threshold[worst]),
        float(times[-1]),
    )


class SettleRule:
    """The settle rule of a collector: ``lookback`` (s, >= 0) and ``sigmas`` (> 0)."""

    def __init__(self, lookback, sigmas):
        lookback, sigmas = float(lookback), float(sigmas)
        if not (math.isfinite(lookback) and lookback >= 0.0):
            raise ValueError(f'settle_lookback must be a finite time >= 0 s, got {lookback}')
        if not sigmas > 0.0:
            raise ValueError(f'settle_sigmas must be > 0, got {sigmas}')
        self.lookback_ns = int(round(lookback * 1e9))
        self.sigmas = sigmas

    def verdict(self, pairs, end, start_ns, window, values_of, noise_std=None, pair_legs=None):
        """None if the channels are at rest over the look-back that ends with ``pairs[end]``
        (``(leg stamp, device stamp)`` ns; at least the ``window`` pairs ending there), else
        :class:`Unsettled`; pending until the look-back is covered by pairs stamped from
        ``start_ns``. ``values_of(pairs)``: their (n, 10) channel values (``phi`` unwrapped);
        ``noise_std`` (10,): the per-sample noise floor; ``pair_legs``: the leg stamps of
        ``pairs`` if the caller keeps them (else they are listed here)."""
        end_stamp = pairs[end][0]
        if end_stamp - start_ns < self.lookback_ns:
            return Unsettled(pending=True)
        if pair_legs is None:
            pair_legs = [leg for leg, _ in pairs]
        first = bisect.bisect_left(pair_legs, end_stamp - self.lookback_ns)
        # Judged over the pairs it holds, a look-back missing its start is a shorter one that
        # may miss a slow trend (seen under load: a listener that lost messages took a window
        # 0.007 rad before the inclinometer was at rest).
        uncovered = pair_legs[first] - (end_stamp - self.lookback_ns)
        if uncovered > MAX_UNCOVERED_FRACTION * self.lookback_ns:
            return Unsettled(pending=True)
        span = pairs[min(first, end - window + 1) : end + 1]
        return span_verdict(values_of(span), [leg for leg, _ in span], self.sigmas, noise_std)
