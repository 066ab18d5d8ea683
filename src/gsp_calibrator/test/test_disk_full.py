"""A disk that fills up mid-run (issue 10): the run ends naming the file and the cause, every row
written before is kept, the node lives on and a later resume continues (docs/faults.md).

The disk really fills: a small tmpfs (conftest ``small_disk``) filled until the kernel refuses,
so the writes of samples.csv, state.json and the recording fail in the kernel; in the node test
of the recording, its file alone is full after a number of bytes (full_disk.WriteLimit), so that
the recording, not another file, is the one to fail."""

import errno
import io
import os
import shutil

import numpy as np
import pytest
from calibrator_suite import make_suite, perturbed_truth
from full_disk import NO_SPACE, WriteLimit
from std_srvs.srv import Trigger
from synthetic import synthetic_samples

from gsp_calibrator.files.run_directory import SamplesAppender, read_samples, write_samples
from gsp_calibrator.recording import mcap_io
from gsp_calibrator.recording.mcap_io import read_recording, recording_info
from gsp_calibrator.recording.recorder import RECORDING_FILE
from gsp_calibrator.run.record import (
    PHASE_COLLECTING,
    PHASE_DONE,
    PHASE_FAILED,
    RunRecord,
    RunState,
    RunWriteError,
    read_state,
)
from gsp_msgs_py import conversions, names

PAGE = 4096  # bytes: tmpfs allocates pages; a write within the file's last page needs none


def _full_disk():
    return OSError(errno.ENOSPC, NO_SPACE)


def test_a_failed_append_leaves_no_half_row_and_names_the_file(small_disk):
    path = small_disk.path / 'samples.csv'
    samples = synthetic_samples(count=3)
    write_samples(path, samples)
    appender = SamplesAppender(path)
    small_disk.fill()
    # Rows still fit in the file's last page; the first that spans into a new page is written
    # in part by the kernel (a short write), then refused.
    appended = 0
    with pytest.raises(OSError) as raised:
        for _ in range(PAGE):
            appender.append(samples, appended % 3)
            appended += 1
    assert raised.value.errno == errno.ENOSPC and raised.value.filename == str(path)
    appender.close()
    kept = read_samples(path)  # every row complete: the torn one was cut back
    assert len(kept) == 3 + appended
    np.testing.assert_array_equal(
        kept.leg_lengths[3:], samples.leg_lengths[np.arange(appended) % 3]
    )
    assert path.read_bytes().endswith(b'\n')


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


def test_a_state_json_that_cannot_be_written_keeps_the_previous_one(small_disk):
    record = RunRecord.create(small_disk.path)
    record.state = RunState({'seed': 1}, np.zeros((2, 6)).tolist())
    record.save(PHASE_COLLECTING)
    files = sorted(os.listdir(record.directory.path))
    small_disk.fill()
    reason = 'x' * 2 * PAGE  # more than the old file's page: a rewrite in place would be torn
    with pytest.raises(RunWriteError) as raised:
        record.save(PHASE_FAILED, reason)
    assert str(raised.value) == f'cannot write {record.directory.path / "state.json"}: {NO_SPACE}'
    assert read_state(record.directory.path).phase == PHASE_COLLECTING
    assert sorted(os.listdir(record.directory.path)) == files  # no temporary file left behind
    small_disk.free()
    record.save(PHASE_FAILED, reason)
    assert read_state(record.directory.path).stop_reason == reason


