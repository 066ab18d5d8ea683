"""A recorded calibration run, ready to be published again (pure, no rclpy node or context).
See docs/data.md#replaying-a-run."""

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from gsp_calibrator.collection.events import PairsCollected, PostureSkipped
from gsp_calibrator.collection.protocol import CollectionProtocol
from gsp_calibrator.files.run_directory import SAMPLES_FILE, RunDirectoryError, read_samples
from gsp_calibrator.recording import rebuild
from gsp_calibrator.recording.mcap_format import RecordingError
from gsp_calibrator.recording.mcap_io import recording_options
from gsp_calibrator.recording.recorder import RECORDING_FILE, recording_parts
from gsp_calibrator.settings import DEFAULTS
from gsp_kinematics.rotation import euler_to_matrix, matrix_to_quaternion
from gsp_msgs_py import conversions, names

SOURCE_SAMPLES = 'samples.csv'
SOURCE_RECORDING = 'recording.mcap'
#: Default largest distance (m and rad) of a command to a recorded commanded pose it matches.
POSE_TOLERANCE = 1e-6


class ReplayError(ValueError):
    """A run cannot be replayed; the message names the file and the problem."""


@dataclasses.dataclass(eq=False)
class SampleStream:
    """Samples to publish in turn (cyclically): N instants, SI units."""

    leg_lengths: np.ndarray  #: (N, 6) q_i, m
    readings: np.ndarray  #: (N, 4) [alpha, beta, phi, d_m], rad and m
    true_poses: np.ndarray = None  #: (N, 6) true pose of each instant, or None if not recorded
    #: (N,) ns: each instant's recorded leg stamp after the first (the stream's own timing), or
    #: None (samples.csv: no timing)
    offsets_ns: np.ndarray = None

    def __post_init__(self):
        self.leg_lengths = np.asarray(self.leg_lengths, dtype=float).reshape(-1, 6)
        count = len(self.leg_lengths)
        self.readings = np.asarray(self.readings, dtype=float).reshape(count, 4)
        if self.true_poses is not None:
            self.true_poses = np.asarray(self.true_poses, dtype=float).reshape(count, 6)
        if self.offsets_ns is not None:
            stamps = np.asarray(self.offsets_ns, dtype=np.int64).reshape(count)
            self.offsets_ns = stamps - (stamps[0] if count else 0)

    def __len__(self):
        return int(self.leg_lengths.shape[0])

    @property
    def has_true_pose(self):
        return self.true_poses is not None and len(self) > 0

    def sample(self, index):
        """``(q (6,), readings (4,), true_pose (6,) or None)`` of instant ``index`` (cyclic)."""
        i = int(index) % len(self)
        true_pose = self.true_poses[i] if self.true_poses is not None else None
        return self.leg_lengths[i], self.readings[i], true_pose


@dataclasses.dataclass(eq=False)
class RecordedPosture:
    """One recorded posture: what was commanded and what the sensors said after settling."""

    posture: int  #: posture number k (1-based, in commanded order)
    commanded_pose: np.ndarray  #: (6,) [x, y, z, psi, theta, phi], m and rad
    stream: SampleStream
    command_id: str = ''  #: the recorded command's id ('' from samples.csv)

    def __post_init__(self):
        self.commanded_pose = np.asarray(self.commanded_pose, dtype=float).reshape(6)


def _quaternions(poses):
    poses = np.asarray(poses, dtype=float).reshape(-1, 6)
    return matrix_to_quaternion(euler_to_matrix(poses[:, 3:]))


