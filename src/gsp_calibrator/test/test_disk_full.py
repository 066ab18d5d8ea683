"""A disk that fills up mid-run (issue 10): the run ends naming the file and the cause, every row
written before is kept, the node lives on and a later resume continues (docs/faults.md).

The full disk is injected: the writes of samples.csv, state.json or the recording raise ENOSPC
(the machine has no tmpfs to fill)."""

import errno
import os

import numpy as np
import pytest
from std_srvs.srv import Trigger
from synthetic import synthetic_samples
from test_calibrator_node import make_suite, perturbed_truth

from gsp_calibrator.recording import mcap_io
from gsp_calibrator.recording import recorder as recording
from gsp_calibrator.run import directory as run_directory
from gsp_calibrator.run import session as run_session
from gsp_calibrator.run import state as run_state
from gsp_calibrator.run.directory import SamplesAppender, read_samples, write_samples
from gsp_msgs_py import names

NO_SPACE = os.strerror(errno.ENOSPC)


def _full_disk():
    return OSError(errno.ENOSPC, NO_SPACE)


def test_a_failed_append_leaves_no_half_row_and_names_the_file(tmp_path, monkeypatch):
    path = tmp_path / 'samples.csv'
    samples = synthetic_samples(count=3)
    write_samples(path, run_directory.Samples.empty())
    appender = SamplesAppender(path)
    appender.append(samples, 0)
    appender.append(samples, 1)

    def torn_write(self, data):  # half the row reaches the file, then the disk is full
        os.write(self._fd, data[: len(data) // 2])
        raise _full_disk()

    monkeypatch.setattr(SamplesAppender, '_write', torn_write)
    with pytest.raises(OSError, match=NO_SPACE) as raised:
        appender.append(samples, 2)
    assert raised.value.filename == str(path)
    appender.close()
    kept = read_samples(path)
    assert len(kept) == 2
    np.testing.assert_array_equal(kept.leg_lengths, samples.leg_lengths[:2])


def test_a_row_cut_by_a_crash_is_dropped_when_the_file_is_appended_again(tmp_path):
    path = tmp_path / 'samples.csv'
    samples = synthetic_samples(count=2)
    write_samples(path, samples)
    with open(path, 'a') as stream:
        stream.write('3,0.1,0.2')  # a torn row, no newline
    appender = SamplesAppender(path)
    appender.append(samples, 1)
    appender.close()
    kept = read_samples(path)
    assert list(kept.posture) == [samples.posture[0], samples.posture[1], samples.posture[1]]


def test_a_state_json_that_cannot_be_written_keeps_the_previous_one(tmp_path, monkeypatch):
    session = run_session.RunSession.create(tmp_path)
    session.state = run_state.RunState({'seed': 1}, np.zeros((2, 6)).tolist())
    session.save(run_state.PHASE_COLLECTING)

    def full(path, text):
        raise _full_disk()

    monkeypatch.setattr(run_session, 'atomic_write_text', full)
    with pytest.raises(run_session.RunWriteError) as raised:
        session.save(run_state.PHASE_FAILED, 'x')
    assert str(raised.value) == f'cannot write {session.run.path / "state.json"}: {NO_SPACE}'
    assert run_state.read_state(session.run.path).phase == run_state.PHASE_COLLECTING


def _run_failed_on(suite, tmp_path, name):
    """Calibrate; the run fails naming ``name`` in its directory and the full disk. Its path."""
    response = suite.wait(suite.call())
    assert not response.success
    (run,) = list((tmp_path / 'runs').iterdir())
    assert f'cannot write {run / name}: {NO_SPACE}' in response.message, response.message
    return run


@pytest.fixture
def truth_file(tmp_path):
    perturbed_truth(tmp_path / 'true.yaml')
    return tmp_path / 'true.yaml'


def test_a_full_disk_mid_run_ends_it_keeps_the_rows_and_resume_continues(
    ros_context, tmp_path, truth_file, monkeypatch
):
    disk = {'full': True, 'rows': 0}
    real_write = SamplesAppender._write

    def write(self, data):
        if disk['full'] and disk['rows'] >= 3:
            os.write(self._fd, data[: len(data) // 2])
            raise _full_disk()
        disk['rows'] += 1
        return real_write(self, data)

    monkeypatch.setattr(SamplesAppender, '_write', write)
    suite, calibrator, _, _ = make_suite(ros_context, tmp_path, truth_file)
    try:
        run = _run_failed_on(suite, tmp_path, 'samples.csv')
        kept = read_samples(run / 'samples.csv')
        assert len(kept) == 3  # every complete row, no half row
        state = run_state.read_state(run)
        assert state.phase == run_state.PHASE_FAILED and NO_SPACE in state.stop_reason
        assert sorted(state.done) == sorted(kept.posture.tolist())

        disk['full'] = False  # space freed: the same node resumes the run
        client = suite.client_node.create_client(Trigger, names.SERVICE_RESUME)
        assert client.wait_for_service(timeout_sec=30.0)
        response = suite.wait(client.call_async(Trigger.Request()))
        assert response.success, response.message
        rows = read_samples(run / 'samples.csv')
        np.testing.assert_array_equal(rows.leg_lengths[:3], kept.leg_lengths)
        assert len(rows) + len(run_state.read_state(run).skipped) == 12
        assert run_state.read_state(run).phase == run_state.PHASE_DONE
    finally:
        suite.close()


def test_a_recording_that_cannot_be_written_ends_the_run_and_keeps_its_messages(
    ros_context, tmp_path, truth_file, monkeypatch
):
    real_flush = mcap_io.McapRecorder._flush_if_crash_safe
    written = {'messages': 0}

    def flush(self):
        count = getattr(self, 'message_count', 0)
        if count >= 400:
            raise _full_disk()
        written['messages'] = count
        real_flush(self)

    monkeypatch.setattr(mcap_io.McapRecorder, '_flush_if_crash_safe', flush)
    suite, calibrator, _, _ = make_suite(ros_context, tmp_path, truth_file)
    try:
        run = _run_failed_on(suite, tmp_path, 'recording.mcap.tmp')
        assert run_state.read_state(run).phase == run_state.PHASE_FAILED
        suite.wait_until(lambda: (run / 'recording.mcap').exists())
        messages = list(recording.read_recording(run / 'recording.mcap'))
        assert len(messages) >= written['messages'] > 0
        # The node lives on: a second call is served (and fails on the same full disk).
        assert not suite.wait(suite.call()).success
    finally:
        suite.close()
