"""One calibration run as the calibrator node drives it: directory, state and rows (pure, no rclpy).

A :class:`RunSession` is a new run (:meth:`RunSession.create`) or the rest of an unfinished one
(:meth:`RunSession.resume`). It holds the run's ``state.json`` (:mod:`.state`), its rows
(:class:`.directory.Rows`, each appended to ``samples.csv`` as it is collected by a
:class:`.directory.SamplesAppender`) and the postures still to command. It is thread-safe:
a row is added by the node's thread whose message ended the posture
(:class:`.host.PostureLink`) while the run coroutine writes ``state.json``.

A file that cannot be written (a full disk: ENOSPC, or any ``OSError``) raises
:class:`RunWriteError`, whose message names the file and the cause. Nothing written before is
lost: rows are appended whole (a failed append is cut back), ``state.json`` is replaced
atomically. See docs/faults.md.
"""

import dataclasses
import os
import threading

import numpy as np

from gsp_calibrator.collection.single_source import other_calibrators
from gsp_calibrator.recording.mcap_io import recover_recordings
from gsp_calibrator.run.approach import ApproachTracker
from gsp_calibrator.run.directory import (
    SAMPLES_FILE,
    Rows,
    RunDirectory,
    RunDirectoryError,
    SamplesAppender,
)
from gsp_calibrator.run.state import (
    PHASE_COLLECTING,
    STATE_FILE,
    ResumeRefused,
    RunState,
    latest_unfinished_run,
    postures_to_collect,
    read_state,
    selection_options,
    validate_resume,
)
from gsp_kinematics.fileio import atomic_write_text, to_json
from gsp_msgs_py import names


class RunRefused(Exception):
    """A run cannot start or resume; the message says why."""


class RunWriteError(Exception):
    """A file of the run could not be written; the message names it and the cause."""

    def __init__(self, path, error):
        self.path, self.error = str(path), error
        cause = getattr(error, 'strerror', None) or str(error)
        super().__init__(f'cannot write {self.path}: {cause}')


@dataclasses.dataclass(frozen=True)
class WriteFailed:
    """A final posture event: a file of the run could not be written, so the run ends."""

    message: str


