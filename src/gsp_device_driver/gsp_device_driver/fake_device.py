"""A reference emulator of the measuring device's microcontroller on a pty (no rclpy)."""

import math
import os
import select
import threading
import time
import tty

import numpy as np

from gsp_kinematics.model.motion import DEFAULT_SENSOR_RATE_HZ

from .serial_protocol import U32, Reading, format_hello, format_reading, is_request

HELLO_PERIOD_S = 1.0
MAX_REQUEST_BYTES = 256  #: host input kept while looking for a request line
PARTIAL_WAIT_S = 0.5  #: longest wait to complete a line the buffer took in part
COUNTER_NAMES = (
    'readings',
    'garbage',
    'checksum_errors',
    'hello',
    'requests',
    'lost',
    'lost_hello',
    'skipped',
    'connects',
)


class TruthFeed:
    """What an emulated device measures: the newest item (a true pose) handed over with the
    instant it describes (s, ``time.monotonic``), each taken at most once: a stalled feed is a
    gap in the device's lines, never an old pose under a new ``t_us``.
    """

    def __init__(self):
        self._lock = threading.Lock()
        self._latest = None  # (instant s, item)
        self._taken_s = -math.inf

    def put(self, item, instant_s):
        """Hand over ``item`` describing ``instant_s``; an item older than the newest is ignored."""
        with self._lock:
            if self._latest is None or instant_s > self._latest[0]:
                self._latest = (float(instant_s), item)

    def take(self):
        """``(item, instant_s)``: the newest item not taken yet, or None."""
        with self._lock:
            if self._latest is None or not self._latest[0] > self._taken_s:
                return None
            self._taken_s = self._latest[0]
            return self._latest[1], self._latest[0]


