"""The serial backend against the reference emulator on a pty: good lines, faults, unplugging,
the hello rules, health() and the order of stamps beside a CPU hog."""

import itertools
import os
import subprocess
import sys
import threading
import time

import gsp_testing
import numpy as np
import pytest

from gsp_device_driver.backends import backend_class
from gsp_device_driver.fake_device import FakeDevice, TruthFeed
from gsp_device_driver.serial_backend import SerialDeviceBackend
from gsp_device_driver.serial_protocol import MIN_STAMP_STEP_S
from gsp_msgs_py import health

TIMEOUT_S = 20.0
VALUES = np.array([0.01, -0.02, 0.3, 0.25])


def wait_until(predicate, timeout=TIMEOUT_S):
    return gsp_testing.wait_until(predicate, timeout)


@pytest.fixture
def link(tmp_path):
    return tmp_path / 'gsp_device'


def make_pair(link, readings=lambda: VALUES, backend_options=None, **fake_options):
    backend = SerialDeviceBackend(
        str(link), timeout=0.05, reconnect_interval=0.05, **(backend_options or {})
    )
    backend.start()  # before the device: it waits for the port to appear
    fake = FakeDevice(link, readings, rng=np.random.default_rng(1), **fake_options)
    # Paused until the backend has the hello (asked for at opening, which flushes what was
    # queued before): no reading is then dropped for want of a hello.
    fake.paused = True
    fake.start()
    assert wait_until(lambda: backend.counters['hello'] >= 1)
    fake.paused = False
    return backend, fake


def drain(backend, fake):
    """Pause the emulator and wait until the backend has read every line it sent."""
    fake.paused = True

    def sent():  # hello lines are left out: the first may go before the port was opened
        return sum(fake.counters[k] for k in ('readings', 'garbage', 'checksum_errors'))

    def read():
        return backend.counters['lines'] - backend.counters['hello']

    assert wait_until(lambda: read() == sent()), (backend.counters, fake.counters)


def test_the_serial_backend_is_registered_with_its_parameters():
    assert backend_class('serial') is SerialDeviceBackend
    names = [spec.name for spec in SerialDeviceBackend.PARAMETERS]
    assert names[:5] == ['port', 'baud', 'timeout', 'angle_unit', 'length_unit']
    assert 'latency' in names


def test_garbage_lines_are_dropped_and_each_counted(link):
    backend, fake = make_pair(link, garbage_fraction=0.05, checksum_error_fraction=0.02)
    try:
        assert wait_until(lambda: fake.counters['readings'] >= 200)
        fake.skip(7)  # seven lines lost on the way: a seq gap
        assert wait_until(lambda: fake.counters['readings'] >= 400)
        drain(backend, fake)
        assert fake.counters['garbage'] > 0 and fake.counters['checksum_errors'] > 0
        assert backend.counters['garbage'] == fake.counters['garbage']
        assert backend.counters['checksum'] == fake.counters['checksum_errors']
        assert backend.counters['readings'] == fake.counters['readings']
        samples = backend.read_available(1000.0)
        assert len(samples) == fake.counters['readings']
        np.testing.assert_allclose([s.readings() for s in samples], [VALUES] * len(samples))
        stamps = np.array([s.stamp_s for s in samples])
        assert np.all(np.diff(stamps) > 0)  # device time orders them
        assert backend.hello.device_id == 'gsp-fake-device'
        # Every dropped or lost line is in health(): garbage is not counted lost as well.
        values = backend.health().values
        assert int(values['dropped_garbage']) == fake.counters['garbage']
        assert int(values['dropped_checksum']) == fake.counters['checksum_errors']
        assert int(values['readings_published']) == len(samples)
        assert fake.counters['skipped'] == 7
        assert int(values['lost_lines']) == fake.counters['skipped'] + fake.counters['lost']
    finally:
        fake.close()
        backend.close()


def test_a_silence_is_reported_and_the_stream_resumes(link):
    backend, fake = make_pair(link)
    try:
        assert wait_until(lambda: backend.counters['readings'] >= 10)
        fake.silence(1.0)
        messages = []
        assert wait_until(
            lambda: messages.extend(backend.messages()) or any('again' in t for _, t in messages)
        )
        assert any('no line from the device' in text for _, text in messages)
    finally:
        fake.close()
        backend.close()


