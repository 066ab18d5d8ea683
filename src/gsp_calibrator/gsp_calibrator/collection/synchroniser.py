"""Stamp-matching synchroniser of leg-length and device samples (pure, no rclpy).
See docs/sensor_errors.md."""

import bisect
import dataclasses
import math

import numpy as np

from gsp_calibrator.collection import at_rest
from gsp_calibrator.collection.pairing import StampPairing, nearest_pairs
from gsp_kinematics import channels
from gsp_kinematics.estimation.noise_estimate import DEFAULT_REST_SIGMAS
from gsp_kinematics.estimation.noise_from_data import posture_lag_sums
from gsp_kinematics.rotation import wrap_angle

NS_PER_S = 1_000_000_000

#: Stream names (the sensors of the channel table), as counted in ``non_finite``.
LEG_LENGTHS, INCLINOMETER, ENCODER, LVDT = channels.SENSORS

#: Robust standard deviations a value may lie from its window's median (see the module docstring).
DEFAULT_CONSISTENCY_THRESHOLD = 10.0
_LEGS = channels.LEG_COUNT
_CHANNELS = channels.CHANNEL_COUNT
_READINGS = len(channels.DEVICE_CHANNELS)
_FIRST_READING = channels.FIRST_READING_COLUMN
#: phi: compared and averaged on the circle (among the ten channels, among the readings).
(_PHI_CHANNEL,) = channels.CIRCULAR_COLUMNS
_PHI_READING = channels.PHI_READING_COLUMN
#: Verdicts of a candidate window (:meth:`SampleCollector.window`); pending: its settle
#: look-back is not yet covered.
_USABLE, _INCONSISTENT, _UNSETTLED, _PENDING = 'usable', 'inconsistent', 'unsettled', 'pending'
_SETTLE_VERDICT = {False: _UNSETTLED, True: _PENDING}  # by ``NotAtRest.pending``


def seconds_to_ns(seconds):
    """Integer nanoseconds of a time in seconds."""
    return int(round(float(seconds) * NS_PER_S))


@dataclasses.dataclass(frozen=True)
class PostureRow:
    """One averaged posture row: ``n_samples`` synchronised pairs, SI units."""

    leg_lengths: np.ndarray  #: (6,) mean q_i, m
    readings: np.ndarray  #: (4,) mean [alpha, beta, phi, d_m], rad and m
    n_samples: int  #: number of pairs averaged
    stamp_ns: int  #: mean stamp of the averaged leg-length samples, ns
    leg_lengths_std: np.ndarray  #: (6,) sample standard deviation of q_i, m
    readings_std: np.ndarray  #: (4,) sample standard deviation of the readings
    rest_wait: float = 0.0  #: s from the collection start to the first averaged sample
    moving_pairs: int = 0  #: pairs before the window waited out as still moving
    #: (4, n // 2 + 1) the window's lag sums per noise channel (the within-posture noise
    #: estimate, ``gsp_kinematics.estimation.noise_from_data.posture_lag_sums``); None below 2 samples
    lag_sums: np.ndarray | None = None

    @property
    def stamp(self):
        """Mean stamp in seconds."""
        return self.stamp_ns / NS_PER_S


def unwrap_phi(values):
    """``values`` (n, 10) with ``phi`` unwrapped around its first value (a copy)."""
    values = np.array(values, dtype=float)
    values[:, _PHI_CHANNEL] = values[0, _PHI_CHANNEL] + wrap_angle(
        values[:, _PHI_CHANNEL] - values[0, _PHI_CHANNEL]
    )
    return values


def median_and_spread(values, noise_std):
    """Median (10,), absolute deviations (n, 10) and robust spread (10,) of the ``(n, 10)``
    channel values (``phi`` unwrapped around the first); the spread is at least ``noise_std``."""
    values = unwrap_phi(values)
    median = np.median(values, axis=0)
    deviation = np.abs(values - median)
    spread = np.maximum(1.4826 * np.median(deviation, axis=0), noise_std)
    return median, deviation, spread


def average_row(legs, readings, stamps):
    """The :class:`PostureRow` of ``legs`` (n, 6) m, ``readings`` (n, 4) and their leg
    stamps (n,) ns: means, sample stds and lag sums; ``phi`` averaged on the circle."""
    readings = np.array(readings, dtype=float)
    phi0 = readings[0, _PHI_READING]
    readings[:, _PHI_READING] = phi0 + wrap_angle(readings[:, _PHI_READING] - phi0)
    mean_readings = readings.mean(axis=0)
    mean_readings[_PHI_READING] = float(wrap_angle(mean_readings[_PHI_READING]))
    ddof = 1 if len(legs) > 1 else 0
    mean_stamp = int(stamps[0] + int(round(float(np.mean(stamps - stamps[0])))))
    return PostureRow(
        leg_lengths=legs.mean(axis=0),
        readings=mean_readings,
        n_samples=len(legs),
        stamp_ns=mean_stamp,
        leg_lengths_std=legs.std(axis=0, ddof=ddof),
        readings_std=readings.std(axis=0, ddof=ddof),
        lag_sums=posture_lag_sums(np.hstack([legs, readings])) if len(legs) > 1 else None,
    )


