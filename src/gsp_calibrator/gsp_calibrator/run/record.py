"""The record of one run: its directory, its rows and its ``state.json`` (pure, no rclpy)."""

import dataclasses
import hashlib
import json
import os
import threading
from pathlib import Path

import numpy as np

from gsp_calibrator.collection.approach import ApproachTracker
from gsp_calibrator.collection.single_source import other_calibrators
from gsp_calibrator.files.run_directory import (
    SAMPLES_FILE,
    Rows,
    RunDirectory,
    RunDirectoryError,
    SamplesAppender,
)
from gsp_calibrator.recording.mcap_io import recover_recordings
from gsp_calibrator.settings import SELECTION_PARAMETERS
from gsp_kinematics.estimation.identification import resolve_free
from gsp_kinematics.fileio import atomic_write_text, to_json
from gsp_msgs_py import names

STATE_FILE = 'state.json'
STATE_VERSION = 1

PHASE_COLLECTING = 'collecting'
PHASE_IDENTIFYING = 'identifying'
PHASE_FAILED = 'failed'  #: the run stopped on an error (``stop_reason`` names it)
PHASE_INTERRUPTED = 'interrupted'  #: the calibrator shut down during the run
PHASE_DONE = 'done'
#: Phases a run can be resumed from (``collecting`` only when its process is gone).
RESUMABLE_PHASES = (PHASE_COLLECTING, PHASE_IDENTIFYING, PHASE_FAILED, PHASE_INTERRUPTED)

DEVICE_PARAMETERS = ('device_length', 'inclinometer_axes_angle')
POSE_TOLERANCE = 1e-9  #: m or rad: a samples.csv row and its selected posture agree to this


class ResumeRefused(ValueError):
    """A run cannot be resumed as asked; the message names the option or the reason."""


def _digest(values):
    data = np.round(np.asarray(values, dtype=float).reshape(-1), 12).tobytes()
    return hashlib.sha256(data).hexdigest()[:16]


def selection_options(settings):
    """The options that decide the selection of ``settings`` (``CalibratorSettings``), and the
    digests of its nominal platform and device."""
    nominal = settings.nominal
    parts = (nominal.base_joints, nominal.platform_joints, nominal.leg_offsets)
    platform = np.concatenate([np.ravel(part) for part in parts])
    device = [getattr(nominal, name) for name in DEVICE_PARAMETERS]
    options = settings.options(SELECTION_PARAMETERS)
    # Compared as the mask: 'paper' and its 44 names are the same selection.
    options['free_parameters'] = list(resolve_free(list(settings.free_parameters)))
    return {
        **options,
        'nominal_geometry_file': str(settings.nominal_geometry_file),
        'nominal_digest': _digest(platform),
        'device_digest': _digest(device),
    }


@dataclasses.dataclass
class RunState:
    """The content of ``state.json`` (postures are 1-based, in commanded order)."""

    selection: dict  #: :func:`selection_options` of the run
    poses: list  #: the selected postures, (count, 6) m and rad
    done: list = dataclasses.field(default_factory=list)  #: postures with a samples.csv row
    skipped: list = dataclasses.field(default_factory=list)  #: [{posture, reason}]
    phase: str = PHASE_COLLECTING
    stop_reason: str = ''
    sessions: int = 1  #: 1 + the number of resumes
    recordings: list = dataclasses.field(default_factory=list)  #: recording files, in order
    pid: int = 0  #: process of the calibrator of the current session
    #: [{rejected, replacement, reason}]: postures the platform rejected and their replacements
    replacements: list = dataclasses.field(default_factory=list)
    #: {posture (str): {wait_s, moving_pairs}}: each kept row's rest wait after its settled status
    rest_waits: dict = dataclasses.field(default_factory=dict)
    added: int = 0  #: postures added from the pool (``stop_when_accurate``; the last of ``poses``)
    #: what the effect groups added to the route (``postures.route_additions``; {}: nothing)
    route_additions: dict = dataclasses.field(default_factory=dict)

    def to_dict(self):
        data = dataclasses.asdict(self)
        data['version'] = STATE_VERSION
        data['poses'] = np.asarray(self.poses, dtype=float).reshape(-1, 6).tolist()
        return data

    @classmethod
    def from_dict(cls, data, source=STATE_FILE):
        if not isinstance(data, dict) or data.get('version') != STATE_VERSION:
            raise ResumeRefused(f'{source}: not a version {STATE_VERSION} run state')
        fields = {f.name for f in dataclasses.fields(cls)}
        try:
            state = cls(**{k: v for k, v in data.items() if k in fields})
            state.poses = np.asarray(state.poses, dtype=float).reshape(-1, 6).tolist()
        except (TypeError, ValueError) as error:
            raise ResumeRefused(f'{source}: malformed ({error})') from None
        return state

    def record_skip(self, posture, reason):
        self.skipped = [s for s in self.skipped if s['posture'] != posture]
        self.skipped.append({'posture': int(posture), 'reason': str(reason)})

    def record_done(self, posture, sample=None):
        """``posture`` has its row; ``sample`` (its ``PostureRow``) gives its rest wait."""
        self.skipped = [s for s in self.skipped if s['posture'] != posture]
        if posture not in self.done:
            self.done.append(int(posture))
        if sample is not None:
            self.rest_waits[str(int(posture))] = {
                'wait_s': float(sample.rest_wait),
                'moving_pairs': int(sample.moving_pairs),
            }


