"""Is every channel at rest? The verdict on a span of synchronised pairs (pure, no rclpy).
See docs/sensor_errors.md."""

import bisect
import dataclasses
import math

import numpy as np

# The rest test takes scipy.stats, which imports lazily and slowly (about 6 s on a busy
# machine): loaded with the collection, at the calibrator's start, not by the first rest test
# in the sensor listener in the middle of a run's first posture.
import scipy.stats  # noqa: F401

from gsp_kinematics.channels import CHANNEL_NAMES
from gsp_kinematics.estimation.noise_estimate import rest_test, scatter_test

#: Fewest samples the rest test judges (a trend and a bend need some scatter left over).
MIN_SETTLE_SAMPLES = 4
#: Largest part of the look-back, at its start, that may hold no pair: a look-back whose start
#: lacks its pairs (messages lost, a device instant incomplete) is not yet covered.
MAX_UNCOVERED_FRACTION = 0.125


@dataclasses.dataclass(frozen=True)
class NotAtRest:
    """Why the latest window judged is not used yet: the look-back is not yet covered
    (``pending``), or ``channel`` moved: its trend ``z`` stds over ``span`` s (``threshold``),
    or (``scatter``) its std over the span ``z`` times its at-rest noise."""

    pending: bool
    channel: str = ''
    z: float = 0.0
    threshold: float = 0.0
    span: float = 0.0
    scatter: bool = False

    def describe(self):
        if self.pending:
            return 'the rest look-back is not yet covered'
        what = 'scatter {:.3g} times its noise std' if self.scatter else 'trend {:.3g} stds'
        return (
            f'{self.channel} still moving: {what.format(self.z)} over the last '
            f'{self.span:.3g} s (at most {self.threshold:.3g})'
        )


def span_verdict(values, stamps_ns, sigmas, noise_std=None):
    """None if every channel of ``values`` (n, 10) (``phi`` unwrapped), stamped ``stamps_ns``
    (n,), is at rest (or the span is too short to judge), else :class:`NotAtRest` naming the
    channel furthest beyond its threshold. ``noise_std`` (10,): the per-sample noise at rest;
    with it, a channel scattering more than that also moves (a platform still ringing)."""
    if len(stamps_ns) < MIN_SETTLE_SAMPLES:
        return None
    times = (np.asarray(stamps_ns, dtype=np.int64) - int(stamps_ns[0])) * 1e-9
    verdict = rest_test(values, times, sigmas, noise_std)
    if not verdict.settled.all():
        worst = int(np.argmax(verdict.z / verdict.threshold))
        z, threshold, scatter = verdict.z[worst], verdict.threshold[worst], False
    elif noise_std is not None:
        ratio, threshold = scatter_test(values, noise_std, sigmas)
        worst = int(np.argmax(ratio))
        if ratio[worst] <= threshold:
            return None
        z, scatter = ratio[worst], True
    else:
        return None
    return NotAtRest(
        False, CHANNEL_NAMES[worst], float(z), float(threshold), float(times[-1]), scatter
    )


class RestRule:
    """The rest rule of a collector: ``lookback`` (s, >= 0) and ``sigmas`` (> 0)."""

    def __init__(self, lookback, sigmas):
        lookback, sigmas = float(lookback), float(sigmas)
        if not (math.isfinite(lookback) and lookback >= 0.0):
            raise ValueError(f'rest_lookback must be a finite time >= 0 s, got {lookback}')
        if not sigmas > 0.0:
            raise ValueError(f'rest_sigmas must be > 0, got {sigmas}')
        self.lookback_ns = int(round(lookback * 1e9))
        self.sigmas = sigmas

    def judge(self, pairs, pair_legs, end, window, values_of, noise_std, slack_ns):
        """None if the channels are at rest over the look-back that ends with ``pairs[end]``
        (``(leg stamp, device stamp)`` ns from the settle on, ``pair_legs`` their leg stamps; at
        least the ``window`` pairs ending there), else :class:`NotAtRest`; pending until the
        look-back, less ``slack_ns``, is covered. ``values_of(pairs)``: their (n, 10) values
        (``phi`` unwrapped); ``noise_std`` (10,): the per-sample noise floor."""
        end_stamp = pairs[end][0]
        # Counted from the first pair, not from the settle: the same pairs cover it wherever
        # the stream starts after the settle (a replay restarts it at its first pair), and the
        # slack (the pairing tolerance) keeps a stamp's jitter from moving it by one pair.
        if end_stamp - pairs[0][0] < self.lookback_ns - slack_ns:
            return NotAtRest(pending=True)
        first = bisect.bisect_left(pair_legs, end_stamp - self.lookback_ns)
        # Judged over the pairs it holds, a look-back missing its start is a shorter one that
        # may miss a slow trend.
        uncovered = pair_legs[first] - (end_stamp - self.lookback_ns)
        if uncovered > MAX_UNCOVERED_FRACTION * self.lookback_ns:
            return NotAtRest(pending=True)
        span = pairs[min(first, end - window + 1) : end + 1]
        return span_verdict(values_of(span), [leg for leg, _ in span], self.sigmas, noise_std)