def _checked_options(sync_tolerance, pairs_per_posture, max_buffer, noise_std, threshold):
    """``(sync_tolerance, noise_std)`` of a :class:`SampleCollector`; ValueError if invalid."""
    sync_tolerance = float(sync_tolerance)
    if not (math.isfinite(sync_tolerance) and sync_tolerance >= 0.0):
        raise ValueError(f'sync_tolerance must be a finite time >= 0 s, got {sync_tolerance}')
    if int(pairs_per_posture) < 1:
        raise ValueError(f'pairs_per_posture must be >= 1, got {pairs_per_posture}')
    if max_buffer is not None and int(max_buffer) < int(pairs_per_posture):
        raise ValueError('max_buffer must hold at least pairs_per_posture samples')
    if noise_std is not None:
        noise_std = np.asarray(noise_std, dtype=float).reshape(_CHANNELS)
        if not np.all(np.isfinite(noise_std) & (noise_std > 0.0)):
            raise ValueError(f'noise_std must be 10 positive values, got {noise_std}')
    if not float(threshold) > 0.0:
        raise ValueError(f'consistency_threshold must be > 0, got {threshold}')
    return sync_tolerance, noise_std


class SampleCollector:
    """Buffers both streams, pairs them by nearest stamp and finds the window to average
    (docs/architecture.md#synchronisation). ``max_buffer``: samples kept per stream (None: all);
    ``noise_std`` (10,) m, rad: the floor of the robust spread and of the rest test's noise
    (None: no consistency check)."""

    def __init__(
        self,
        sync_tolerance,
        pairs_per_posture,
        max_buffer=2000,
        noise_std=None,
        consistency_threshold=DEFAULT_CONSISTENCY_THRESHOLD,
        rest_lookback=0.0,
        rest_sigmas=DEFAULT_REST_SIGMAS,
    ):
        sync_tolerance, noise_std = _checked_options(
            sync_tolerance, pairs_per_posture, max_buffer, noise_std, consistency_threshold
        )
        self.rest_rule = at_rest.RestRule(rest_lookback, rest_sigmas)
        self.not_at_rest = None  #: why the latest window judged waits (``NotAtRest``), or None
        self.noise_std = noise_std
        self.consistency_threshold = float(consistency_threshold)
        self._pairing = StampPairing(seconds_to_ns(sync_tolerance))
        self.pairs_per_posture = int(pairs_per_posture)
        self.max_buffer = None if max_buffer is None else int(max_buffer)
        self.start_ns = None  # None: not collecting, every sample is ignored
        self.previous_readings = None  # device readings (4,) of the previous posture
        self._legs = {}  # stamp_ns -> q (6,)
        self._device = {}  # stamp_ns -> readings (4,), NaN where not received yet
        self._device_stamps = []  # sorted keys of _device
        self._window_checks = {}  # tuple(window pairs) -> _USABLE, _INCONSISTENT or _UNSETTLED
        self._verdicts = []  # of the windows starting at pairs 0, 1, ..., none usable
        self._window_start = None  # start of the usable window, or None
        self._window_revision = None  # pairing revision of _verdicts and _window_start
        self.horizon_ns = None  # ns, or None (set_horizon)
        self.non_finite = dict.fromkeys(channels.SENSORS, 0)  #: readings dropped, per stream
        self.inconsistent = 0  #: pairs dropped, inconsistent with the window averaged after them
        self.settling_dropped = 0  #: pairs dropped while the readings settled (the rest waits)

    def start(self, start_ns, previous_readings=None):
        """Begin a new posture: forget buffered samples, keep only stamps >= ``start_ns``;
        ``previous_readings``: the previous posture's ``[alpha, beta, phi, d_m]``, if any."""
        self.start_ns = int(start_ns)
        if previous_readings is not None:
            previous_readings = np.asarray(previous_readings, dtype=float).reshape(_READINGS)
        self.previous_readings = previous_readings
        self._clear()
        self.not_at_rest = None

    def dropped(self):
        """The samples dropped so far: ``{inconsistent_dropped, settling_dropped,
        non_finite_dropped: {stream: count}}``."""
        return {
            'inconsistent_dropped': int(self.inconsistent),
            'settling_dropped': int(self.settling_dropped),
            'non_finite_dropped': {stream: int(n) for stream, n in self.non_finite.items()},
        }

    def stop(self):
        """Stop collecting: ignore samples until the next :meth:`start`."""
        self.start_ns = None
        self.previous_readings = None
        self._clear()

    def _clear(self):
        self._legs.clear()
        self._device.clear()
        self._device_stamps.clear()
        self._window_checks.clear()
        self._pairing.clear()
        self._verdicts.clear()
        self._window_revision = None
        self.horizon_ns = None

    def set_horizon(self, horizon_ns):
        """Judge only windows whose pairs are final once every stream has delivered its samples
        stamped up to ``horizon_ns`` (None: every window, as the pairs stand)."""
        horizon_ns = None if horizon_ns is None else int(horizon_ns)
        if horizon_ns != self.horizon_ns:
            self.horizon_ns, self._window_revision = horizon_ns, None

    @property
    def tolerance_ns(self):
        """Largest stamp difference (ns) of a pair."""
        return self._pairing.tolerance_ns

    @property
    def pair_revision(self):  # changes whenever the pairs change
        return self._pairing.revision

    def record_non_finite(self, stream):
        """Count a non-finite reading the caller has already dropped (e.g. at message parsing)."""
        self.non_finite[stream] += 1

    def _accept(self, stream, stamp_ns, values):
        if not np.all(np.isfinite(values)):
            self.non_finite[stream] += 1
            return False
        return self.start_ns is not None and stamp_ns >= self.start_ns

    def add_leg_lengths(self, stamp_ns, leg_lengths):
        """Add a leg-length sample ``q`` (6, m). Returns False if dropped."""
        leg_lengths = np.asarray(leg_lengths, dtype=float).reshape(_LEGS)
        stamp_ns = int(stamp_ns)
        if not self._accept(LEG_LENGTHS, stamp_ns, leg_lengths):
            return False
        if stamp_ns not in self._legs:
            self._pairing.add_leg(stamp_ns)
        self._legs[stamp_ns] = leg_lengths.copy()
        while self.max_buffer is not None and len(self._legs) > self.max_buffer:
            oldest = self._pairing.legs[0]
            self._pairing.remove_leg(oldest)
            del self._legs[oldest]
        return True

    def _add_device(self, stream, stamp_ns, values):
        values = np.asarray(values, dtype=float).reshape(-1)
        stamp_ns = int(stamp_ns)
        if not self._accept(stream, stamp_ns, values):
            return False
        row = self._device.get(stamp_ns)
        if row is None:
            row = np.full(_READINGS, np.nan)
            self._device[stamp_ns] = row
            self._device_stamps.insert(bisect.bisect_left(self._device_stamps, stamp_ns), stamp_ns)
            while self.max_buffer is not None and len(self._device) > self.max_buffer:
                oldest = self._device_stamps.pop(0)
                if np.all(np.isfinite(self._device.pop(oldest))):
                    self._pairing.remove_device(oldest)
        complete = np.all(np.isfinite(row))
        row[list(channels.DEVICE_READING_COLUMNS[stream])] = values
        if not complete and stamp_ns in self._device and np.all(np.isfinite(row)):
            self._pairing.add_device(stamp_ns)
        return True

    def add_inclinometer(self, stamp_ns, alpha, beta):
        """Add an inclinometer sample ``alpha, beta`` (rad). Returns False if dropped."""
        return self._add_device(INCLINOMETER, stamp_ns, [alpha, beta])

    def add_encoder(self, stamp_ns, phi):
        """Add an encoder sample ``phi`` (rad). Returns False if dropped."""
        return self._add_device(ENCODER, stamp_ns, [phi])

    def add_lvdt(self, stamp_ns, d_m):
        """Add an LVDT sample ``d_m`` (m). Returns False if dropped."""
        return self._add_device(LVDT, stamp_ns, [d_m])

    def pair_count(self):
        return len(self._pairing.pairs)

    def _arrays(self, pairs):
        """``(leg stamps (n,) ns, q (n, 6) m, readings (n, 4))`` of ``pairs``."""
        return (
            np.array([leg for leg, _ in pairs], dtype=np.int64),
            np.array([self._legs[leg] for leg, _ in pairs]).reshape(-1, _LEGS),
            np.array([self._device[dev] for _, dev in pairs]).reshape(-1, _READINGS),
        )

    def _values(self, pairs):
        """(n, 10) ``[q_1..q_6, alpha, beta, phi, d_m]`` of ``pairs``."""
        return np.hstack(self._arrays(pairs)[1:])

    def _median_and_spread(self, pairs):
        return median_and_spread(self._values(pairs), self.noise_std)

    def consistent(self, pairs):
        """Whether every value of ``pairs`` lies within the threshold of their median."""
        if self.noise_std is None or len(pairs) < 3:
            return True
        _, deviation, spread = self._median_and_spread(pairs)
        return bool(np.all(deviation <= self.consistency_threshold * spread))

    def unchanged(self, pairs):
        """Whether the device readings of ``pairs`` still equal the previous posture's."""
        if self.noise_std is None or self.previous_readings is None or not pairs:
            return False
        median, _, spread = self._median_and_spread(pairs)
        difference = median[_FIRST_READING:] - self.previous_readings
        difference[_PHI_READING] = wrap_angle(difference[_PHI_READING])
        threshold = self.consistency_threshold * spread[_FIRST_READING:]
        return bool(np.all(np.abs(difference) <= threshold))

    def window(self):
        """The pairs to average: the earliest run of ``pairs_per_posture`` consecutive pairs
        that is consistent, changed from the previous posture and settled, or None if there is
        none yet (:attr:`not_at_rest` then says why the latest run judged waits, if it does)."""
        start = self._window_start_now()
        count = self.pairs_per_posture
        return None if start is None else self._pairing.pairs[start : start + count]

    def _window_start_now(self):
        """Index of the first pair of :meth:`window`, or None. A window's verdict holds until
        one of its pairs changes (``StampPairing.take_changed``)."""
        pairing = self._pairing
        if self._window_revision == pairing.revision:
            return self._window_start
        count = self.pairs_per_posture
        changed = pairing.take_changed()
        if changed is not None:  # the windows holding a changed pair are judged again
            del self._verdicts[max(0, changed - count + 1) :]
        pairs = pairing.pairs
        self._window_start = None
        start = len(self._verdicts)
        horizon = math.inf if self.horizon_ns is None else self.horizon_ns - self.tolerance_ns
        while start + count <= len(pairs) and pairs[start + count - 1][0] <= horizon:
            verdict = self._verdict(pairs, start)
            if verdict == _USABLE:
                self._window_start = start
                break
            self._verdicts.append(verdict)
            start += 1
        self._window_revision = pairing.revision
        return self._window_start

    def _verdict(self, pairs, start):
        """The verdict of the window of ``pairs`` starting at ``start`` (judged once)."""
        count = self.pairs_per_posture
        candidate = pairs[start : start + count]
        key = tuple(candidate)
        verdict = self._window_checks.get(key)
        if verdict is None:
            verdict = _INCONSISTENT
            if self.consistent(candidate) and not self.unchanged(candidate):
                self.not_at_rest = self.rest_rule.judge(
                    pairs,
                    self._pairing.pair_legs,
                    start + count - 1,
                    count,
                    lambda span: unwrap_phi(self._values(span)),
                    self.noise_std,
                    self.tolerance_ns,
                )
                unsettled = self.not_at_rest
                verdict = _USABLE if unsettled is None else _SETTLE_VERDICT[unsettled.pending]
            # (A window ending before the look-back is covered never will be.)
            self._window_checks[key] = verdict
        return verdict

    def ready(self):
        """True once ``pairs_per_posture`` consistent pairs are available."""
        return self.pair_count() >= self.pairs_per_posture and self.window() is not None

    def counts(self):
        """Buffered samples per stream since the start time (device: complete instants)."""
        return {
            LEG_LENGTHS: len(self._legs),
            'device': len(self._pairing.devices),
            'pairs': self.pair_count(),
            'consistent': self.window() is not None if self.pair_count() else False,
        }

    def take_posture(self):
        """Average the consistent window and stop collecting; ValueError if not ready."""
        window = self.window() if self.pair_count() >= self.pairs_per_posture else None
        if window is None:
            raise ValueError(
                f'only {self.pair_count()} synchronised samples, no {self.pairs_per_posture} '
                'consistent ones'
            )
        verdicts = self._verdicts[: self._window_start]
        unsettled, inconsistent = verdicts.count(_UNSETTLED), verdicts.count(_INCONSISTENT)
        self.settling_dropped += len(verdicts) - inconsistent  # moving or look-back pending
        self.inconsistent += inconsistent
        stamps, legs, readings = self._arrays(window)
        sample = dataclasses.replace(
            average_row(legs, readings, stamps),
            rest_wait=(window[0][0] - self.start_ns) * 1e-9,
            moving_pairs=int(unsettled),
        )
        self.stop()
        return sample


def segment_pairs(collector, limit=None, last=False):
    """Every pair of ``collector`` (a :class:`SampleCollector`) of its first (``last``: the
    last) ``limit`` leg-length samples, as it pairs them: ``(leg stamps (N,) ns, q (N, 6) m,
    readings (N, 4))`` in stamp order."""
    legs = sorted(collector._legs)
    if limit is not None:
        legs = legs[-int(limit) :] if last else legs[: int(limit)]
    if not legs:
        return collector._arrays([])
    margin = collector.tolerance_ns
    devices = [
        stamp
        for stamp in collector._pairing.devices
        if legs[0] - margin <= stamp <= legs[-1] + margin
    ]
    return collector._arrays(nearest_pairs(legs, devices, margin))
