"""The ``serial`` device backend: the measuring device on a serial line (pyserial, no rclpy).

A reader thread opens ``port``, reads protocol lines (:mod:`.serial_protocol`), drops bad ones
(counted by reason in :attr:`SerialDeviceBackend.counters`) and queues the good ones stamped by
:class:`~.serial_protocol.DeviceClock`. The node drains the queue with :meth:`read_available`.
When the port fails (unplugged) or is absent, the thread reports it and retries every
``reconnect_interval`` until the device is back; nothing is raised to the node.
"""

import collections
import dataclasses
import threading
import time

from .device_backend import BackendError, DeviceBackend, DeviceSample
from .serial_protocol import (
    ANGLE_UNITS,
    DROP_REASONS,
    LENGTH_UNITS,
    PROTOCOL_VERSION,
    DeviceClock,
    Hello,
    LineError,
    parse_line,
)

QUEUE_LENGTH = 2000  #: readings kept for the node (10 s at 200 Hz)
MAX_PENDING_BYTES = 1024  #: a longer run without a line end is dropped as garbage


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


@dataclasses.dataclass(frozen=True)
class SerialSettings:
    """The serial backend's parameters (the ``serial.*`` parameters of ``device_driver``)."""

    port: str
    baud: int = 115200
    timeout: float = 0.1  #: s
    angle_unit: str = 'rad'
    length_unit: str = 'm'
    latency: float = 0.0  #: s
    reconnect_interval: float = 0.5  #: s
    silence_warning: float = 0.5  #: s