@dataclasses.dataclass(eq=False)
class RecordedRun:
    """The postures of a recorded run (docs/data.md#replaying-a-run)."""

    source: Path  #: the file read
    kind: str  #: :data:`SOURCE_SAMPLES` or :data:`SOURCE_RECORDING`
    postures: tuple  #: of :class:`RecordedPosture`, in recorded order
    #: Stream before the first command: the recorded idle samples, else the stream of the last
    #: posture away from the first posture's pose (:func:`resting_stream`).
    initial_stream: SampleStream
    #: Commands that gave no posture: ``[(k, reason), ...]`` (rejected, never settled, no samples).
    skipped: tuple = ()
    options: dict = dataclasses.field(default_factory=dict)  #: run options stored in the file
    parts: tuple = ()  #: the recording parts read, in order (empty for a ``samples.csv``)

    def __post_init__(self):
        if not self.postures:
            raise ReplayError(f'{self.source}: no recorded posture to replay')
        poses = np.array([p.commanded_pose for p in self.postures])
        self._positions, self._quaternions = poses[:, :3], _quaternions(poses)

    def __len__(self):
        return len(self.postures)

    @property
    def has_true_pose(self):
        """True if the recording holds the true pose of every replayed sample of some posture."""
        return self.initial_stream.has_true_pose or any(
            p.stream.has_true_pose for p in self.postures
        )

    # --- loading ---------------------------------------------------------------------------

    @classmethod
    def load(cls, path, sync_tolerance=None):
        """A run directory (its ``samples.csv``, else its ``recording.mcap``), a ``samples.csv``
        or an MCAP recording (``.mcap``); :class:`ReplayError` naming the file otherwise."""
        if path is None or not str(path).strip():
            raise ReplayError('no run given: a run directory, samples.csv or recording.mcap')
        path = Path(os.path.expanduser(str(path)))
        if path.is_dir():
            samples = path / SAMPLES_FILE
            if samples.is_file():
                return cls.from_samples(samples)
            parts = recording_parts(path)
            if parts:
                return cls.from_recording(parts, sync_tolerance)
            raise ReplayError(f'{path}: run directory without {SAMPLES_FILE} or {RECORDING_FILE}')
        if not path.exists():
            raise ReplayError(f'{path}: no such file or directory')
        if path.suffix.lower() == '.mcap':
            if path.name == RECORDING_FILE:  # with the later parts of a resumed run
                return cls.from_recording(recording_parts(path.parent), sync_tolerance)
            return cls.from_recording(path, sync_tolerance)
        return cls.from_samples(path)

    @classmethod
    def from_samples(cls, path):
        """One averaged row per posture, from ``samples.csv``."""
        path = Path(path)
        try:
            samples = read_samples(path)
        except RunDirectoryError as error:
            raise ReplayError(str(error)) from None
        postures = tuple(
            RecordedPosture(
                posture=int(samples.posture[m]),
                commanded_pose=samples.commanded_poses[m],
                stream=SampleStream(samples.leg_lengths[m : m + 1], samples.readings[m : m + 1]),
            )
            for m in range(len(samples))
        )
        if not postures:
            raise ReplayError(f'{path}: no posture rows to replay')
        return cls(path, SOURCE_SAMPLES, postures, resting_stream(postures))

    @classmethod
    def from_recording(cls, path, sync_tolerance=None):
        """The synchronised samples after each posture's settle, paired as the calibrator pairs
        them, from an MCAP recording or the parts of a resumed run (a list, in order); a posture
        collected again keeps its later segment. ``sync_tolerance`` (s) defaults to the first
        part's stored option, else the calibrator's default."""
        parts = [Path(p) for p in ([path] if isinstance(path, (str, os.PathLike)) else path)]
        try:
            return cls._from_recording(parts, sync_tolerance)
        except RecordingError as error:
            raise ReplayError(str(error)) from None

    @classmethod
    def _from_recording(cls, parts, sync_tolerance):
        path = parts[0]
        options = recording_options(path)
        sync_tolerance = _sync_tolerance(path, options, sync_tolerance)

        # Every pair after each settle, paired by the calibrator's own protocol; the true poses
        # of each segment (command to command) are kept beside it, by command id.
        true_poses = {'': {}}  # command id ('' before the first command) -> {stamp_ns: pose}
        current = ['']
        commands = []

        def on_message(topic, _, msg):
            try:
                if topic == names.TOPIC_POSE_COMMAND:
                    commands.append(msg)
                    current[0] = conversions.command_id_from_stamp(msg.header.stamp)
                    true_poses[current[0]] = {}
                elif topic == names.TOPIC_TRUE_POSE:
                    stamp = conversions.stamp_to_nanoseconds(msg.header.stamp)
                    true_poses[current[0]][stamp] = conversions.pose_stamped_to_pose(msg)
            except (ValueError, TypeError):
                pass  # malformed: dropped, as the calibrator drops it

        postures, skipped, initial_stream = {}, {}, None  # postures and skips by number
        for part in parts:
            collection = CollectionProtocol(sync_tolerance, 1, keep_pairs=True)
            if postures:
                last = next(reversed(postures.values()))
                collection.continue_after(np.mean(last.stream.readings, axis=0))
            current[0] = ''  # idle samples of a new session belong to no command
            margin = collection.collector.tolerance_ns
            for event in rebuild.feed_recording(
                part, collection, extra_topics=(names.TOPIC_TRUE_POSE,), on_message=on_message
            ):
                if isinstance(event, PairsCollected):
                    stream = SampleStream(
                        event.leg_lengths,
                        event.readings,
                        _true_poses(true_poses.get(event.command_id, {}), event.stamps, margin),
                        offsets_ns=event.stamps,
                    )
                    if event.posture is None:
                        if initial_stream is None or len(initial_stream) == 0:
                            initial_stream = stream  # the first session's idle samples
                    else:
                        postures.pop(event.posture, None)
                        skipped.pop(event.posture, None)
                        postures[event.posture] = RecordedPosture(
                            event.posture, event.pose, stream, event.command_id
                        )
                elif isinstance(event, PostureSkipped) and event.posture not in postures:
                    skipped[event.posture] = (
                        f'rejected: {event.platform_reason}'
                        if event.rejected_by_platform
                        else event.reason
                    )
        postures = list(postures.values())
        if not postures:
            raise ReplayError(
                f'{path}{f" and {len(parts) - 1} later part(s)" if len(parts) > 1 else ""}: '
                f'no settled posture with synchronised samples '
                f'({len(commands)} pose command(s) recorded)'
            )
        if initial_stream is None or len(initial_stream) == 0:
            initial_stream = resting_stream(postures)
        return cls(
            source=path,
            kind=SOURCE_RECORDING,
            postures=tuple(postures),
            initial_stream=initial_stream,
            skipped=tuple(skipped.items()),
            options=dict(options, sync_tolerance=sync_tolerance),
            parts=tuple(parts),
        )

    # --- lookup ----------------------------------------------------------------------------

    def distances(self, commanded_pose):
        """``(position (M,) m, orientation (M,) rad)`` of ``commanded_pose`` to each posture."""
        return _pose_distances(self._positions, self._quaternions, commanded_pose)

    def match(self, commanded_pose, tolerance=POSE_TOLERANCE):
        """The nearest :class:`RecordedPosture` (the first of equals) within ``tolerance`` (m, and
        rad of rotation) of ``commanded_pose``, or None; ValueError for a pose not 6 finite values."""
        position, angle = self.distances(commanded_pose)
        distance = np.maximum(position, angle)
        best = int(np.argmin(distance))
        if distance[best] <= float(tolerance):
            return self.postures[best]
        return None

    def visits(self, commanded_pose, tolerance=POSE_TOLERANCE):
        """Indices into :attr:`postures` of the visits of the pose :meth:`match` finds: the
        postures within ``tolerance`` of both ``commanded_pose`` and that posture's pose (one,
        or a reference pose and its revisits), in posture order; empty when none matches."""
        nearest = self.match(commanded_pose, tolerance)
        if nearest is None:
            return []
        tolerance = float(tolerance)
        near_command = np.maximum(*self.distances(commanded_pose)) <= tolerance
        near_nearest = np.maximum(*self.distances(nearest.commanded_pose)) <= tolerance
        indices = np.flatnonzero(near_command & near_nearest)
        return sorted((int(i) for i in indices), key=lambda i: self.postures[i].posture)