def read_state(directory):
    path = Path(directory) / STATE_FILE
    try:
        data = json.loads(path.read_text(encoding='utf-8'))
    except OSError as error:
        raise ResumeRefused(f'{path}: cannot read ({error.strerror})') from None
    except json.JSONDecodeError as error:
        raise ResumeRefused(f'{path}: not valid JSON ({error})') from None
    return RunState.from_dict(data, str(path))


def process_alive(pid):
    """Whether process ``pid`` exists (this host)."""
    try:
        os.kill(pid, 0) if pid > 0 else None
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return pid > 0


def resumable(state, own_pid=None):
    """Whether ``state`` is of an unfinished run no live calibrator is writing."""
    if state.phase not in RESUMABLE_PHASES:
        return False
    if state.phase in (PHASE_COLLECTING, PHASE_IDENTIFYING) and state.pid != own_pid:
        return not process_alive(state.pid)
    return True


def latest_unfinished_run(output_root, own_pid=None):
    """The newest run directory under ``output_root`` that can be resumed (ResumeRefused if none)."""
    root = Path(output_root)
    candidates = [path for path in root.glob('*') if (path / STATE_FILE).is_file()]
    for path in sorted(candidates, key=lambda p: p.name, reverse=True):
        try:
            if resumable(read_state(path), own_pid):
                return path
        except ResumeRefused:
            continue
    raise ResumeRefused(f'no unfinished run to resume under {root.resolve()}')


def validate_resume(state, settings, samples, own_pid=None):
    """Refuse (:class:`ResumeRefused`) a resume of ``state`` with ``settings`` and the run's
    ``samples`` when they do not belong together (``own_pid``: the resuming calibrator's)."""
    current = selection_options(settings)
    stored = state.selection
    if stored.get('device_digest') != current['device_digest']:
        raise ResumeRefused(
            'the run was collected with a different device (device_length or '
            'inclinometer_axes_angle of the nominal geometry differ): resume refused'
        )
    if stored.get('nominal_digest') != current['nominal_digest']:
        raise ResumeRefused(
            f'nominal geometry changed (the run used {stored.get("nominal_geometry_file")}, '
            f'now {current["nominal_geometry_file"]} with other values): resume refused'
        )
    for name in SELECTION_PARAMETERS:
        if stored.get(name) != current[name]:
            raise ResumeRefused(
                f'option {name} changed since the run started ({stored.get(name)} -> '
                f'{current[name]}): it would change the selection; resume refused'
            )
    if not resumable(state, own_pid):
        if state.phase == PHASE_DONE:
            raise ResumeRefused('the run is finished (phase done): nothing to resume')
        raise ResumeRefused(
            f'the run is still being written by process {state.pid} (phase {state.phase})'
        )
    poses = np.asarray(state.poses, dtype=float)
    for m, posture in enumerate(samples.posture):
        if not 1 <= posture <= len(poses):
            raise ResumeRefused(f'samples.csv row {m + 1}: posture {posture} is not selected')
        if np.max(np.abs(samples.commanded_poses[m] - poses[posture - 1])) > POSE_TOLERANCE:
            raise ResumeRefused(
                f'samples.csv row {m + 1} (posture {posture}) was commanded at another pose '
                'than the selection: its samples come from a different selection or nominal'
            )


def postures_to_collect(state, samples):
    """The 1-based postures without a row or a replacement (skipped ones are tried again)."""
    collected = set(int(k) for k in samples.posture)
    replaced = {int(r['rejected']) for r in state.replacements}
    return [k for k in range(1, len(state.poses) + 1) if k not in collected and k not in replaced]


# --- the record of a run in progress ----------------------------------------------------------


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


