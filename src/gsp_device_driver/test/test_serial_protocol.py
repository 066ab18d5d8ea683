"""The serial line protocol: framing, checksum, units, range checks and the stamping rule, and
the spec's test vectors (docs/serial_test_vectors.json) through the parser and the backend."""

import json
import math
import pathlib

import numpy as np
import pytest

from gsp_device_driver import serial_check
from gsp_device_driver.serial_protocol import (
    ANGLE_UNITS,
    LENGTH_UNITS,
    MIN_STAMP_STEP_S,
    PROTOCOL_VERSION,
    REQUEST_LINE,
    DeviceClock,
    Hello,
    LineError,
    Reading,
    checksum,
    format_hello,
    format_number,
    format_reading,
    frame,
    is_request,
    parse_line,
)

READING = Reading(7, 123456, 0.01, -0.02, 0.3, 0.25)
#: The spec's test vectors, read where firmware writers find them (the repository's docs/).
VECTORS_PATH = pathlib.Path(__file__).resolve().parents[3] / 'docs' / 'serial_test_vectors.json'
VECTORS = json.loads(VECTORS_PATH.read_text(encoding='ascii'))


@pytest.mark.parametrize('case', VECTORS['lines'], ids=lambda case: case['name'])
def test_each_line_vector_gives_its_outcome(case):
    assert serial_check.line_mismatch(case) == ''


@pytest.mark.parametrize('case', VECTORS['sequences'], ids=lambda case: case['name'])
def test_each_sequence_vector_publishes_drops_and_counts_as_specified(case):
    assert serial_check.sequence_mismatch(case) == ''


def test_the_vectors_request_line_is_the_drivers():
    assert VECTORS['request_line'].encode('latin-1') == REQUEST_LINE
    assert is_request(REQUEST_LINE) and VECTORS['protocol_version'] == PROTOCOL_VERSION


def test_the_vector_check_reports_a_driver_that_disagrees(tmp_path):
    # A vector whose expectation is wrong must be reported: the check is not vacuous.
    wrong = dict(VECTORS['lines'][0], reading=dict(VECTORS['lines'][0]['reading'], d_m=0.3))
    assert 'd_m' in serial_check.line_mismatch(wrong)
    sequence = VECTORS['sequences'][0]
    # Without its two readings before the hello, nothing is dropped for want of a hello.
    without = dict(sequence, lines=sequence['lines'][2:])
    assert "expected {'no_hello': 2}" in serial_check.sequence_mismatch(without)


def test_the_request_is_sent_when_the_port_opens():
    _, _, port = serial_check.read_through_backend(b'', 'rad', 'm')
    assert port.written[0] == REQUEST_LINE


@pytest.mark.parametrize('angle_unit', list(ANGLE_UNITS))
@pytest.mark.parametrize('length_unit', list(LENGTH_UNITS))
def test_a_formatted_reading_parses_back_in_every_unit(angle_unit, length_unit):
    line = format_reading(READING, angle_unit, length_unit)
    assert line.endswith(b'\r\n') and line.startswith(b'$GSP,7,123456,')
    parsed = parse_line(line, angle_unit, length_unit)
    assert (parsed.seq, parsed.device_time_us) == (7, 123456)
    for name in ('alpha', 'beta', 'phi', 'd_m'):
        assert getattr(parsed, name) == pytest.approx(getattr(READING, name), rel=1e-8)


def test_the_checksum_is_the_xor_of_the_body_like_nmea():
    # Worked example of docs/hardware.md.
    line = b'$GSP,0,0,0,0,0,0.25,0*' + f'{checksum("GSP,0,0,0,0,0,0.25,0"):02X}\r\n'.encode()
    assert parse_line(line).d_m == 0.25
    assert checksum('GSP') == ord('G') ^ ord('S') ^ ord('P')


def test_hello_line_round_trip():
    hello = parse_line(format_hello('board-3', 'urad', 'um', 500.0))
    assert hello == Hello(PROTOCOL_VERSION, 'board-3', 'urad', 'um', 500.0)


def _body_line(body):
    return frame(body)