class PostureServer:
    """Which recorded posture each pose command of a replay gets (pure; one per replay)."""

    def __init__(self, run, tolerance=POSE_TOLERANCE):
        self.run = run
        self.tolerance = float(tolerance)  #: m and rad (:meth:`RecordedRun.match`)
        self._served = {}  # visits (tuple of indices) -> commands served
        self._last = None  # (visits, index) of the previous served command

    def serve(self, commanded_pose):
        """The :class:`RecordedPosture` to stream for a command of ``commanded_pose`` (6,), or
        None (not recorded); ValueError for a pose that is not 6 finite values."""
        visits = tuple(self.run.visits(commanded_pose, self.tolerance))
        if not visits:
            return None
        if self._last is not None and self._last[0] == visits:
            return self.run.postures[self._last[1]]
        served = self._served.get(visits, 0)
        index = visits[served % len(visits)]
        self._served[visits] = served + 1
        self._last = (visits, index)
        return self.run.postures[index]


def resting_stream(postures):
    """The stream of a run without idle samples before its first command: the last posture's
    away from the first posture's pose (a route with reference revisits ends at it): at that
    pose the replaying calibrator would find the device unchanged and skip the first posture."""
    poses = np.array([p.commanded_pose for p in postures])
    first = poses[min(range(len(postures)), key=lambda m: postures[m].posture)]
    position, angle = _pose_distances(poses[:, :3], _quaternions(poses), first)
    away = np.flatnonzero(np.maximum(position, angle) > POSE_TOLERANCE)
    return postures[int(away[-1]) if away.size else -1].stream