class RunRecord:
    """The run's ``directory`` (a ``RunDirectory``), its rows ``samples`` and ``state`` (None
    until :meth:`begin`); ``recovered``: recordings a killed calibrator left, finalised."""

    def __init__(self, directory, samples, state=None, recovered=()):
        self.directory = directory
        self.samples = samples
        self.state = state
        self.recovered = list(recovered)
        self.remaining = []  #: postures (1-based) still to command, in order
        self.replace = None  #: ``replace(poses, rejected)``: a rejected posture's new pose or None
        self._appender = None
        self.approach = None  #: the ApproachTracker of the postures commanded (from begin)
        self._lock = threading.Lock()  # guards samples, state and remaining
        self._save_lock = threading.Lock()  # orders the state.json writes

    @classmethod
    def create(cls, output_root):
        """A new run directory with an empty ``samples.csv`` (OSError if unwritable)."""
        directory = RunDirectory.create(output_root)
        samples = Rows.empty()
        directory.write_samples(samples)
        return cls(directory, samples)

    @classmethod
    def resume(cls, settings, pid):
        """The unfinished run ``resume_run_directory``, else the latest under ``output_root``."""
        try:
            if settings.resume_run_directory:
                path = settings.resume_run_directory
            else:
                path = latest_unfinished_run(settings.output_root, pid)
            directory = RunDirectory(path)
            state = read_state(directory.path)
            samples = directory.read_samples()
            validate_resume(state, settings, samples, pid)
        except (ResumeRefused, RunDirectoryError) as error:
            raise RunRefused(f'resume refused: {error}') from None
        # samples.csv decides what was collected: state.json lags it by the rows appended after
        # its last write (a killed calibrator), so those rows count as done from here on.
        for posture in samples.posture:
            state.record_done(int(posture))
        recovered = recover_recordings(directory.path)
        state.sessions += 1
        return cls(directory, samples, state, recovered)

    @property
    def resumed(self):
        return self.state is not None and self.state.sessions > 1

    def begin(self, settings, poses, pid, recording_file=None, route_additions=None):
        """Start collecting ``poses``, a new run's plan (a resumed run keeps its own), with
        this session's ``recording_file`` and the plan's ``route_additions``; writes state.json."""
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
        path = self.directory.file(SAMPLES_FILE)
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
        """``posture`` is about to be commanded from ``standing_legs`` (6,) m, heard last (its
        row gets the legs' approach directions)."""
        with self._lock:
            self.approach.command(posture, pose, standing_legs)

    def rows_so_far(self):
        """A copy of the rows collected so far (:class:`gsp_calibrator.files.run_directory.Rows`)."""
        with self._lock:
            return self.samples.rows(slice(0, len(self.samples)))

    def add_posture(self, pose):
        """Append ``pose`` (6,), a pool posture, to state.json's poses: its ``(k, pose)``."""
        with self._lock:
            self.state.poses.append(np.asarray(pose, dtype=float).tolist())
            self.state.added += 1
            return len(self.state.poses), np.asarray(pose, dtype=float)

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
                self.samples = self.samples.rows(slice(0, len(self.samples) - 1))
                raise RunWriteError(self._appender.path, error) from None
            self.state.record_done(event.posture, row)

    def end_posture(self, event):
        """Keep a ``RowReady`` or a ``PostureSkipped``: the event, or a :class:`WriteFailed`."""
        try:
            if hasattr(event, 'sample'):
                self.add_row(event)
            elif hasattr(event, 'reason') and hasattr(event, 'posture'):
                self.skip(event)
        except RunWriteError as error:
            return WriteFailed(str(error))
        return event

    def skip(self, event):
        """Note a ``PostureSkipped``; one the platform rejected gets a replacement (``replace``)."""
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
        :class:`RunWriteError` if it cannot be written."""
        path = self.directory.file(STATE_FILE)
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


def open_record(settings, resume, pid, pose_command_publishers=(), node=('calibrator', '/')):
    """The :class:`RunRecord` of a run (``resume``: the rest of an unfinished one)."""
    others = other_calibrators(pose_command_publishers, *node)
    if others:
        raise RunRefused(
            f'another calibrator publishes on {names.TOPIC_POSE_COMMAND} ({", ".join(others)})'
            ': two calibrators must not drive one platform; run refused'
        )
    try:
        return RunRecord.resume(settings, pid) if resume else RunRecord.create(settings.output_root)
    except OSError as error:
        raise RunRefused(
            f'cannot write the run directory under {settings.output_root}: {error}'
        ) from None