class SerialDeviceBackend(DeviceBackend):
    """Readings from a device speaking the serial protocol on ``port``.

    ``clock`` (s, monotonic) stamps the received lines; :meth:`read_available` maps them to the
    node's clock. Start the reader with :meth:`start` (done by :meth:`from_config`).
    """

    name = 'serial'

    def __init__(self, settings, clock=time.monotonic, serial_factory=None):
        """``settings``: a :class:`SerialSettings`; ``serial_factory(port, baud, timeout)`` opens
        the port (tests; default: pyserial)."""
        angle_unit, length_unit = settings.angle_unit, settings.length_unit
        if angle_unit not in ANGLE_UNITS or length_unit not in LENGTH_UNITS:
            raise BackendError(f'unknown units {angle_unit!r}, {length_unit!r}')
        self.port = str(settings.port)
        self.baud = int(settings.baud)
        self.timeout = float(settings.timeout)
        self.angle_unit, self.length_unit = angle_unit, length_unit
        self.reconnect_interval = float(settings.reconnect_interval)
        self.silence_warning = float(settings.silence_warning)
        self.device_clock = DeviceClock(settings.latency)
        self._clock = clock
        self._serial_factory = serial_factory
        self._lock = threading.Lock()
        self._queue = collections.deque(maxlen=QUEUE_LENGTH)
        self._messages = collections.deque(maxlen=100)
        self.counters = dict.fromkeys(
            ('lines', 'readings', 'hello', 'connects', 'disconnects', *DROP_REASONS), 0
        )
        self.hello = None
        self._stop = threading.Event()
        self._thread = None

    @classmethod
    def from_config(cls, rng=None, **config):
        names = {spec.name for spec in cls.PARAMETERS}
        backend = cls(SerialSettings(**{k: v for k, v in config.items() if k in names}))
        backend.start()
        return backend

    # ----------------------------------------------------------------------- node side

    def start(self):
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name='gsp-serial', daemon=True)
            self._thread.start()

    def read_available(self, now_s):
        """Every reading received since the last call, stamped on the node's clock (``now_s``)."""
        with self._lock:
            queued = list(self._queue)
            self._queue.clear()
        shift = now_s - self._clock()
        return [DeviceSample(stamp + shift, r.alpha, r.beta, r.phi, r.d_m) for stamp, r in queued]

    def read(self, now_s):
        samples = self.read_available(now_s)
        return samples[-1] if samples else None

    def messages(self):
        """``[(level, text)]`` to log since the last call (``warning`` or ``info``)."""
        with self._lock:
            messages = list(self._messages)
            self._messages.clear()
        return messages

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0 + self.timeout)

    # ----------------------------------------------------------------------- reader thread

    def _say(self, level, text):
        with self._lock:
            self._messages.append((level, text))

    def _count(self, key):
        with self._lock:
            self.counters[key] += 1

    def _open(self):
        if self._serial_factory is not None:
            return self._serial_factory(self.port, self.baud, self.timeout)
        import serial

        return serial.Serial(self.port, self.baud, timeout=self.timeout)

    def _run(self):
        failure = None  # last reason the port could not be opened (reported once)
        while not self._stop.is_set():
            try:
                port = self._open()
            except (OSError, ValueError) as error:  # serial.SerialException is an OSError
                if str(error) != failure:
                    failure = str(error)
                    self._say('warning', f'cannot open {self.port}: {error}; retrying')
                self._stop.wait(self.reconnect_interval)
                continue
            failure = None
            self._count('connects')
            self._say('info', f'serial device connected on {self.port} at {self.baud} baud')
            self.device_clock.reset()
            try:
                self._read_lines(port)
            except (OSError, ValueError) as error:
                self._count('disconnects')
                self._say('warning', f'serial device on {self.port} lost: {error}; reconnecting')
            finally:
                try:
                    port.close()
                except (OSError, ValueError):
                    pass
            self._stop.wait(self.reconnect_interval)

    def _read_lines(self, port):
        # Read what has arrived in one call and split it here: pyserial's readline() reads one
        # byte per call, which falls behind at a few hundred lines/s when other threads hold
        # the GIL (the calibrator's numerics in the same process).
        last_line = self._clock()
        silent = False
        pending = b''
        while not self._stop.is_set():
            data = port.read(max(1, port.in_waiting))
            now = self._clock()
            if not data:
                if not silent and now - last_line > self.silence_warning:
                    silent = True
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
                pending = b''
            if not lines:
                continue
            if silent:
                self._say(
                    'info', f'device on {self.port} talks again after {now - last_line:.2f} s'
                )
                silent = False
            last_line = now
            for line in lines:
                if line.strip():
                    self._handle(line + b'\n', now)

    def _handle(self, line, now):
        self._count('lines')
        # A device whose hello disagrees (protocol version, units) has its readings dropped:
        # counted as 'version' or 'units' even when their values also fail the range checks.
        refused = self._refusal(self.hello)
        try:
            parsed = parse_line(line, self.angle_unit, self.length_unit)
        except LineError as error:
            self._count(refused if refused and error.reason == 'range' else error.reason)
            return
        if isinstance(parsed, Hello):
            self._on_hello(parsed)
            return
        if refused:
            self._count(refused)
            return
        stamp = self.device_clock.stamp(parsed.device_time_us, now)
        with self._lock:
            self.counters['readings'] += 1
            self._queue.append((stamp, parsed))

    def _refusal(self, hello):
        """'' if the readings of a device that said ``hello`` are usable, else the drop reason."""
        if hello is None:
            return ''
        if hello.version != PROTOCOL_VERSION:
            return 'version'
        return '' if self._hello_ok(hello) else 'units'

    def _hello_ok(self, hello):
        return hello.version == PROTOCOL_VERSION and (hello.angle_unit, hello.length_unit) == (
            self.angle_unit,
            self.length_unit,
        )

    def _on_hello(self, hello):
        self._count('hello')
        first = self.hello != hello
        self.hello = hello
        if not first:
            return
        if hello.version != PROTOCOL_VERSION:
            self._say(
                'warning',
                f'device {hello.device_id!r} speaks protocol version {hello.version}, this '
                f'driver version {PROTOCOL_VERSION}: its readings are dropped',
            )
        elif not self._hello_ok(hello):
            self._say(
                'warning',
                f'device {hello.device_id!r} sends {hello.angle_unit}/{hello.length_unit} but '
                f'serial.angle_unit/length_unit are {self.angle_unit}/{self.length_unit}: '
                'its readings are dropped until the parameters match',
            )
        else:
            self._say(
                'info',
                f'device {hello.device_id!r}: protocol {hello.version}, '
                f'{hello.angle_unit}/{hello.length_unit}, {hello.rate_hz:g} Hz',
            )


SerialDeviceBackend.PARAMETERS = _specs()