def _pose_distances(positions, quaternions, pose):
    """``(position (M,) m, rotation angle (M,) rad)`` of ``pose`` (6,) to the poses of
    ``positions`` (M, 3) and unit ``quaternions`` (M, 4); ValueError for a bad pose."""
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (6,):
        raise ValueError(f'pose: expected [x, y, z, psi, theta, phi], got shape {pose.shape}')
    if not np.all(np.isfinite(pose)):
        raise ValueError(f'pose: non-finite component(s) in {pose.tolist()}')
    position = np.linalg.norm(positions - pose[:3], axis=1)
    quaternion = _quaternions(pose)[0]
    chord = np.minimum(
        np.linalg.norm(quaternions - quaternion, axis=1),
        np.linalg.norm(quaternions + quaternion, axis=1),
    )
    # Unit quaternions a rotation angle t apart are 2 sin(t / 4) apart (accurate near 0).
    angle = 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))
    return position, angle


def _sync_tolerance(path, options, sync_tolerance):
    """The pairing tolerance (s): ``sync_tolerance`` if given, else the recorded run's option,
    else the calibrator's default; ReplayError if it is not a time >= 0."""
    if sync_tolerance is None:
        sync_tolerance = options.get('sync_tolerance', DEFAULTS['sync_tolerance'])
    try:
        sync_tolerance = float(sync_tolerance)
    except (TypeError, ValueError):
        raise ReplayError(f'{path}: sync_tolerance {sync_tolerance!r} is not a number') from None
    if not (math.isfinite(sync_tolerance) and sync_tolerance >= 0.0):
        raise ReplayError(f'{path}: sync_tolerance {sync_tolerance!r} must be >= 0 s')
    return sync_tolerance


def _true_poses(known, stamps, margin):
    """True pose (``known``: {stamp_ns: pose}) of each leg-length stamp: the same stamp, else
    the nearest within ``margin`` ns; None unless every stamp has one."""
    if not known or len(stamps) == 0:
        return None
    sorted_stamps = np.array(sorted(known), dtype=np.int64)
    poses = []
    for stamp in stamps:
        stamp = int(stamp)
        i = int(np.searchsorted(sorted_stamps, stamp))
        near = [j for j in (i - 1, i) if 0 <= j < sorted_stamps.size]
        j = min(near, key=lambda j: abs(int(sorted_stamps[j]) - stamp))
        if abs(int(sorted_stamps[j]) - stamp) > margin:
            return None
        poses.append(known[int(sorted_stamps[j])])
    return np.array(poses)
