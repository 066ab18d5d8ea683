"""The measuring device's serial line protocol, version 1 (pure: no pyserial, no rclpy).

One ASCII line per instant, NMEA-like, ended by ``\\r\\n`` (a bare ``\\n`` is accepted)::

    $GSP,<seq>,<t_us>,<alpha>,<beta>,<phi>,<d>,<status>*<CC>
    $GSPHELLO,<version>,<device_id>,<angle_unit>,<length_unit>,<rate_hz>*<CC>

* ``seq``: line counter, decimal, 0..2**32-1, wraps; ``t_us``: device clock in microseconds,
  decimal, 0..2**32-1, wraps (~71.6 min);
* ``alpha``, ``beta`` (inclinometer), ``phi`` (encoder): decimal numbers in ``angle_unit``
  (``rad``, ``mrad``, ``urad`` or ``deg``); ``d`` (LVDT): in ``length_unit`` (``m``, ``mm`` or
  ``um``). Integers are fine (e.g. ``urad`` and ``um`` from fixed-point firmware);
* ``status``: hexadecimal bit mask, 0 = all good (:data:`STATUS_BITS`); a non-zero line is
  dropped;
* ``CC``: two hex digits, the XOR of every byte between ``$`` and ``*`` (exclusive).

The hello line is sent at connection (and may be repeated, e.g. once per second). Its
``version`` must be :data:`PROTOCOL_VERSION`. Full text for firmware writers: docs/hardware.md.
"""

import dataclasses
import math

PROTOCOL_VERSION = 1
READING_TAG = 'GSP'
HELLO_TAG = 'GSPHELLO'
MAX_LINE_BYTES = 160  #: a longer line is garbage
U32 = 2**32

#: Angle and length units: name -> factor to SI (rad, m).
ANGLE_UNITS = {'rad': 1.0, 'mrad': 1e-3, 'urad': 1e-6, 'deg': math.pi / 180.0}
LENGTH_UNITS = {'m': 1.0, 'mm': 1e-3, 'um': 1e-6}

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

#: Why a line is dropped (counter keys of the backend).
DROP_REASONS = ('garbage', 'checksum', 'range', 'status', 'version', 'units')


class LineError(ValueError):
    """A line is not a valid protocol line; ``reason`` is one of :data:`DROP_REASONS`."""

    def __init__(self, reason, message):
        super().__init__(message)
        self.reason = reason


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
    """The hello line: protocol ``version``, ``device_id``, units, nominal ``rate_hz``."""

    version: int
    device_id: str
    angle_unit: str
    length_unit: str
    rate_hz: float


def checksum(body):
    """XOR of the bytes of ``body`` (the text between ``$`` and ``*``), 0..255."""
    value = 0
    for byte in body.encode('ascii'):
        value ^= byte
    return value


def frame(body):
    """``$<body>*<CC>\\r\\n`` as bytes."""
    return f'${body}*{checksum(body):02X}\r\n'.encode('ascii')


def format_number(value):
    """A decimal text of ``value`` a microcontroller could print (no exponent for integers)."""
    if isinstance(value, int):
        return str(value)
    return f'{value:.9g}'


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


def format_hello(device_id, angle_unit='rad', length_unit='m', rate_hz=200.0):
    """The hello line (bytes)."""
    body = ','.join(
        [HELLO_TAG, str(PROTOCOL_VERSION), device_id, angle_unit, length_unit, f'{rate_hz:g}']
    )
    return frame(body)


def _unframe(line):
    """The body of a framed line (bytes or str); LineError('garbage' or 'checksum')."""
    if isinstance(line, bytes):
        if len(line) > MAX_LINE_BYTES:
            raise LineError('garbage', f'line longer than {MAX_LINE_BYTES} bytes')
        try:
            line = line.decode('ascii')
        except UnicodeDecodeError:
            raise LineError('garbage', 'line is not ASCII') from None
    line = line.strip()
    star = line.rfind('*')
    if not line.startswith('$') or star < 0 or len(line) - star != 3:
        raise LineError('garbage', f'not a $...*CC line: {line[:40]!r}')
    body = line[1:star]
    try:
        expected = int(line[star + 1 :], 16)
    except ValueError:
        raise LineError('garbage', f'checksum is not hex: {line[star + 1 :]!r}') from None
    if checksum(body) != expected:
        raise LineError('checksum', f'checksum {expected:02X} != computed {checksum(body):02X}')
    return body


def _number(text, what):
    try:
        value = float(text)
    except ValueError:
        raise LineError('garbage', f'{what} is not a number: {text!r}') from None
    if not math.isfinite(value):
        raise LineError('range', f'{what} is not finite: {text!r}')
    return value


def _counter(text, what):
    if not text.isdigit() or int(text) >= U32:
        raise LineError('garbage', f'{what} is not an unsigned 32-bit decimal: {text!r}')
    return int(text)