def test_a_recording_on_a_full_disk_keeps_every_message_written(small_disk):
    path = small_disk.path / 'recording.mcap'
    recorder = mcap_io.McapRecorder(path, crash_safe=True)
    small_disk.fill()
    written = 0
    with pytest.raises(OSError) as raised:
        for j in range(PAGE):
            recorder.write(names.TOPIC_LVDT, conversions.lvdt_to_msg(1e-3 * j, j), j)
            written += 1
    assert raised.value.errno == errno.ENOSPC
    # Still full: the summary cannot be written, so nothing poses as a finished recording.
    with pytest.raises(OSError):
        recorder.close()
    assert not path.exists()
    small_disk.free()
    recovered = mcap_io.recover_recording(f'{path}.tmp')
    assert recovered['message_count'] == written > 0
    values = [m.position[0] for _, _, _, m, _ in read_recording(path)]
    np.testing.assert_allclose(values, 1e-3 * np.arange(written), rtol=0, atol=1e-15)


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
        state = read_state(run)
        assert state.phase == PHASE_FAILED and NO_SPACE in state.stop_reason
        assert sorted(state.done) == sorted(kept.posture.tolist())

        disk['full'] = False  # space freed: the same node resumes the run
        client = suite.client_node.create_client(Trigger, names.SERVICE_RESUME)
        assert client.wait_for_service(timeout_sec=30.0)
        response = suite.wait(client.call_async(Trigger.Request()))
        assert response.success, response.message
        rows = read_samples(run / 'samples.csv')
        np.testing.assert_array_equal(rows.leg_lengths[:3], kept.leg_lengths)
        assert len(rows) + len(read_state(run).skipped) == 12
        assert read_state(run).phase == PHASE_DONE
    finally:
        suite.close()


def test_a_recording_that_cannot_be_written_ends_the_run_and_keeps_its_messages(
    ros_context, tmp_path, truth_file, monkeypatch
):
    # The recording's file fills up mid-run, on an event and not after a number of bytes: the
    # streams are recorded from the start, so a byte count is reached at a time that depends on
    # how long the posture selection took, before the first row on a slow machine. Once the
    # third row of samples.csv is written, the recording has 1 KiB of room left (a write cut
    # short at the limit, then ENOSPC); its writes fail below the MCAP writer and its buffer.
    disk = {'full': True, 'bytes': 1 << 62, 'rows': 0}
    files = []
    rows_before_full = 3
    real_append = SamplesAppender.append

    def append_row(self, *args, **kwargs):
        real_append(self, *args, **kwargs)
        disk['rows'] += 1
        if disk['rows'] == rows_before_full:
            disk['bytes'] = files[0].written + 1024

    def open_recording(file, mode='r', *args, **kwargs):
        if mode == 'wb' and str(file).endswith(f'{RECORDING_FILE}.tmp'):
            files.append(WriteLimit(io.FileIO(file, 'w'), disk))
            return io.BufferedWriter(files[-1])
        return open(file, mode, *args, **kwargs)

    monkeypatch.setattr(mcap_io, 'open', open_recording, raising=False)
    monkeypatch.setattr(SamplesAppender, 'append', append_row)
    suite, calibrator, _, _ = make_suite(ros_context, tmp_path, truth_file)
    try:
        run = _run_failed_on(suite, tmp_path, 'recording.mcap.tmp')
        assert read_state(run).phase == PHASE_FAILED
        rows = read_samples(run / 'samples.csv')
        assert rows_before_full <= len(rows) < 12  # mid-run
        part = run / f'{RECORDING_FILE}.tmp'
        # The disk is still full when the run ends: the recording cannot be finished, so its
        # .tmp is kept with every byte written, and nothing poses as a finished recording.
        suite.wait_until(lambda: not calibrator.recorder.recording)
        assert part.stat().st_size == files[0].written == disk['bytes']
        assert not (run / RECORDING_FILE).exists()
        copy = tmp_path / 'copy.mcap'
        shutil.copy(part, f'{copy}.tmp')
        before = mcap_io.recover_recording(f'{copy}.tmp')['message_count']
        assert before > 0

        disk['full'] = False  # space freed: the same node resumes the run, recovering the .tmp
        client = suite.client_node.create_client(Trigger, names.SERVICE_RESUME)
        assert client.wait_for_service(timeout_sec=30.0)
        response = suite.wait(client.call_async(Trigger.Request()))
        assert response.success, response.message
        assert not part.exists()
        assert recording_info(run / RECORDING_FILE)['message_count'] == before
        again = read_samples(run / 'samples.csv')
        np.testing.assert_array_equal(again.leg_lengths[: len(rows)], rows.leg_lengths)
        assert read_state(run).phase == PHASE_DONE
    finally:
        suite.close()
