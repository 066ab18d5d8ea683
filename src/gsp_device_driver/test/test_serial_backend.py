"""The serial backend against the reference emulator on a pty: good lines, faults, unplugging."""

import numpy as np
import pytest

from gsp_device_driver.backends import backend_class
from gsp_device_driver.fake_device import FakeDevice
from gsp_device_driver.serial_backend import SerialDeviceBackend, SerialSettings
from gsp_msgs_py import testing

TIMEOUT_S = 20.0
VALUES = np.array([0.01, -0.02, 0.3, 0.25])


def wait_until(predicate, timeout=TIMEOUT_S):
    return testing.wait_until(predicate, timeout)


@pytest.fixture
def link(tmp_path):
    return tmp_path / 'gsp_device'


def make_pair(link, **fake_options):
    backend = SerialDeviceBackend(SerialSettings(str(link), timeout=0.05, reconnect_interval=0.05))
    backend.start()  # before the device: it waits for the port to appear
    fake = FakeDevice(link, lambda: VALUES, rng=np.random.default_rng(1), **fake_options)
    # Paused until the backend has opened the port: opening flushes what was queued before.
    fake.paused = True
    fake.start()
    assert wait_until(lambda: backend.counters['connects'] == 1)
    fake.paused = False
    return backend, fake


def drain(backend, fake):
    """Pause the emulator and wait until the backend has read every line it sent."""
    fake.paused = True

    def sent():  # hello lines are left out: the first may go before the port was opened
        return sum(fake.count(k) for k in ('readings', 'garbage', 'checksum_errors'))

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
        assert wait_until(lambda: fake.count('readings') >= 400)
        drain(backend, fake)
        assert fake.count('garbage') > 0 and fake.count('checksum_errors') > 0
        assert backend.counters['garbage'] == fake.count('garbage')
        assert backend.counters['checksum'] == fake.count('checksum_errors')
        assert backend.counters['readings'] == fake.count('readings')
        samples = backend.read_available(1000.0)
        assert len(samples) == fake.count('readings')
        np.testing.assert_allclose([s.readings() for s in samples], [VALUES] * len(samples))
        stamps = np.array([s.stamp_s for s in samples])
        assert np.all(np.diff(stamps) > 0)  # device time orders them
        assert backend.hello.device_id == 'gsp-fake-device'
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


def test_unplug_and_replug_resume_without_a_restart(link):
    backend, fake = make_pair(link)
    try:
        assert wait_until(lambda: backend.counters['readings'] >= 10)
        fake.disconnect(0.3)
        assert wait_until(lambda: backend.counters['disconnects'] == 1)
        before = backend.counters['readings']
        assert wait_until(
            lambda: backend.counters['connects'] >= 2 and backend.counters['readings'] > before + 10
        )
        texts = [text for _, text in backend.messages()]
        assert any('lost' in text and 'reconnecting' in text for text in texts), texts
    finally:
        fake.close()
        backend.close()


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
    backend = SerialDeviceBackend(
        SerialSettings(str(tmp_path / 'absent'), timeout=0.05, reconnect_interval=0.05)
    )
    backend.start()
    try:
        messages = []
        assert wait_until(lambda: messages.extend(backend.messages()) or messages)
        assert messages[0][0] == 'warning' and 'cannot open' in messages[0][1]
    finally:
        backend.close()