def parse_line(line, angle_unit='rad', length_unit='m'):
    """A :class:`Reading` (SI) or :class:`Hello` of one line; :class:`LineError` otherwise.

    ``angle_unit`` and ``length_unit`` are the units the reading lines are in.
    """
    fields = _unframe(line).split(',')
    if fields[0] == HELLO_TAG:
        if len(fields) != 6:
            raise LineError('garbage', f'hello line has {len(fields) - 1} fields, expected 5')
        try:
            version = int(fields[1])
        except ValueError:
            raise LineError('garbage', f'hello version is not an integer: {fields[1]!r}') from None
        if fields[3] not in ANGLE_UNITS or fields[4] not in LENGTH_UNITS:
            raise LineError('units', f'hello line names unknown units {fields[3:5]}')
        return Hello(version, fields[2], fields[3], fields[4], _number(fields[5], 'rate'))
    if fields[0] != READING_TAG:
        raise LineError('garbage', f'unknown line tag {fields[0]!r}')
    if len(fields) != 8:
        raise LineError('garbage', f'reading line has {len(fields) - 1} fields, expected 7')
    seq, t_us = _counter(fields[1], 'seq'), _counter(fields[2], 't_us')
    try:
        status = int(fields[7], 16)
    except ValueError:
        raise LineError('garbage', f'status is not hex: {fields[7]!r}') from None
    if status:
        faults = [text for bit, text in STATUS_BITS.items() if status & bit] or ['unknown bit']
        raise LineError('status', f'status 0x{status:X}: {", ".join(faults)}')
    angle, length = ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit]
    alpha, beta, phi = (
        _number(text, name) * angle
        for text, name in zip(fields[3:6], ('alpha', 'beta', 'phi'), strict=True)
    )
    d_m = _number(fields[6], 'd') * length
    for name, value in (('alpha', alpha), ('beta', beta)):
        if abs(value) > MAX_TILT_RAD:
            raise LineError('range', f'{name} {value:.6g} rad is beyond +-90 deg (wrong unit?)')
    if abs(phi) > MAX_PHI_RAD:
        raise LineError('range', f'phi {phi:.6g} rad is beyond +-2 pi (wrong unit?)')
    if not LVDT_RANGE_M[0] <= d_m <= LVDT_RANGE_M[1]:
        raise LineError('range', f'd {d_m:.6g} m is outside {list(LVDT_RANGE_M)} m (wrong unit?)')
    return Reading(seq, t_us, alpha, beta, phi, d_m)


#: Least step (s) between two stamps of :class:`DeviceClock` (1 us: distinct in ns stamps).
MIN_STAMP_STEP_S = 1e-6


class DeviceClock:
    """Maps device time to host time: the documented stamping rule of the serial backend.

    Each line's host receive time ``t_rx`` is later than the instant it reports by the
    (unknown, positive, jittery) transmission delay. For ``device_time_us`` ``t_d`` the offset
    ``t_rx - t_d`` is therefore smallest for the least-delayed lines: the clock keeps the minimum
    offset over the last ``window`` lines, and stamps ``t_d + min_offset - latency`` (s). A jump
    back of the device time (wrap, reboot) or a gap longer than ``max_gap_s`` restarts the
    window. ``latency`` (s) is the remaining fixed delay (sensor filter, USB frame), measured once.
    A lower offset (a less-delayed line after a backlog, e.g. on a loaded host) is slewed in by
    at most half the device step per line, so stamps keep the order of the device times. And
    stamps only grow, by at least :data:`MIN_STAMP_STEP_S`, also across a restarted window: the
    three readings of different instants must never share a stamp downstream.
    """

    def __init__(self, latency=0.0, window=200, max_gap_s=1.0):
        self.latency = float(latency)
        self.window = int(window)
        self.max_gap_s = float(max_gap_s)
        self._last_stamp = None  # kept across reset(): host time only grows
        self.reset()

    def reset(self):
        self._last_device_s = None
        self._offsets = []
        self._offset = None  # the offset of the last stamp (s)

    def stamp(self, device_time_us, receive_s):
        """Host time (s) of the instant of a line with ``device_time_us`` received at
        ``receive_s`` (s, host clock)."""
        device_s = device_time_us * 1e-6
        step = None
        if self._last_device_s is not None:
            step = device_s - self._last_device_s
            if step < 0.0 or step > self.max_gap_s:
                self._offsets, self._offset, step = [], None, None
        self._last_device_s = device_s
        self._offsets.append(receive_s - device_s)
        if len(self._offsets) > self.window:
            del self._offsets[0]
        offset = min(self._offsets)
        if step is not None and self._offset is not None:
            offset = max(offset, self._offset - 0.5 * step)
        self._offset = offset
        stamp = device_s + offset - self.latency
        if self._last_stamp is not None and stamp < self._last_stamp + MIN_STAMP_STEP_S:
            stamp = self._last_stamp + MIN_STAMP_STEP_S
        self._last_stamp = stamp
        return stamp
