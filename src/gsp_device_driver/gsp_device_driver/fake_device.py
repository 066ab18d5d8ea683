"""A reference emulator of the measuring device's microcontroller on a pseudo-terminal (no rclpy).

:class:`FakeDevice` opens a pty pair, points the symlink ``link`` at its slave end (the "port" a
driver opens, like a udev ``/dev/gsp_device`` rule) and writes the serial protocol to it from a
thread: a hello line at connection and every second, then one reading line per ``1/rate_hz``
from ``readings()`` (``[alpha, beta, phi, d_m]`` in SI, or None while there is nothing to
report). Faults: garbage lines and checksum errors (each replacing a reading line, with the
given probabilities, counted in :attr:`counters`), :meth:`silence` and :meth:`disconnect`
(closes the pty, as an unplugged USB device; a new one appears after the given time).
"""

import os
import select
import threading
import time
import tty

import numpy as np

from .serial_protocol import U32, Reading, format_hello, format_reading

HELLO_PERIOD_S = 1.0
PARTIAL_WAIT_S = 0.5  #: longest wait to complete a line the buffer took in part


class FakeDevice:
    """The device emulator; :meth:`start` it, :meth:`close` it."""

    def __init__(
        self,
        link,
        readings,
        rate_hz=200.0,
        angle_unit='rad',
        length_unit='m',
        garbage_fraction=0.0,
        checksum_error_fraction=0.0,
        device_id='gsp-fake-device',
        rng=None,
    ):
        self.link = str(link)
        self._readings = readings
        self.period_s = 1.0 / float(rate_hz)
        self.rate_hz = float(rate_hz)
        self.angle_unit, self.length_unit = angle_unit, length_unit
        self.garbage_fraction = float(garbage_fraction)
        self.checksum_error_fraction = float(checksum_error_fraction)
        self.device_id = device_id
        self._rng = rng if rng is not None else np.random.default_rng()
        self._lock = threading.Lock()
        self.counters = dict.fromkeys(
            ('readings', 'garbage', 'checksum_errors', 'hello', 'lost', 'connects'), 0
        )
        self.paused = False  # True: no reading lines (a test's pause to let the reader catch up)
        self._silent_until = 0.0
        self._unplugged_until = 0.0
        self._fds = None
        self._seq = 0
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread = None

    # ------------------------------------------------------------------------- control

    def start(self):
        self._plug()
        self._thread = threading.Thread(target=self._run, name='gsp-fake-device', daemon=True)
        self._thread.start()
        return self

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

    def count(self, key):
        with self._lock:
            return self.counters[key]

    # --------------------------------------------------------------------------- pty

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
        self.counters['connects'] += 1
        self._send(format_hello(self.device_id, self.angle_unit, self.length_unit, self.rate_hz))
        self.counters['hello'] += 1
        self._last_hello = time.monotonic()

    def _unplug(self):
        if self._fds is not None:
            for fd in self._fds:
                os.close(fd)
            self._fds = None

    def _send(self, data):
        """Write one line. A line the full buffer cannot take at all is lost (counted), as on a
        UART nobody reads; one it took in part is completed (waiting up to PARTIAL_WAIT_S), so
        that a reader never sees a torn line the emulator did not mean to send."""
        master = self._fds[0]
        try:
            written = os.write(master, data)
        except OSError:  # BlockingIOError: buffer full; EIO: the reader side vanished
            written = 0
        if written == 0:
            self.counters['lost'] += 1
            return False
        deadline = time.monotonic() + PARTIAL_WAIT_S
        while written < len(data):
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not select.select([], [master], [], remaining)[1]:
                self.counters['lost'] += 1
                return False
            try:
                written += os.write(master, data[written:])
            except BlockingIOError:
                continue
            except OSError:
                self.counters['lost'] += 1
                return False
        return True

    # ------------------------------------------------------------------------- thread

    def _line(self, values, now):
        reading = Reading(
            self._seq % U32, int((now - self._t0) * 1e6) % U32, *(float(v) for v in values)
        )
        self._seq += 1
        draw = self._rng.random()
        if draw < self.garbage_fraction:
            junk = self._rng.integers(0x21, 0x7F, size=int(self._rng.integers(1, 60)))
            junk[0] = ord('#')  # never the '$' of a protocol line
            return bytes(junk.astype(np.uint8)) + b'\r\n', 'garbage'
        line = format_reading(reading, self.angle_unit, self.length_unit)
        if draw < self.garbage_fraction + self.checksum_error_fraction:
            bad = (int(line[-4:-2], 16) ^ 0x5A) & 0xFF
            return line[:-4] + f'{bad:02X}'.encode() + b'\r\n', 'checksum_errors'
        return line, 'readings'

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
                if now - self._last_hello >= HELLO_PERIOD_S:
                    if self._send(
                        format_hello(
                            self.device_id, self.angle_unit, self.length_unit, self.rate_hz
                        )
                    ):
                        self.counters['hello'] += 1
                    self._last_hello = now
                if self.paused:
                    continue
                values = self._readings()
                if values is None:
                    continue
                line, kind = self._line(values, now)
                if self._send(line):
                    self.counters[kind] += 1
