"""The ``serial`` device backend: the measuring device on a serial line (pyserial, no rclpy)."""

import threading
import time

from gsp_msgs_py.parameter_specs import (
    ParameterSpec,
    non_negative_spec,
    not_blank,
    one_of,
    positive_spec,
)

from .device_backend import DeviceBackend
from .serial_gate import DROP_SUMMARY_PERIOD_S, HELLO_REQUEST_INTERVAL_S, SerialLineGate
from .serial_protocol import ANGLE_UNITS, LENGTH_UNITS, REQUEST_LINE

MAX_PENDING_BYTES = 1024  #: a longer run without a line end is dropped as garbage


class SerialDeviceBackend(DeviceBackend):
    """Readings from a device speaking the serial protocol on ``port``."""

    name = 'serial'
    PARAMETERS = (
        ParameterSpec(
            'port', '/dev/ttyACM0', 'Serial port of the device', check=not_blank('a port')
        ),
        ParameterSpec('baud', 115200, 'Baud rate', integer_range=(1, 10_000_000)),
        positive_spec(
            'timeout',
            0.1,
            'Read timeout of the port; bounds how fast a stop or silence is noticed',
            's',
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
        non_negative_spec(
            'latency',
            0.0,
            'Fixed delay from the instant a line reports to its arrival beyond the least '
            'transmission delay; subtracted from every stamp',
            's',
        ),
        positive_spec('reconnect_interval', 0.5, 'Wait between attempts to (re)open the port', 's'),
        positive_spec(
            'silence_warning', 0.5, 'Warn when an open port delivers no line for this long', 's'
        ),
    )

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
        self.port = str(port)
        self.baud = int(baud)
        self.timeout = float(timeout)
        self.reconnect_interval = float(reconnect_interval)
        self.silence_warning = float(silence_warning)
        self.gate = SerialLineGate(
            self.port,
            angle_unit,
            length_unit,
            trust_configured_units,
            latency,
            now=clock(),
            drop_summary_period=drop_summary_period,
        )
        self._clock = clock
        self._stamp_clock = stamp_clock if stamp_clock is not None else clock
        self._serial_factory = serial_factory
        self._silent = False
        self._stop = threading.Event()
        self._thread = None

    @classmethod
    def from_config(cls, rng=None, stamp_clock=None, **config):
        """From the node's ``serial.*`` parameters; ``stamp_clock``: the node's clock (s)."""
        names = {spec.name for spec in cls.PARAMETERS}
        backend = cls(**{k: v for k, v in config.items() if k in names}, stamp_clock=stamp_clock)
        backend.start()
        return backend

    # The gate's state, read by the node, gsp_serial_check and the tests.
    counters = property(lambda self: self.gate.counters)
    first_drops = property(lambda self: self.gate.first_drops)
    hello = property(lambda self: self.gate.hello)

    def describe(self):
        """One line for the node's start-up log."""
        gate = self.gate
        trust = ', trusting them before a hello' if gate.trust_configured_units else ''
        return (
            f'port {self.port} at {self.baud} baud, units {gate.angle_unit}/{gate.length_unit}'
            f'{trust}, latency {gate.device_clock.latency:g} s'
        )

    def start(self):
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name='gsp-serial', daemon=True)
            self._thread.start()

    def read_available(self, now_s):
        """Every reading received since the last call, each with its stamp on the node's clock
        (taken by the reader thread: ``now_s`` is not used, so a late call moves no stamp)."""
        return self.gate.take_samples()

    def messages(self):
        """``[(level, text)]`` to log since the last call (``warning`` or ``info``)."""
        return self.gate.take_messages()

    @property
    def hardware_id(self):
        """The ``hardware_id`` of the device's status on /diagnostics: the port."""
        return self.port

    def health(self):
        """The device path's :class:`~gsp_msgs_py.health.Health` since the previous call
        (:meth:`.serial_gate.SerialLineGate.health`)."""
        return self.gate.health(self._clock())

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0 + self.timeout)

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
                    self.gate.say('warning', f'cannot open {self.port}: {error}; retrying')
                self._stop.wait(self.reconnect_interval)
                continue
            reported = False
            self.gate.connected()
            self.gate.say('info', f'serial device connected on {self.port} at {self.baud} baud')
            try:
                self._read_lines(port)
            except (OSError, ValueError) as error:
                reported = True  # one warning per outage: not again for a failed reopen
                self.gate.count('disconnects')
                self.gate.say(
                    'warning', f'serial device on {self.port} lost: {error}; reconnecting'
                )
            finally:
                self.gate.disconnected()
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
        self.gate.count('requests')

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
            if self.gate.hello is None and now - last_request >= HELLO_REQUEST_INTERVAL_S:
                last_request = now
                self._request_hello(port)
            self.gate.summarise_drops(now)
            if not data:
                if not self._silent and now - last_line > self.silence_warning:
                    self._silent = True
                    self.gate.say(
                        'warning',
                        f'no line from the device on {self.port} for {self.silence_warning:g} s',
                    )
                continue
            pending += data
            *lines, pending = pending.split(b'\n')
            if len(pending) > MAX_PENDING_BYTES:  # no line end in sight: garbage
                self.gate.garbage()
                pending = b''
            if not lines:
                continue
            if self._silent:
                self.gate.say(
                    'info', f'device on {self.port} talks again after {now - last_line:.2f} s'
                )
                self._silent = False
            last_line = now
            for line in lines:
                self.gate.handle(line + b'\n', now, stamp_now)
