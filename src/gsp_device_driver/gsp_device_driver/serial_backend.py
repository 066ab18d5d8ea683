"""The ``serial`` device backend: the measuring device on a serial line (pyserial, no rclpy).

A reader thread opens ``port``, asks for the device's hello (``$GSPQ,HELLO``), reads protocol
lines (:mod:`.serial_protocol`), drops bad ones and the readings no valid hello vouches for
(counted by reason, with seq gaps as lost lines, in :attr:`SerialDeviceBackend.counters` and
:meth:`~SerialDeviceBackend.health`), and queues the good ones stamped by
:class:`~.serial_protocol.DeviceClock` on the node's clock. The node drains the queue with
:meth:`read_available`. When the port fails (unplugged) or is absent, the thread reports it once
and retries every ``reconnect_interval`` until the device is back; nothing is raised to the node.
"""

import collections
import threading
import time

from gsp_msgs_py.health import ERROR, OK, WARN, Health

from .device_backend import BackendError, DeviceBackend, DeviceSample
from .serial_protocol import (
    ANGLE_UNITS,
    DROP_REASONS,
    LENGTH_UNITS,
    PROTOCOL_VERSION,
    REQUEST_LINE,
    U32,
    DeviceClock,
    Hello,
    LineError,
    parse_line,
)

QUEUE_LENGTH = 2000  #: readings kept for the node (10 s at 200 Hz)
MAX_PENDING_BYTES = 1024  #: a longer run without a line end is dropped as garbage
HELLO_REQUEST_INTERVAL_S = 0.5  #: while no valid hello: ask again this often
REFUSAL_WARNING_PERIOD_S = 10.0  #: a lasting refusal (no hello, units) is repeated this often
FIRST_DROPS_KEPT = 10
DROP_SUMMARY_PERIOD_S = 5.0  #: at most one summary of drops and lost lines per period
#: Backend-level drop reasons beyond the protocol's: the node did not drain the queue in time.
BACKEND_DROP_REASONS = (*DROP_REASONS, 'overflow')


def _specs():
    from gsp_msgs_py.node_tools import ParameterSpec, at_least, greater_than, not_blank, one_of

    return (
        ParameterSpec(
            'port', '/dev/ttyACM0', 'Serial port of the device', check=not_blank('a port')
        ),
        ParameterSpec('baud', 115200, 'Baud rate', integer_range=(1, 10_000_000)),
        ParameterSpec(
            'timeout',
            0.1,
            'Read timeout of the port; bounds how fast a stop or silence is noticed',
            unit='s',
            check=greater_than(0.0, 's'),
        ),
        ParameterSpec(
            'angle_unit',
            'rad',
            f'Unit of alpha, beta, phi on the line: one of {", ".join(ANGLE_UNITS)}',
            check=one_of(ANGLE_UNITS),
        ),
        ParameterSpec(
            'length_unit',
            'm',
            f'Unit of d on the line: one of {", ".join(LENGTH_UNITS)}',
            check=one_of(LENGTH_UNITS),
        ),
        ParameterSpec(
            'trust_configured_units',
            False,
            'Publish readings in angle_unit/length_unit before the device has sent a hello line '
            '(default: dropped until a hello confirms the units; a hello that disagrees still '
            'drops them)',
        ),
        ParameterSpec(
            'latency',
            0.0,
            'Fixed delay from the instant a line reports to its arrival beyond the least '
            'transmission delay; subtracted from every stamp',
            unit='s',
            check=at_least(0.0, 's'),
        ),
        ParameterSpec(
            'reconnect_interval',
            0.5,
            'Wait between attempts to (re)open the port',
            unit='s',
            check=greater_than(0.0, 's'),
        ),
        ParameterSpec(
            'silence_warning',
            0.5,
            'Warn when an open port delivers no line for this long',
            unit='s',
            check=greater_than(0.0, 's'),
        ),
    )