def test_unplug_and_replug_resume_without_a_restart_with_one_warning(link):
    backend, fake = make_pair(link)
    try:
        assert wait_until(lambda: backend.counters['readings'] >= 10)
        backend.messages()
        backend.health()
        fake.disconnect(0.3)
        assert wait_until(lambda: backend.counters['disconnects'] == 1)
        assert backend.health().level == health.ERROR
        before = backend.counters['readings']
        assert wait_until(
            lambda: backend.counters['connects'] >= 2 and backend.counters['readings'] > before + 10
        )
        warnings = [text for level, text in backend.messages() if level == 'warning']
        # One warning for the outage, not a second one for the failed reopen attempts.
        outage = [text for text in warnings if 'lost' in text or 'cannot open' in text]
        assert len(outage) == 1 and 'reconnecting' in outage[0], warnings
        backend.health()
        assert wait_until(lambda: backend.health().level == health.OK)
    finally:
        fake.close()
        backend.close()


def test_a_late_driver_asks_for_the_hello_instead_of_waiting(link):
    # The device says hello only at its start (before the port was opened: flushed) and when
    # asked: the driver's request gets the readings going.
    fake = FakeDevice(link, lambda: VALUES, hello_period_s=0.0).start()
    backend = SerialDeviceBackend(str(link), timeout=0.05, reconnect_interval=0.05)
    backend.start()
    try:
        assert wait_until(lambda: backend.counters['readings'] >= 20)
        assert fake.counters['requests'] >= 1 and backend.hello.device_id == 'gsp-fake-device'
        samples = backend.read_available(0.0)
        np.testing.assert_allclose([s.readings() for s in samples], [VALUES] * len(samples))
    finally:
        fake.close()
        backend.close()


def test_firmware_in_other_units_publishes_nothing_with_one_warning_and_an_error(link):
    # The case: firmware printing mrad/mm to a driver set to urad/um.
    backend, fake = make_pair(
        link,
        backend_options={'angle_unit': 'urad', 'length_unit': 'um'},
        angle_unit='mrad',
        length_unit='mm',
    )
    try:
        assert wait_until(lambda: backend.counters['lines'] >= 60)
        assert backend.counters['readings'] == 0 and backend.read_available(0.0) == []
        assert backend.counters['units'] >= 50
        warnings = [text for level, text in backend.messages() if level == 'warning']
        told = [text for text in warnings if 'serial.angle_unit' in text]
        # Repeated only every REFUSAL_WARNING_PERIOD_S (10 s) while it lasts.
        assert len(told) == 1 and 'mrad/mm' in told[0] and 'urad/um' in told[0], warnings
        report = backend.health()
        assert report.level == health.ERROR and 'mrad/mm' in report.message
        assert int(report.values['dropped_units']) >= 50
    finally:
        fake.close()
        backend.close()


def test_a_summary_of_drops_is_logged_while_lines_are_dropped(link):
    backend, fake = make_pair(
        link, backend_options={'drop_summary_period': 0.2}, garbage_fraction=0.2
    )
    try:
        messages = []
        assert wait_until(
            lambda: (
                messages.extend(backend.messages())
                or any('dropped or lost' in text for _, text in messages)
            )
        )
        summary = next(text for _, text in messages if 'dropped or lost' in text)
        assert 'garbage' in summary, summary
        assert backend.health().level == health.WARN
    finally:
        fake.close()
        backend.close()


def _cpu_hogs(seconds):
    """One busy loop per core, each ending by itself after ``seconds`` (killed sooner)."""
    code = f'import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end: pass'
    return [subprocess.Popen([sys.executable, '-c', code]) for _ in range(os.cpu_count() or 2)]


def test_stamps_grow_and_are_never_early_beside_a_cpu_hog(link):
    # The node's clock is another clock than the backend's monotonic one (as ROS time is); the
    # consumer reads it and then the backend, as the node's timer does.
    node_offset_s = 1000.0

    def node_clock():
        return time.monotonic() + node_offset_s

    count = itertools.count()
    backend, fake = make_pair(
        link,
        # d_m numbers the readings: each sample is matched to its true sampling instant.
        readings=lambda: [0.0, 0.0, 0.0, 0.1 + next(count) * 1e-6],
        backend_options={'stamp_clock': node_clock},
        record_sampling=True,
    )
    hogs = _cpu_hogs(120)
    samples, stop = [], threading.Event()

    def consume():
        while not stop.is_set():
            now_s = node_clock()
            samples.extend(backend.read_available(now_s))
            stop.wait(0.005)

    def hold_the_gil():  # Python work in the driver's process (the calibrator's, in a launch)
        while not stop.is_set():
            sum(range(1000))

    threads = [threading.Thread(target=consume), threading.Thread(target=hold_the_gil)]
    for thread in threads:
        thread.start()
    try:
        assert wait_until(lambda: len(samples) >= 1000, timeout=60.0)
    finally:
        stop.set()
        for thread in threads:
            thread.join()
        for hog in hogs:
            hog.kill()
            hog.wait()
        fake.close()
        backend.close()
    truth = {round((r.d_m - 0.1) * 1e6): t for t, r in list(fake.sampling_log)}
    stamps = np.array([s.stamp_s - node_offset_s for s in samples])
    sampled = np.array([truth[round((s.d_m - 0.1) * 1e6)] for s in samples])
    steps = np.diff(stamps)
    # Early: before the sampling instant by more than the bound (latency 0, the device's t_us
    # truncated to 1 us, and float rounding at 1000 s well under 1 ns).
    early = stamps < sampled - (1e-6 + 1e-9)
    assert np.count_nonzero(steps < MIN_STAMP_STEP_S - 1e-9) == 0, steps.min()
    assert np.count_nonzero(early) == 0, (np.count_nonzero(early), (sampled - stamps).max())


