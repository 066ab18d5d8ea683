"""The measuring device's serial line protocol, version 1 (pure: no pyserial, no rclpy).

Grammar and rules: docs/hardware.md section 1; test vectors: docs/serial_test_vectors.json.
"""

import dataclasses
import functools
import math
import operator
import re

import numpy as np

PROTOCOL_VERSION = 1
READING_TAG = 'GSP'
HELLO_TAG = 'GSPHELLO'
REQUEST_BODY = 'GSPQ,HELLO'  #: the host's hello request (body between '$' and '*')
MAX_LINE_BYTES = 160  #: a longer line (counting '$' and the line end) is garbage
U32 = 2**32

#: Angle and length units: name -> factor to SI (rad, m).
ANGLE_UNITS = {'rad': 1.0, 'mrad': 1e-3, 'urad': 1e-6, 'deg': math.pi / 180.0}
LENGTH_UNITS = {'m': 1.0, 'mm': 1e-3, 'um': 1e-6}
#: Decimal units divide by a power of ten: the correctly rounded SI value of the decimal text.
_DIVISORS = {'mrad': 1e3, 'urad': 1e6, 'mm': 1e3, 'um': 1e6}

#: Status bits of a reading line (a set bit means that sensor's value is not valid).
STATUS_BITS = {
    0x1: 'inclinometer fault',
    0x2: 'encoder fault',
    0x4: 'LVDT fault',
    0x8: 'device busy (initialising)',
}

#: Range checks in SI: an inclinometer tilts less than 90 deg; phi is within one turn either way
#: (the encoder may count past +-pi); the LVDT extension is within [0, 10] m.
MAX_TILT_RAD = math.pi / 2
MAX_PHI_RAD = 2 * math.pi
LVDT_RANGE_M = (0.0, 10.0)

#: Why a line is dropped (counter keys of the backend). The first four come from one line
#: (:func:`parse_line`); the last three from the stream's state (the hello rules).
DROP_REASONS = ('garbage', 'checksum', 'range', 'status', 'no_hello', 'version', 'units')

# The grammar's tokens (docs/hardware.md): ABNF rule -> regular expression.
_UINT32 = r'[0-9]{1,10}'
_NUMBER = r'-?[0-9]+(?:\.[0-9]+)?'
_UNSIGNED = r'[0-9]+(?:\.[0-9]+)?'
_STATUS = r'[0-9A-Fa-f]{1,8}'
_FRAME = re.compile(r'\$([\x20-\x29\x2B-\x7E]*)\*([0-9A-Fa-f]{2})\r?\n')
_READING = re.compile(
    rf'GSP,({_UINT32}),({_UINT32}),({_NUMBER}),({_NUMBER}),({_NUMBER}),({_NUMBER}),({_STATUS})'
)
_HELLO = re.compile(
    rf'GSPHELLO,([0-9]{{1,3}}),([A-Za-z0-9_.-]{{1,32}}),([A-Za-z]{{1,8}}),([A-Za-z]{{1,8}}),'
    rf'({_UNSIGNED})'
)
_EMPTY = (b'\n', b'\r\n')


class LineError(ValueError):
    """A line is not a valid protocol line; ``reason`` is one of :data:`DROP_REASONS`."""

    def __init__(self, reason, message, seq=None):
        super().__init__(message)
        self.reason = reason
        self.seq = seq  # the line's seq when it could be read (a range or status drop)


@dataclasses.dataclass(frozen=True)
class Reading:
    """One reading line in SI: ``seq``, ``device_time_us`` and alpha, beta, phi (rad), d_m (m)."""

    seq: int
    device_time_us: int
    alpha: float
    beta: float
    phi: float
    d_m: float


@dataclasses.dataclass(frozen=True)
class Hello:
    """The hello line: protocol ``version``, ``device_id``, units (as sent: maybe unknown to this
    driver, see :attr:`units_known`), nominal ``rate_hz``."""

    version: int
    device_id: str
    angle_unit: str
    length_unit: str
    rate_hz: float

    @property
    def units_known(self):
        return self.angle_unit in ANGLE_UNITS and self.length_unit in LENGTH_UNITS

    def text(self):
        """One-line summary for logs and /diagnostics."""
        return (
            f'{self.device_id} v{self.version} {self.angle_unit}/{self.length_unit} '
            f'{self.rate_hz:g} Hz'
        )


def checksum(body):
    """XOR of the bytes of ``body`` (the text between ``$`` and ``*``), 0..255."""
    return functools.reduce(operator.xor, body.encode('ascii'), 0)


def frame(body):
    """``$<body>*<CC>\\r\\n`` as bytes."""
    return f'${body}*{checksum(body):02X}\r\n'.encode('ascii')


#: The host's hello request line (bytes).
REQUEST_LINE = frame(REQUEST_BODY)


def format_number(value):
    """The grammar's ``number`` of ``value``: decimal, no exponent, the shortest text that reads
    back as the same double (an int prints as is)."""
    if isinstance(value, int | np.integer):
        return str(int(value))
    return np.format_float_positional(float(value), trim='-')


def format_reading(reading, angle_unit='rad', length_unit='m', status=0):
    """The reading line (bytes) of ``reading`` (SI) in the given units."""
    angle, length = ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit]
    fields = [
        READING_TAG,
        str(reading.seq % U32),
        str(reading.device_time_us % U32),
        *(format_number(v / angle) for v in (reading.alpha, reading.beta, reading.phi)),
        format_number(reading.d_m / length),
        f'{status:X}',
    ]
    return frame(','.join(fields))