@pytest.mark.parametrize(
    'line, reason',
    [
        (b'garbage\r\n', 'garbage'),
        (b'\xff\xfe$GSP*00\r\n', 'garbage'),
        (b'$GSP,1,2,0,0,0,0.2,0*00\r\n', 'checksum'),
        (_body_line('GSP,1,2,0,0,0,0.2'), 'garbage'),  # a field missing
        (_body_line('GSP,x,2,0,0,0,0.2,0'), 'garbage'),
        (_body_line('GSP,1,2,zero,0,0,0.2,0'), 'garbage'),
        (_body_line('GSP,1,2,nan,0,0,0.2,0'), 'garbage'),  # not a number of the grammar
        (_body_line('GSP,1,2,0,0,0,0.2,4'), 'status'),
        (_body_line('GSP,1,2,0,2.0,0,0.2,0'), 'range'),  # beta 2 rad: degrees?
        (_body_line('GSP,1,2,0,0,7,0.2,0'), 'range'),
        (_body_line('GSP,1,2,0,0,0,250,0'), 'range'),  # 250 m: millimetres?
        (_body_line('NMEA,1,2'), 'garbage'),
        (_body_line('GSPHELLO,1,dev,rad,m,2e2'), 'garbage'),
        (b'$' + b'1' * 200 + b'*00\r\n', 'garbage'),
    ],
)
def test_bad_lines_raise_with_their_reason(line, reason):
    with pytest.raises(LineError) as caught:
        parse_line(line)
    assert caught.value.reason == reason


def test_status_names_the_faulty_sensor():
    with pytest.raises(LineError, match='LVDT fault'):
        parse_line(_body_line('GSP,1,2,0,0,0,0.2,4'))


def test_an_unknown_unit_in_a_hello_is_reported_not_refused_by_the_parser():
    # The backend decides (drops the readings, counted as 'units'): the parser keeps what it said.
    hello = parse_line(_body_line('GSPHELLO,1,dev,furlong,m,200'))
    assert hello.angle_unit == 'furlong' and not hello.units_known


@pytest.mark.parametrize('value', [1e-5, -3.25e-7, 123456.789, 0.1, 2.0**-30])
def test_format_number_prints_no_exponent_and_reads_back_exactly(value):
    text = format_number(value)
    assert 'e' not in text.lower() and float(text) == value


def test_degrees_are_converted_to_radians():
    parsed = parse_line(_body_line('GSP,1,2,1,-1,90,200,0'), 'deg', 'mm')
    assert parsed.alpha == pytest.approx(math.radians(1)) and parsed.d_m == pytest.approx(0.2)


def test_device_clock_keeps_the_least_delayed_offset():
    clock = DeviceClock(latency=0.001)
    # The device ticks every 5 ms; the host receives each line 2 ms + jitter later, from 100 s.
    delays = [0.004, 0.002, 0.009, 0.003, 0.002]
    stamps = [clock.stamp(k * 5000, 100.0 + k * 0.005 + d) for k, d in enumerate(delays)]
    # After the least-delayed line, each stamp is device time + 100 + 2 ms - 1 ms latency.
    for k in range(1, 5):
        assert stamps[k] == pytest.approx(100.0 + k * 0.005 + 0.001, abs=1e-9)
    assert stamps[0] == pytest.approx(100.004 - 0.001)


def test_device_clock_stamps_keep_device_order_after_a_backlog():
    clock = DeviceClock()
    # The first lines wait 30 ms in a backlog (a loaded host), then arrive 1 ms late: the lower
    # offset is slewed in by half a device step per line instead of stepping the stamps back.
    delays = [0.030, 0.0255, 0.021] + [0.001] * 17
    stamps = [clock.stamp(k * 5000, 100.0 + k * 0.005 + d) for k, d in enumerate(delays)]
    assert all(b - a >= 0.0025 - 1e-12 for a, b in zip(stamps, stamps[1:], strict=False))
    # 29 ms slewed in at 2.5 ms per line: converged to the least delay within 12 lines.
    assert stamps[-1] == pytest.approx(100.0 + 19 * 0.005 + 0.001)


def test_device_clock_restarts_after_a_reboot_or_a_gap():
    clock = DeviceClock()
    clock.stamp(1_000_000, 50.0)
    assert clock.stamp(10, 60.0) == pytest.approx(60.0)  # device time went back: reboot
    assert clock.stamp(5_000_010, 70.0) == pytest.approx(70.0)  # 5 s gap > max_gap_s


def test_device_clock_stamps_a_backlog_in_device_order():
    # A reader late at start-up takes 4 queued lines (5 ms apart) at once, then the next on time:
    # each backlog line's own offset is the least so far, which alone would give all four the
    # receive time, and the on-time line one earlier than theirs.
    clock = DeviceClock()
    stamps = [clock.stamp(k * 5000, 10.0) for k in range(4)] + [clock.stamp(20_000, 10.0001)]
    assert np.all(np.diff(stamps) >= MIN_STAMP_STEP_S - 1e-12)
    assert stamps[0] == pytest.approx(10.0)