class SerialDeviceBackend(DeviceBackend):
    """Readings from a device speaking the serial protocol on ``port``.

    ``clock`` (s, monotonic) times silences, warnings and :meth:`health`; ``stamp_clock`` (s, the
    node's clock; default ``clock``) is read by the reader thread when a line arrives, and the
    stamps are on it. Start the reader with :meth:`start` (done by :meth:`from_config`).
    """

    name = 'serial'

    def __init__(
        self,
        port,
        baud=115200,
        timeout=0.1,
        angle_unit='rad',
        length_unit='m',
        trust_configured_units=False,
        latency=0.0,
        reconnect_interval=0.5,
        silence_warning=0.5,
        clock=time.monotonic,
        stamp_clock=None,
        serial_factory=None,
        drop_summary_period=DROP_SUMMARY_PERIOD_S,
    ):
        if angle_unit not in ANGLE_UNITS or length_unit not in LENGTH_UNITS:
            raise BackendError(f'unknown units {angle_unit!r}, {length_unit!r}')
        self.port = str(port)
        self.baud = int(baud)
        self.timeout = float(timeout)
        self.angle_unit, self.length_unit = angle_unit, length_unit
        self.trust_configured_units = bool(trust_configured_units)
        self.reconnect_interval = float(reconnect_interval)
        self.silence_warning = float(silence_warning)
        self.drop_summary_period = float(drop_summary_period)
        self.device_clock = DeviceClock(latency)
        self._clock = clock
        self._stamp_clock = stamp_clock if stamp_clock is not None else clock
        self._serial_factory = serial_factory
        self._lock = threading.Lock()
        self._queue = collections.deque()
        self._messages = collections.deque(maxlen=100)
        self.counters = dict.fromkeys(
            (
                'lines',
                'readings',
                'published',
                'hello',
                'requests',
                'connects',
                'disconnects',
                'resets',
                'lost',
                *BACKEND_DROP_REASONS,
            ),
            0,
        )
        #: (reason, why, line) of the first FIRST_DROPS_KEPT dropped lines (gsp_serial_check)
        self.first_drops = []
        self._last_drop = ''  # reason and why of the last dropped line, for health()
        self.hello = None  #: the valid hello since the port was opened or the device reset
        self._last_hello = None  # (hello, clock time) of the last hello ever received
        self._connected = False
        self._silent = False
        self._last_seq = None
        self._unreadable = 0  # lines without a readable seq since the last seq (garbage, checksum)
        self._hello_since_reading = False
        self._waiting_since = 'the port was opened'
        self._warned_at = {}  # refusal reason -> clock time of its last warning
        self._summary = (clock(), self._drop_total())  # last drop summary: time, total
        self._health_snapshot = (clock(), dict(self.counters))  # the last report: time, counters
        self._stop = threading.Event()
        self._thread = None

    @classmethod
    def from_config(cls, rng=None, stamp_clock=None, **config):
        """From the node's ``serial.*`` parameters; ``stamp_clock``: the node's clock (s)."""
        names = {spec.name for spec in cls.PARAMETERS}
        backend = cls(**{k: v for k, v in config.items() if k in names}, stamp_clock=stamp_clock)
        backend.start()
        return backend

    def describe(self):
        """One line for the node's start-up log."""
        trust = ', trusting them before a hello' if self.trust_configured_units else ''
        return (
            f'port {self.port} at {self.baud} baud, units {self.angle_unit}/{self.length_unit}'
            f'{trust}, latency {self.device_clock.latency:g} s'
        )

    # ----------------------------------------------------------------------- node side

    def start(self):
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name='gsp-serial', daemon=True)
            self._thread.start()

    def read_available(self, now_s):
        """Every reading received since the last call, each with its stamp on the node's clock
        (taken by the reader thread: ``now_s`` is not used, so a late call moves no stamp)."""
        with self._lock:
            queued = list(self._queue)
            self._queue.clear()
            self.counters['published'] += len(queued)
        return [DeviceSample(stamp, r.alpha, r.beta, r.phi, r.d_m) for stamp, r in queued]

    def read(self, now_s):
        samples = self.read_available(now_s)
        return samples[-1] if samples else None

    def messages(self):
        """``[(level, text)]`` to log since the last call (``warning`` or ``info``)."""
        with self._lock:
            messages = list(self._messages)
            self._messages.clear()
        return messages

    @property
    def hardware_id(self):
        """The ``hardware_id`` of the device's status on /diagnostics: the port."""
        return self.port

    def health(self):
        """The device path's :class:`~gsp_msgs_py.health.Health`; "since the last report" is
        since the previous call (the node calls it every ``diagnostics_period``). Keys and levels:
        docs/hardware.md section 2."""
        now = self._clock()
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
            **{key: counters[key] for key in ('lines', 'readings', 'hello', 'connects')},
            'disconnects': counters['disconnects'],
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

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0 + self.timeout)

    # ----------------------------------------------------------------------- reader thread

    def _say(self, level, text):
        with self._lock:
            self._messages.append((level, text))

    def _count(self, key, n=1):
        with self._lock:
            self.counters[key] += n

    def _drop_total(self):
        return sum(self.counters[k] for k in (*BACKEND_DROP_REASONS, 'lost'))

    def _open(self):
        if self._serial_factory is not None:
            return self._serial_factory(self.port, self.baud, self.timeout)
        import serial

        return serial.Serial(self.port, self.baud, timeout=self.timeout, write_timeout=self.timeout)

    def _run(self):
        reported = False  # the current outage (absent port, or lost) has had its one warning
        while not self._stop.is_set():
            try:
                port = self._open()
            except (OSError, ValueError) as error:  # serial.SerialException is an OSError
                if not reported:
                    reported = True
                    self._say('warning', f'cannot open {self.port}: {error}; retrying')
                self._stop.wait(self.reconnect_interval)
                continue
            reported = False
            with self._lock:
                self.counters['connects'] += 1
                self._connected = True
                # Units are known again only from a hello received on this connection.
                self.hello, self._hello_since_reading = None, False
                self._waiting_since = 'the port was opened'
            self._say('info', f'serial device connected on {self.port} at {self.baud} baud')
            self.device_clock.reset()
            try:
                self._read_lines(port)
            except (OSError, ValueError) as error:
                reported = True  # one warning per outage: not again for a failed reopen
                self._count('disconnects')
                self._say('warning', f'serial device on {self.port} lost: {error}; reconnecting')
            finally:
                with self._lock:
                    self._connected = False
                try:
                    port.close()
                except (OSError, ValueError):
                    pass
            self._stop.wait(self.reconnect_interval)

    def _request_hello(self, port):
        """Ask the device for its hello (a version 1 device may ignore it)."""
        try:
            port.write(REQUEST_LINE)
        except OSError as error:
            if type(error).__name__ != 'SerialTimeoutException':  # a device not reading
                raise
            return
        self._count('requests')

    def _read_lines(self, port):
        # Read what has arrived in one call and split it here: pyserial's readline() reads one
        # byte per call, which falls behind at a few hundred lines/s when other threads hold
        # the GIL (the calibrator's numerics in the same process).
        last_line = last_request = self._clock()
        self._request_hello(port)
        pending = b''
        while not self._stop.is_set():
            data = port.read(max(1, port.in_waiting))
            # The receive instant on the node's clock, taken here (not at the node's tick).
            stamp_now = self._stamp_clock()
            now = self._clock()
            if self.hello is None and now - last_request >= HELLO_REQUEST_INTERVAL_S:
                last_request = now
                self._request_hello(port)
            self._summarise_drops(now)
            if not data:
                if not self._silent and now - last_line > self.silence_warning:
                    self._silent = True
                    self._say(
                        'warning',
                        f'no line from the device on {self.port} for {self.silence_warning:g} s',
                    )
                continue
            pending += data
            *lines, pending = pending.split(b'\n')
            if len(pending) > MAX_PENDING_BYTES:  # no line end in sight: garbage
                self._count('lines')
                self._count('garbage')
                self._unreadable += 1
                pending = b''
            if not lines:
                continue
            if self._silent:
                self._say(
                    'info', f'device on {self.port} talks again after {now - last_line:.2f} s'
                )
                self._silent = False
            last_line = now
            for line in lines:
                self._handle(line + b'\n', now, stamp_now)

    def _summarise_drops(self, now):
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
            self._say(
                'warning',
                f'serial device on {self.port}: {total - total_then} lines dropped or lost in '
                f'the last {now - then:.1f} s (since start: {by_reason}; lines {counters["lines"]})',
            )

    def _handle(self, line, now, stamp_now):
        try:
            parsed = parse_line(line, self.angle_unit, self.length_unit)
        except LineError as error:
            self._count('lines')
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
        self._count('lines')
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
            self._count('lost', max(0, gap - 1 - unreadable))
            return
        self.device_clock.reset()
        with self._lock:
            self.counters['resets'] += 1
            if not hello_fresh:  # a hello sent after the restart, before this line, stands
                self.hello = None
                self._waiting_since = f'it restarted (seq {last} -> {seq})'
        self._say(
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
            self._say('warning', f'{self._refusal_text(reason)} ({dropped} dropped so far)')

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
            self._say('warning', self._refusal_text(refusal))
            self._warned_at[refusal] = now
        else:
            self._say('info', f'device {hello.text()} on {self.port}')


SerialDeviceBackend.PARAMETERS = _specs()