def format_hello(device_id, angle_unit, length_unit, rate_hz):
    """The hello line (bytes)."""
    rate = format_number(float(rate_hz))
    return frame(f'{HELLO_TAG},{PROTOCOL_VERSION},{device_id},{angle_unit},{length_unit},{rate}')


def is_request(line):
    """Whether ``line`` (bytes, with its line end) is the host's hello request."""
    return line in (REQUEST_LINE, REQUEST_LINE[:-2] + b'\n')


def _unframe(line):
    """The body of a framed line (bytes, with its line end); LineError('garbage' or 'checksum')."""
    if len(line) > MAX_LINE_BYTES:
        raise LineError('garbage', f'line longer than {MAX_LINE_BYTES} bytes ({len(line)})')
    try:
        text = line.decode('ascii')
    except UnicodeDecodeError:
        raise LineError('garbage', 'line is not ASCII') from None
    framed = _FRAME.fullmatch(text)
    if framed is None:
        raise LineError('garbage', f'not a $<body>*<CC><CR><LF> line: {text[:40]!r}')
    body, expected = framed.group(1), int(framed.group(2), 16)
    if checksum(body) != expected:
        raise LineError('checksum', f'checksum {expected:02X} != computed {checksum(body):02X}')
    return body


def _to_si(text, unit, units):
    if unit in _DIVISORS:
        return float(text) / _DIVISORS[unit]
    return float(text) * units[unit]


def _counter(text, what):
    value = int(text)
    if value >= U32:
        raise LineError('garbage', f'{what} {value} is beyond 32 bits')
    return value


def parse_line(line, angle_unit='rad', length_unit='m'):
    """A :class:`Reading` (SI) or :class:`Hello` of one line (bytes or str, with its line end
    ``\\r\\n`` or ``\\n``); None for an empty line; :class:`LineError` otherwise.
    """
    if isinstance(line, str):
        line = line.encode('latin-1')
    if line in _EMPTY:
        return None
    body = _unframe(line)
    if body.startswith(HELLO_TAG + ','):
        hello = _HELLO.fullmatch(body)
        if hello is None:
            raise LineError('garbage', f'hello line does not follow the grammar: {body[:60]!r}')
        version, device_id, angle, length, rate = hello.groups()
        if float(rate) <= 0.0:
            raise LineError('garbage', f'hello rate_hz must be > 0, got {rate}')
        return Hello(int(version), device_id, angle, length, float(rate))
    reading = _READING.fullmatch(body)
    if reading is None:
        raise LineError('garbage', f'not a reading or hello line: {body[:60]!r}')
    seq_text, t_text, *values, status_text = reading.groups()
    seq, t_us = _counter(seq_text, 'seq'), _counter(t_text, 't_us')
    status = int(status_text, 16)
    if status:
        faults = [text for bit, text in STATUS_BITS.items() if status & bit] or ['unknown bit']
        raise LineError('status', f'status 0x{status:X}: {", ".join(faults)}', seq)
    alpha, beta, phi = (_to_si(text, angle_unit, ANGLE_UNITS) for text in values[:3])
    d_m = _to_si(values[3], length_unit, LENGTH_UNITS)
    for name, value in (('alpha', alpha), ('beta', beta)):
        if abs(value) > MAX_TILT_RAD:
            raise LineError(
                'range', f'{name} {value:.6g} rad is beyond +-90 deg (wrong unit?)', seq
            )
    if abs(phi) > MAX_PHI_RAD:
        raise LineError('range', f'phi {phi:.6g} rad is beyond +-2 pi (wrong unit?)', seq)
    if not LVDT_RANGE_M[0] <= d_m <= LVDT_RANGE_M[1]:
        raise LineError(
            'range', f'd {d_m:.6g} m is outside {list(LVDT_RANGE_M)} m (wrong unit?)', seq
        )
    return Reading(seq, t_us, alpha, beta, phi, d_m)


#: Least step (s) between two stamps of :class:`DeviceClock` (1 us: distinct in ns stamps).
MIN_STAMP_STEP_S = 1e-6


class DeviceClock:
    """Maps device time to host time: the stamping rule of docs/hardware.md (minimum offset over
    ``window`` lines, slewed in; stamps grow by at least :data:`MIN_STAMP_STEP_S`)."""

    def __init__(self, latency=0.0, window=200, max_gap_s=1.0):
        self.latency = float(latency)
        self.window = int(window)
        self.max_gap_s = float(max_gap_s)
        self._last_stamp = None  # kept across reset(): host time only grows
        self.reset()

    def reset(self):
        self._last_device_s = None
        self._offsets = []
        #: Host time minus device time of the last stamp (s, before ``latency``), or None.
        self.offset = None

    def stamp(self, device_time_us, receive_s):
        """Host time (s) of the instant of a line with ``device_time_us`` received at
        ``receive_s`` (s, host clock)."""
        device_s = device_time_us * 1e-6
        step = None
        if self._last_device_s is not None:
            step = device_s - self._last_device_s
            if step < 0.0 or step > self.max_gap_s:
                self._offsets, self.offset, step = [], None, None
        self._last_device_s = device_s
        self._offsets.append(receive_s - device_s)
        if len(self._offsets) > self.window:
            del self._offsets[0]
        offset = min(self._offsets)
        if step is not None and self.offset is not None:
            offset = max(offset, self.offset - 0.5 * step)
        self.offset = offset
        stamp = device_s + offset - self.latency
        if self._last_stamp is not None and stamp < self._last_stamp + MIN_STAMP_STEP_S:
            stamp = self._last_stamp + MIN_STAMP_STEP_S
        self._last_stamp = stamp
        return stamp