def test_units_that_disagree_with_the_hello_line_drop_the_readings(link):
    backend, fake = make_pair(link, angle_unit='deg')
    try:
        assert wait_until(lambda: backend.counters['units'] >= 5)
        assert backend.counters['readings'] == 0
        assert any('serial.angle_unit' in text for _, text in backend.messages())
    finally:
        fake.close()
        backend.close()


def test_a_missing_port_is_a_warning_and_a_retry(tmp_path):
    backend = SerialDeviceBackend(str(tmp_path / 'absent'), timeout=0.05, reconnect_interval=0.05)
    backend.start()
    try:
        messages = []
        assert wait_until(lambda: messages.extend(backend.messages()) or messages)
        assert messages[0][0] == 'warning' and 'cannot open' in messages[0][1]
    finally:
        backend.close()


def test_health_warns_while_readings_wait_for_a_hello():
    from gsp_device_driver.serial_check import ScriptedPort
    from gsp_device_driver.serial_protocol import Reading, format_reading

    lines = b''.join(format_reading(Reading(k, 5000 * k, *VALUES)) for k in range(30))
    port = ScriptedPort(lines, timeout=0.01)
    backend = SerialDeviceBackend('scripted', timeout=0.01, serial_factory=lambda *_: port)
    backend.start()
    try:
        assert port.drained.wait(TIMEOUT_S)
        report = backend.health()
        assert report.level == health.WARN and 'hello' in report.message
        assert report.values['dropped_no_hello'] == '30' and report.values['last_hello'] == ''
        assert float(report.values['line_rate_hz']) > 0.0
        assert backend.read_available(0.0) == []
    finally:
        backend.close()


def test_fake_device_takes_the_sensor_dynamics_options():
    from gsp_device_driver.fake_device_node import parse_arguments

    args, _ = parse_arguments(['--port', 'p', '--inclinometer-response-time', '0.3'])
    assert args.inclinometer_response_time == 0.3 and args.lvdt_noise_correlation_time == 0.0
    with pytest.raises(SystemExit):
        parse_arguments(['--port', 'p', '--encoder-noise-correlation-time', '-1'])


def test_the_truth_feed_gives_each_pose_once_and_never_an_older_one():
    feed = TruthFeed()
    assert feed.take() is None
    feed.put('A', 10.0)
    assert feed.take() == ('A', 10.0)
    assert feed.take() is None  # stalled: nothing, not 'A' again
    feed.put('late', 9.5)  # older than what was sent
    assert feed.take() is None
    feed.put('B', 10.005)
    feed.put('C', 10.010)
    assert feed.take() == ('C', 10.010)


def test_a_stalled_truth_sends_no_line_and_a_line_carries_its_pose_instant(link):
    """A loaded host: the true pose the emulator measures stops coming. Each pose goes out once,
    at the instant it describes; the device must not repeat an old pose under new t_us (ten such
    consistent lines after a settled status were averaged as the settled posture)."""
    feed = TruthFeed()

    def readings():
        taken = feed.take()
        return None if taken is None else (VALUES + [0.0, 0.0, 0.0, taken[0] * 1e-6], taken[1])

    backend, fake = make_pair(
        link, readings, timed_readings=True, record_sampling=True, hello_period_s=0.02
    )
    try:
        instant = time.monotonic()
        feed.put(7, instant)
        assert wait_until(lambda: backend.counters['readings'] >= 1)
        hellos = fake.counters['hello']
        # At least 4 device periods without a new pose (the hello lines mark the ticks).
        assert wait_until(lambda: fake.counters['hello'] >= hellos + 2)
        drain(backend, fake)
        assert fake.counters['readings'] == 1, fake.counters
        sampled, reading = fake.sampling_log[0]
        assert sampled == instant  # the pose's instant, not the time the line went out
        assert reading.d_m == pytest.approx(VALUES[3] + 7e-6, abs=1e-12)
    finally:
        fake.close()
        backend.close()
