"""The serial device's line gate: what the reader thread does with each line (pure, no port)."""

import collections
import threading

from gsp_msgs_py.health import ERROR, OK, WARN, Health

from .device_backend import DeviceSample
from .serial_protocol import (
    DROP_REASONS,
    PROTOCOL_VERSION,
    REQUEST_LINE,
    U32,
    DeviceClock,
    Hello,
    LineError,
    parse_line,
)

QUEUE_LENGTH = 2000  #: readings kept for the node (10 s at 200 Hz)
HELLO_REQUEST_INTERVAL_S = 0.5  #: while no valid hello: ask again this often
REFUSAL_WARNING_PERIOD_S = 10.0  #: a lasting refusal (no hello, units) is repeated this often
FIRST_DROPS_KEPT = 10
DROP_SUMMARY_PERIOD_S = 5.0  #: at most one summary of drops and lost lines per period
#: Backend-level drop reasons beyond the protocol's: the node did not drain the queue in time.
BACKEND_DROP_REASONS = (*DROP_REASONS, 'overflow')
COUNTER_NAMES = (
    *('lines', 'readings', 'published', 'hello', 'requests', 'connects', 'disconnects'),
    *('resets', 'lost', *BACKEND_DROP_REASONS),
)


class SerialLineGate:
    """Counters, hello and unit gate, seq tracking and the reading queue of one serial device."""

    def __init__(
        self,
        port,
        angle_unit,
        length_unit,
        trust_configured_units=False,
        latency=0.0,
        now=0.0,
        drop_summary_period=DROP_SUMMARY_PERIOD_S,
    ):
        self.port = port
        self.angle_unit, self.length_unit = angle_unit, length_unit
        self.trust_configured_units = bool(trust_configured_units)
        self.drop_summary_period = float(drop_summary_period)
        self.device_clock = DeviceClock(latency)
        self._lock = threading.Lock()
        self._queue = collections.deque()
        self._messages = collections.deque(maxlen=100)
        self.counters = dict.fromkeys(COUNTER_NAMES, 0)
        #: (reason, why, line) of the first FIRST_DROPS_KEPT dropped lines (gsp_serial_check)
        self.first_drops = []
        self._last_drop = ''  # reason and why of the last dropped line, for health()
        self.hello = None  #: the valid hello since the port was opened or the device reset
        self._last_hello = None  # (hello, clock time) of the last hello ever received
        self._connected = False
        self._last_seq = None
        self._unreadable = 0  # lines without a readable seq since the last seq (garbage, checksum)
        self._hello_since_reading = False
        self._waiting_since = 'the port was opened'
        self._warned_at = {}  # refusal reason -> clock time of its last warning
        self._summary = (now, self._drop_total())  # last drop summary: time, total
        self._health_snapshot = (now, dict(self.counters))  # the last report: time, counters

    def take_samples(self):
        """Every reading queued since the last call, stamped on the node's clock."""
        with self._lock:
            queued = list(self._queue)
            self._queue.clear()
            self.counters['published'] += len(queued)
        return [DeviceSample(stamp, r.alpha, r.beta, r.phi, r.d_m) for stamp, r in queued]

    def take_messages(self):
        """``[(level, text)]`` to log since the last call (``warning`` or ``info``)."""
        with self._lock:
            messages = list(self._messages)
            self._messages.clear()
        return messages

    def health(self, now):
        """The device path's :class:`~gsp_msgs_py.health.Health`; "since the last report" is
        since the previous call (the node calls it every ``diagnostics_period``); ``now``: s, monotonic. Keys and levels:
        docs/hardware.md section 2."""
        with self._lock:
            counters = dict(self.counters)
            hello, last_hello = self.hello, self._last_hello
            connected = self._connected
            refusal = self._refusal()
            last_drop = self._last_drop
        (then, before), self._health_snapshot = self._health_snapshot, (now, counters)
        new = {key: counters[key] - before[key] for key in counters}
        rate = new['lines'] / (now - then) if now > then else 0.0
        offset = self.device_clock.offset
        values = {
            **{
                key: counters[key]
                for key in ('lines', 'readings', 'hello', 'connects', 'disconnects')
            },
            'readings_published': counters['published'],
            **{f'dropped_{reason}': counters[reason] for reason in BACKEND_DROP_REASONS},
            'last_drop': last_drop,
            'lost_lines': counters['lost'],
            'resets': counters['resets'],
            'line_rate_hz': f'{rate:.1f}',
            'units': f'{self.angle_unit}/{self.length_unit}',
            'trust_configured_units': str(self.trust_configured_units).lower(),
            'last_hello': last_hello[0].text() if last_hello else '',
            'last_hello_age_s': f'{now - last_hello[1]:.1f}' if last_hello else '',
            'clock_offset_s': f'{offset:.6f}' if offset is not None else '',
        }
        dropped = sum(new[reason] for reason in BACKEND_DROP_REASONS)
        if not connected:
            return Health(ERROR, f'{self.port} is not open', values)
        if refusal in ('units', 'version'):
            return Health(
                ERROR,
                f'the device hello is refused ({refusal}): readings dropped; it says '
                f'{hello.text()}, serial.angle_unit/length_unit are '
                f'{self.angle_unit}/{self.length_unit}',
                values,
            )
        if refusal == 'no_hello':
            return Health(WARN, 'waiting for the device hello: readings dropped', values)
        if dropped or new['lost']:
            parts = [f'{dropped} line(s) dropped'] if dropped else []
            parts += [f'{new["lost"]} line(s) lost (seq gaps)'] if new['lost'] else []
            return Health(WARN, f'{" and ".join(parts)} since the last report', values)
        if new['lines'] == 0:
            return Health(WARN, f'no line from {self.port} since the last report', values)
        return Health(OK, f'{rate:.1f} lines/s', values)

    def say(self, level, text):
        with self._lock:
            self._messages.append((level, text))

    def count(self, key, n=1):
        with self._lock:
            self.counters[key] += n

    def connected(self):
        """The port is open: units are known again only from a hello received on it."""
        with self._lock:
            self.counters['connects'] += 1
            self._connected = True
            self.hello, self._hello_since_reading = None, False
            self._waiting_since = 'the port was opened'
        self.device_clock.reset()

    def disconnected(self):
        with self._lock:
            self._connected = False

    def garbage(self):
        """A run of bytes without a line end, too long to be a line."""
        self.count('lines')
        self.count('garbage')
        self._unreadable += 1

    def _drop_total(self):
        return sum(self.counters[k] for k in (*BACKEND_DROP_REASONS, 'lost'))

    def summarise_drops(self, now):
        """One warning per ``drop_summary_period`` while lines are dropped or lost."""
        then, total_then = self._summary
        if now - then < self.drop_summary_period:
            return
        with self._lock:
            counters = dict(self.counters)
            total = self._drop_total()
        self._summary = (now, total)
        if total > total_then:
            by_reason = ', '.join(
                f'{reason} {counters[reason]}'
                for reason in (*BACKEND_DROP_REASONS, 'lost')
                if counters[reason]
            )
            self.say(
                'warning',
                f'serial device on {self.port}: {total - total_then} lines dropped or lost in '
                f'the last {now - then:.1f} s (since start: {by_reason}; lines {counters["lines"]})',
            )

    def handle(self, line, now, stamp_now):
        """Take one protocol line received at ``now`` (s, monotonic), ``stamp_now`` (s, node's clock)."""
        try:
            parsed = parse_line(line, self.angle_unit, self.length_unit)
        except LineError as error:
            self.count('lines')
            if error.seq is None:  # garbage, checksum: its seq cannot be trusted
                self._unreadable += 1
            else:
                self._track_seq(error.seq)
            with self._lock:
                refusal = self._refusal()
            # Values out of range in units the hello refused: the units are the cause.
            if refusal and error.reason == 'range':
                self._drop(refusal, f'{error} (units refused: {self._refusal_text(refusal)})', line)
                self._warn_refusal(refusal, now)
            else:
                self._drop(error.reason, str(error), line)
            return
        if parsed is None:  # an empty line: ignored (docs/hardware.md)
            return
        self.count('lines')
        if isinstance(parsed, Hello):
            self._on_hello(parsed, now)
            return
        self._track_seq(parsed.seq)
        with self._lock:
            refusal = self._refusal()
        if refusal:
            self._drop(refusal, 'no valid hello for these units', line)
            self._warn_refusal(refusal, now)
            return
        stamp = self.device_clock.stamp(parsed.device_time_us, stamp_now)
        with self._lock:
            self.counters['readings'] += 1
            if len(self._queue) >= QUEUE_LENGTH:  # the node is not draining: oldest goes
                self._queue.popleft()
                self.counters['overflow'] += 1
            self._queue.append((stamp, parsed))

    def _drop(self, reason, why, line):
        with self._lock:
            self.counters[reason] += 1
            self._last_drop = f'{reason}: {why}'
            if len(self.first_drops) < FIRST_DROPS_KEPT:
                self.first_drops.append((reason, why, line[:80]))

    def _track_seq(self, seq):
        """Count the lines a seq gap lost, and take a seq that does not advance for a reset."""
        self._hello_since_reading, hello_fresh = False, self._hello_since_reading
        last, unreadable = self._last_seq, self._unreadable
        self._last_seq, self._unreadable = seq, 0
        if last is None:
            return
        gap = (seq - last) % U32
        if 0 < gap < U32 // 2:
            # Lines whose seq could not be read (garbage, checksum) are counted as drops already.
            self.count('lost', max(0, gap - 1 - unreadable))
            return
        self.device_clock.reset()
        with self._lock:
            self.counters['resets'] += 1
            if not hello_fresh:  # a hello sent after the restart, before this line, stands
                self.hello = None
                self._waiting_since = f'it restarted (seq {last} -> {seq})'
        self.say(
            'warning',
            f'device on {self.port} restarted (seq {last} -> {seq})'
            + ('' if hello_fresh else ': readings dropped until its next hello'),
        )

    def _refusal(self):
        """'' if the readings are usable now, else the drop reason (call with the lock)."""
        hello = self.hello
        if hello is None:
            return '' if self.trust_configured_units else 'no_hello'
        if hello.version != PROTOCOL_VERSION:
            return 'version'
        if (hello.angle_unit, hello.length_unit) != (self.angle_unit, self.length_unit):
            return 'units'
        return ''

    def _refusal_text(self, reason):
        hello = self.hello
        parameters = (
            f'serial.angle_unit/serial.length_unit are {self.angle_unit}/{self.length_unit}'
        )
        if reason == 'no_hello':
            return (
                f'no hello line from the device on {self.port} since {self._waiting_since}: its '
                f'readings are dropped until one comes (asked with {REQUEST_LINE.decode().strip()} '
                f'every {HELLO_REQUEST_INTERVAL_S:g} s); set serial.trust_configured_units to '
                f'publish them in {self.angle_unit}/{self.length_unit} without one'
            )
        if reason == 'version':
            return (
                f'device {hello.device_id!r} speaks protocol version {hello.version}, this '
                f'driver version {PROTOCOL_VERSION}: its readings are dropped'
            )
        known = '' if hello.units_known else ' (unknown unit)'
        return (
            f'device {hello.device_id!r} sends {hello.angle_unit}/{hello.length_unit}{known} but '
            f'{parameters}: its readings are dropped until they match'
        )

    def _warn_refusal(self, reason, now):
        """The refusal's warning: at once, then every REFUSAL_WARNING_PERIOD_S while it lasts."""
        last = self._warned_at.get(reason)
        if last is None or now - last >= REFUSAL_WARNING_PERIOD_S:
            self._warned_at[reason] = now
            with self._lock:
                dropped = self.counters[reason]
            self.say('warning', f'{self._refusal_text(reason)} ({dropped} dropped so far)')

    def _on_hello(self, hello, now):
        with self._lock:
            self.counters['hello'] += 1
            changed = self.hello != hello
            self.hello, self._last_hello = hello, (hello, now)
            self._hello_since_reading = True
            refusal = self._refusal()
        if not changed:
            return
        self._warned_at.clear()  # a new refusal is told at once
        if refusal:
            self.say('warning', self._refusal_text(refusal))
            self._warned_at[refusal] = now
        else:
            self.say('info', f'device {hello.text()} on {self.port}')
