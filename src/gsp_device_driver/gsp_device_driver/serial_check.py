"""``gsp_serial_check``: check a device's serial output, or the driver, against the protocol
(docs/hardware.md section 1)."""

import argparse
import json
import math
import sys
import threading
import time

from gsp_kinematics.channels import READING_NAMES

from .serial_backend import SerialDeviceBackend
from .serial_gate import BACKEND_DROP_REASONS
from .serial_protocol import ANGLE_UNITS, LENGTH_UNITS, Hello, LineError, parse_line

#: |published - expected| allowed for a vector (rad, m): far below any unit's quantisation.
VALUE_TOLERANCE = 1e-12
READ_TIMEOUT_S = 30.0  #: safety net: a backend that never reads the scripted data fails loudly


def line_outcome(case):
    """The outcome of one ``lines`` vector through :func:`parse_line`, in the vector's terms:
    ``('reading', {...})``, ``('hello', {...})``, ``('drop', reason)`` or ``('ignored', None)``."""
    try:
        parsed = parse_line(case['line'].encode('latin-1'), case['angle_unit'], case['length_unit'])
    except LineError as error:
        return 'drop', error.reason
    if parsed is None:
        return 'ignored', None
    if isinstance(parsed, Hello):
        return 'hello', {
            'version': parsed.version,
            'device_id': parsed.device_id,
            'angle_unit': parsed.angle_unit,
            'length_unit': parsed.length_unit,
            'rate_hz': parsed.rate_hz,
        }
    return 'reading', {
        'seq': parsed.seq,
        't_us': parsed.device_time_us,
        **{name: getattr(parsed, name) for name in READING_NAMES},
    }


def _close(a, b):
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(a, b, rel_tol=0.0, abs_tol=VALUE_TOLERANCE)
    return a == b


def line_mismatch(case):
    """'' if the driver gives ``case``'s expected outcome, else what differs."""
    kind, detail = line_outcome(case)
    expected = case['expect']
    if kind != expected:
        return f'expected {expected}, got {kind} {detail!r}'
    if kind == 'drop' and detail != case['reason']:
        return f'expected drop {case["reason"]!r}, got drop {detail!r}'
    if kind in ('reading', 'hello'):
        wrong = {
            key: (value, detail[key])
            for key, value in case[kind].items()
            if not _close(value, detail[key])
        }
        if wrong:
            return f'{kind} fields differ (expected, got): {wrong}'
    return ''


class ScriptedPort:
    """A port that delivers ``data`` in one read, then nothing (a read timeout each call);
    :attr:`drained` is set at the first read after the data: the reader has handled it all."""

    def __init__(self, data, timeout):
        self._data = data
        self._timeout = timeout
        self.written = []
        self.drained = threading.Event()

    @property
    def in_waiting(self):
        return len(self._data)

    def read(self, size):
        if self._data:
            data, self._data = self._data, b''
            return data
        self.drained.set()
        time.sleep(self._timeout)  # a read timeout, as on an idle port
        return b''

    def write(self, data):
        self.written.append(bytes(data))
        return len(data)

    def close(self):
        self.drained.set()


def read_through_backend(data, angle_unit, length_unit, trust_configured_units=False):
    """Feed ``data`` (bytes, from the opening of the port) to a serial backend; returns
    ``(backend, samples, port)`` once every line is handled (the backend is closed)."""
    port = ScriptedPort(data, timeout=0.01)
    backend = SerialDeviceBackend(
        'scripted',
        timeout=0.01,
        angle_unit=angle_unit,
        length_unit=length_unit,
        trust_configured_units=trust_configured_units,
        serial_factory=lambda *_: port,
    )
    backend.start()
    try:
        if not port.drained.wait(READ_TIMEOUT_S):
            raise TimeoutError(f'the serial backend did not read the data in {READ_TIMEOUT_S} s')
    finally:
        backend.close()
    return backend, backend.read_available(0.0), port


def sequence_mismatch(case):
    """'' if the backend publishes, drops and counts what ``case`` expects, else what differs."""
    data = ''.join(case['lines']).encode('latin-1')  # one byte per character
    units = case['angle_unit'], case['length_unit'], case['trust_configured_units']
    backend, samples, _ = read_through_backend(data, *units)
    expect = case['expect']
    problems = []
    published = [sample.readings().tolist() for sample in samples]
    if len(published) != len(expect['published']) or not all(
        _close(float(a), float(b))
        for got, want in zip(published, expect['published'], strict=False)
        for a, b in zip(got, want, strict=True)
    ):
        problems.append(f'published {published}, expected {expect["published"]}')
    drops = {k: backend.counters[k] for k in BACKEND_DROP_REASONS if backend.counters[k]}
    if drops != expect['drops']:
        problems.append(f'drops {drops}, expected {expect["drops"]}')
    for key in ('lost', 'resets'):
        if backend.counters[key] != expect[key]:
            problems.append(f'{key} {backend.counters[key]}, expected {expect[key]}')
    return '; '.join(problems)


def check_vectors(path, out=sys.stdout):
    """Run every vector of ``path`` through this driver; the number of mismatches."""
    with open(path, encoding='ascii') as file:
        vectors = json.load(file)
    failures = 0
    for group, check in (('lines', line_mismatch), ('sequences', sequence_mismatch)):
        for case in vectors[group]:
            problem = check(case)
            if problem:
                failures += 1
                print(f'FAIL {group}: {case["name"]}: {problem}', file=out)
        print(f'{group}: {len(vectors[group])} vectors checked', file=out)
    print('all vectors pass' if not failures else f'{failures} vectors fail', file=out)
    return failures


def report(backend, out=sys.stdout):
    """Print what the backend saw (its messages, counters, health and the first dropped lines);
    True if it published readings and dropped and lost none."""
    for level, text in backend.messages():
        print(f'{level}: {text}', file=out)
    counters = backend.counters
    health = backend.health()
    for key, value in health.values.items():
        print(f'{key}: {value}', file=out)
    for reason, text, line in backend.first_drops:
        print(f'dropped ({reason}): {text}: {line!r}', file=out)
    dropped = sum(counters[reason] for reason in BACKEND_DROP_REASONS)
    ok = counters['readings'] > 0 and not dropped and not counters['lost']
    print('OK: every line accepted' if ok else 'FAIL: see the drops above', file=out)
    return ok


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog='gsp_serial_check', description='Check serial output against the GSP line protocol.'
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--port', help='serial port of the device (asks for its hello)')
    source.add_argument('--capture', help='file of recorded device output')
    source.add_argument('--vectors', help='test-vector file to run through this driver')
    parser.add_argument('--baud', type=int, default=115200)
    parser.add_argument('--duration', type=float, default=5.0, help='s to read --port (5)')
    parser.add_argument('--angle-unit', default='rad', choices=tuple(ANGLE_UNITS))
    parser.add_argument('--length-unit', default='m', choices=tuple(LENGTH_UNITS))
    args = parser.parse_args(argv)
    if args.vectors:
        return 1 if check_vectors(args.vectors) else 0
    if args.capture:
        with open(args.capture, 'rb') as file:
            backend, _, _ = read_through_backend(file.read(), args.angle_unit, args.length_unit)
    else:
        backend = SerialDeviceBackend(
            args.port, args.baud, angle_unit=args.angle_unit, length_unit=args.length_unit
        )
        backend.start()
        time.sleep(args.duration)  # a command-line tool reading for the asked duration
        backend.close()
    return 0 if report(backend) else 1


if __name__ == '__main__':
    raise SystemExit(main())