class FakeDevice:
    """The device emulator; :meth:`start` it, :meth:`close` it."""

    def __init__(
        self,
        link,
        readings,
        rate_hz=DEFAULT_SENSOR_RATE_HZ,
        angle_unit='rad',
        length_unit='m',
        garbage_fraction=0.0,
        checksum_error_fraction=0.0,
        device_id='gsp-fake-device',
        rng=None,
        hello_period_s=HELLO_PERIOD_S,
        record_sampling=False,
        timed_readings=False,
    ):
        self.link = str(link)
        self._readings = readings
        self.timed_readings = bool(timed_readings)
        self.period_s = 1.0 / float(rate_hz)
        self.rate_hz = float(rate_hz)
        self.angle_unit, self.length_unit = angle_unit, length_unit
        self.garbage_fraction = float(garbage_fraction)
        self.checksum_error_fraction = float(checksum_error_fraction)
        self.device_id = device_id
        self.hello_period_s = float(hello_period_s)  # 0: only at connection and on request
        #: (sampling instant on time.monotonic (s), Reading) of each reading line sent, if asked
        self.sampling_log = [] if record_sampling else None
        self._host_input = b''
        self._rng = rng if rng is not None else np.random.default_rng()
        self._lock = threading.Lock()
        self.counters = dict.fromkeys(COUNTER_NAMES, 0)
        self.paused = False  # True: no reading lines (a test's pause to let the reader catch up)
        self._silent_until = 0.0
        self._skip = 0
        self._unplugged_until = 0.0
        self._fds = None
        self._seq = 0
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread = None

    def start(self):
        self._plug()
        self._thread = threading.Thread(target=self._run, name='gsp-fake-device', daemon=True)
        self._thread.start()
        return self

    def skip(self, count):
        """Lose the next ``count`` reading lines on the way (their seq is used, nothing is sent),
        as a noisy cable would."""
        with self._lock:
            self._skip += int(count)

    def silence(self, duration_s):
        """Send nothing for ``duration_s`` (the port stays open)."""
        with self._lock:
            self._silent_until = time.monotonic() + float(duration_s)

    def disconnect(self, duration_s):
        """Unplug now (the pty is closed: readers get an I/O error), replug after
        ``duration_s`` on a new pty behind the same link."""
        with self._lock:
            self._unplugged_until = time.monotonic() + float(duration_s)
            self._unplug()

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        with self._lock:
            self._unplug()
        try:
            os.unlink(self.link)
        except OSError:
            pass

    def _plug(self):
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass as on a UART
        os.set_blocking(master, False)  # a full buffer drops lines instead of blocking
        temporary = f'{self.link}.{os.getpid()}.tmp'
        try:
            os.unlink(temporary)
        except FileNotFoundError:
            pass
        os.symlink(os.ttyname(slave), temporary)
        os.replace(temporary, self.link)
        self._fds = (master, slave)
        self._host_input = b''
        self.counters['connects'] += 1
        self._send_hello(time.monotonic())

    def _send_hello(self, now):
        if self._send(
            format_hello(self.device_id, self.angle_unit, self.length_unit, self.rate_hz),
            lost='lost_hello',
        ):
            self.counters['hello'] += 1
        self._last_hello = now

    def _serve_requests(self, now):
        """Answer each hello request the host wrote since the last tick with the hello line."""
        try:
            self._host_input += os.read(self._fds[0], 4096)
        except OSError:  # BlockingIOError: nothing written; EIO: no reader opened the port
            pass
        *lines, self._host_input = self._host_input.split(b'\n')
        self._host_input = self._host_input[-MAX_REQUEST_BYTES:]
        requests = sum(is_request(line + b'\n') for line in lines)
        if requests:
            self.counters['requests'] += requests
            self._send_hello(now)

    def _unplug(self):
        if self._fds is not None:
            for fd in self._fds:
                os.close(fd)
            self._fds = None

    def _send(self, data, lost='lost'):
        """Write one line. A line the full buffer cannot take at all is lost (counted under
        ``lost``: reading lines, whose seq then shows a gap, apart from hello lines), as on a
        UART nobody reads; one it took in part is completed (waiting up to PARTIAL_WAIT_S), so
        that a reader never sees a torn line the emulator did not mean to send."""
        master = self._fds[0]
        try:
            written = os.write(master, data)
        except OSError:  # BlockingIOError: buffer full; EIO: the reader side vanished
            written = 0
        if written == 0:
            self.counters[lost] += 1
            return False
        deadline = time.monotonic() + PARTIAL_WAIT_S
        while written < len(data):
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not select.select([], [master], [], remaining)[1]:
                self.counters[lost] += 1
                return False
            try:
                written += os.write(master, data[written:])
            except BlockingIOError:
                continue
            except OSError:
                self.counters[lost] += 1
                return False
        return True

    def _line(self, values, now):
        """(line, counter key, Reading) of one reading instant."""
        reading = Reading(
            self._seq % U32, int((now - self._t0) * 1e6) % U32, *(float(v) for v in values)
        )
        self._seq += 1
        draw = self._rng.random()
        if draw < self.garbage_fraction:
            junk = self._rng.integers(0x21, 0x7F, size=int(self._rng.integers(1, 60)))
            junk[0] = ord('#')  # never the '$' of a protocol line
            return bytes(junk.astype(np.uint8)) + b'\r\n', 'garbage', reading
        line = format_reading(reading, self.angle_unit, self.length_unit)
        if draw < self.garbage_fraction + self.checksum_error_fraction:
            bad = (int(line[-4:-2], 16) ^ 0x5A) & 0xFF
            return line[:-4] + f'{bad:02X}'.encode() + b'\r\n', 'checksum_errors', reading
        return line, 'readings', reading

    def _run(self):
        deadline = time.monotonic()
        while not self._stop.is_set():
            deadline += self.period_s
            delay = deadline - time.monotonic()
            if delay < -1.0:  # far behind (suspended): do not burst
                deadline = time.monotonic()
            elif delay > 0:
                self._stop.wait(delay)
            now = time.monotonic()
            with self._lock:
                if self._fds is None:
                    if now >= self._unplugged_until:
                        self._plug()
                    continue
                if now < self._silent_until:
                    continue
                self._serve_requests(now)
                if self.hello_period_s > 0 and now - self._last_hello >= self.hello_period_s:
                    self._send_hello(now)
                if self.paused:
                    continue
                taken = self._readings()
                if taken is None:
                    continue
                # t_us is the sampling instant: that of the values when the reader gives it.
                values, sampled = taken if self.timed_readings else (taken, now)
                if sampled < self._t0:  # before this device's clock started
                    continue
                line, kind, reading = self._line(values, sampled)
                if self._skip > 0:
                    self._skip -= 1
                    self.counters['skipped'] += 1
                    continue
                if self._send(line):
                    self.counters[kind] += 1
                    if self.sampling_log is not None and kind == 'readings':
                        self.sampling_log.append((sampled, reading))