class RunSession:
    """The run directory ``run``, its rows ``samples`` and ``state`` (None until :meth:`begin`
    for a new run); ``recovered``: recordings a killed calibrator left, finalised on resume."""

    def __init__(self, run, samples, state=None, recovered=()):
        self.run = run
        self.samples = samples
        self.state = state
        self.recovered = list(recovered)
        self.remaining = []  #: postures (1-based) still to command, in order
        #: ``replace(poses, rejected)``: the pose (6,) to add for a rejected posture, or None
        self.replace = None
        self._appender = None
        self.approach = None  #: the ApproachTracker of the postures commanded (from begin)
        self._lock = threading.Lock()  # guards samples, state and remaining
        self._save_lock = threading.Lock()  # orders the state.json writes

    @classmethod
    def create(cls, output_root):
        """A new run directory with an empty ``samples.csv`` (OSError if unwritable)."""
        run = RunDirectory.create(output_root)
        samples = Rows.empty()
        run.write_samples(samples)
        return cls(run, samples)

    @classmethod
    def resume(cls, settings, pid):
        """The unfinished run ``settings.resume_run_directory``, else the latest under
        ``output_root``; :class:`RunRefused` names why it cannot be resumed."""
        try:
            if settings.resume_run_directory:
                path = settings.resume_run_directory
            else:
                path = latest_unfinished_run(settings.output_root, pid)
            run = RunDirectory(path)
            state = read_state(run.path)
            samples = run.read_samples()
            validate_resume(state, settings, samples, pid)
        except (ResumeRefused, RunDirectoryError) as error:
            raise RunRefused(f'resume refused: {error}') from None
        # samples.csv decides what was collected: state.json lags it by the rows appended after
        # its last write (a killed calibrator), so those rows count as done from here on.
        for posture in samples.posture:
            state.record_done(int(posture))
        recovered = recover_recordings(run.path)
        state.sessions += 1
        return cls(run, samples, state, recovered)

    @property
    def resumed(self):
        return self.state is not None and self.state.sessions > 1

    def begin(self, settings, poses, pid, recording_file=None, route_additions=None):
        """Start collecting: ``poses`` is a new run's selection (a resumed run keeps its own);
        ``recording_file``: this session's recording, if any; ``route_additions``: what the
        effect groups added to a new run's route (``postures.route_additions``). Writes
        state.json."""
        if self.state is None:
            poses = np.asarray(poses, dtype=float).reshape(-1, 6)
            self.state = RunState(selection_options(settings), poses.tolist())
            self.state.route_additions = dict(route_additions or {})
            self.remaining = list(range(1, len(poses) + 1))
        else:
            self.remaining = postures_to_collect(self.state, self.samples)
        self.state.pid = int(pid)
        # The legs arrived last as the last row says (a new run: homed extending).
        last = self.samples.directions[-1] if len(self.samples) else None
        self.approach = ApproachTracker(settings.nominal, last)
        self.state.phase, self.state.stop_reason = PHASE_COLLECTING, ''
        if recording_file is not None:
            self.state.recordings.append(os.path.basename(recording_file))
        path = self.run.file(SAMPLES_FILE)
        try:
            self._appender = SamplesAppender(path)
        except OSError as error:
            raise RunWriteError(path, error) from None
        self.save()

    def next_posture(self):
        """``(k, pose)`` of the next posture to command, or None when all were commanded."""
        with self._lock:
            if not self.remaining:
                return None
            k = self.remaining.pop(0)
            return k, np.asarray(self.state.poses[k - 1], dtype=float)

    def note_command(self, posture, pose, standing_legs=None):
        """``posture`` (``pose``) is about to be commanded; ``standing_legs`` (6,) m: the leg
        lengths heard last (where the first command starts from). Its row gets the approach
        directions (``run.approach``)."""
        with self._lock:
            self.approach.command(posture, pose, standing_legs)

    def rows_so_far(self):
        """A copy of the rows collected so far (:class:`.directory.Rows`)."""
        with self._lock:
            return self.samples.rows(slice(0, len(self.samples)))

    def add_posture(self, pose):
        """Append ``pose`` (6,) to the postures to command (a run that stops when it is good
        enough adds pool postures); ``(k, pose)`` of it, recorded in state.json's poses."""
        with self._lock:
            self.state.poses.append(np.asarray(pose, dtype=float).tolist())
            self.state.added += 1
            return len(self.state.poses), np.asarray(pose, dtype=float)

    @property
    def commanded_all(self):
        with self._lock:
            return not self.remaining

    def add_row(self, event):
        """Keep the row of a ``protocol.RowReady`` (appended to samples.csv at once)."""
        row = event.sample
        with self._lock:
            self.samples.append(
                event.posture,
                event.pose,
                row.leg_lengths,
                row.readings,
                row.n_samples,
                row.stamp,
                row.lag_sums,
                self.approach.directions(event.posture) if self.approach else None,
            )
            try:
                self._appender.append(self.samples)
            except OSError as error:
                self.samples = _without_last(self.samples)
                raise RunWriteError(self._appender.path, error) from None
            self.state.record_done(event.posture, row)

    def end_posture(self, event):
        """Keep what ends a posture: a ``RowReady`` (its row) or a ``PostureSkipped``; returns
        the event, or a :class:`WriteFailed` when the row could not be written."""
        try:
            if hasattr(event, 'sample'):
                self.add_row(event)
            elif hasattr(event, 'reason') and hasattr(event, 'posture'):
                self.skip(event)
        except RunWriteError as error:
            return WriteFailed(str(error))
        return event

    def skip(self, event):
        """Note a ``protocol.PostureSkipped``; one the platform rejected gets a replacement
        (``replace``), appended to the postures to command and recorded."""
        with self._lock:
            self.state.record_skip(event.posture, event.reason)
            if event.rejected_by_platform and self.approach is not None:
                self.approach.rejected(event.posture)
            if not (event.rejected_by_platform and self.replace is not None):
                return
            rejected = [event.posture] + [r['rejected'] for r in self.state.replacements]
            pose = self.replace(np.asarray(self.state.poses), rejected)
            if pose is None:
                return
            self.state.poses.append(np.asarray(pose, dtype=float).tolist())
            replacement = len(self.state.poses)
            self.remaining.append(replacement)
            self.state.replacements.append(
                {
                    'rejected': int(event.posture),
                    'replacement': replacement,
                    'reason': str(event.reason),
                }
            )

    def save(self, phase=None, stop_reason=None):
        """Rewrite state.json (atomic) with ``phase`` / ``stop_reason`` if given;
        :class:`RunWriteError` if it cannot be written (the previous one is then intact)."""
        path = self.run.file(STATE_FILE)
        with self._save_lock:
            with self._lock:
                if self.state is None:
                    return
                if phase is not None:
                    self.state.phase = phase
                if stop_reason is not None:
                    self.state.stop_reason = stop_reason
                text = to_json(self.state.to_dict())
            try:
                atomic_write_text(path, text)
            except OSError as error:
                raise RunWriteError(path, error) from None

    def close(self):
        if self._appender is not None:
            self._appender.close()
            self._appender = None


def open_session(settings, resume, pid, pose_command_publishers=(), node=('calibrator', '/')):
    """The :class:`RunSession` of a run (``resume``: the rest of an unfinished one).

    :class:`RunRefused` when it must not start: another calibrator among
    ``pose_command_publishers`` (``TopicEndpointInfo``; ``node``: this one's name and namespace),
    a refused resume, or an unwritable or full ``output_root`` (nothing has moved yet).
    """
    others = other_calibrators(pose_command_publishers, *node)
    if others:
        raise RunRefused(
            f'another calibrator publishes on {names.TOPIC_POSE_COMMAND} ({", ".join(others)})'
            ': two calibrators must not drive one platform; run refused'
        )
    try:
        return (
            RunSession.resume(settings, pid) if resume else RunSession.create(settings.output_root)
        )
    except OSError as error:
        raise RunRefused(
            f'cannot write the run directory under {settings.output_root}: {error}'
        ) from None


def _without_last(samples):
    return samples.rows(slice(0, len(samples) - 1))
