"""A recorded calibration run, ready to be published again (pure, no rclpy node or context).

:class:`RecordedRun` loads a run directory, a ``samples.csv`` or a ``recording.mcap`` and gives,
per recorded posture (:class:`RecordedPosture`), its commanded pose and the sample stream
(:class:`SampleStream`) the ``replay`` node publishes when that pose is commanded again:

* from ``samples.csv``: one averaged row per posture (republished as it is, again and again);
* from ``recording.mcap``: the raw synchronised samples recorded after the posture's settle, in
  order, paired exactly as the calibrator pairs them
  (:class:`gsp_calibrator.collector.SampleCollector`, the recording's ``sync_tolerance``); with
  the simulator's ``true_pose`` of each sample when it was recorded.

A run directory is replayed from its ``samples.csv`` when it has one (the rows the calibration
was computed from, so a replay reproduces it exactly whatever the timing), else from its
``recording.mcap``. Give the file itself to choose.

:meth:`RecordedRun.match` finds the recorded posture of a commanded pose (position within
``tolerance`` m and orientation within ``tolerance`` rad).
"""

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from gsp_kinematics.rotation import euler_to_matrix, matrix_to_quaternion
from gsp_msgs_py import names

from . import recording
from .collector import SampleCollector
from .run_directory import SAMPLES_FILE, RunDirectoryError, read_samples
from .settings import DEFAULTS

SOURCE_SAMPLES = 'samples.csv'
SOURCE_RECORDING = 'recording.mcap'

#: Largest stream kept per posture (the first pairs after the settle), and before the first
#: command (the last pairs before it), so a long idle recording stays cheap to load and pair.
MAX_STREAM_SAMPLES = 2000

_SENSOR_TOPICS = (names.TOPIC_LEG_LENGTHS, names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER,
                  names.TOPIC_LVDT)


class ReplayError(ValueError):
    """A run cannot be replayed; the message names the file and the problem."""


@dataclasses.dataclass(frozen=True, eq=False)
class SampleStream:
    """Samples to publish in turn (cyclically): N instants, SI units."""

    leg_lengths: np.ndarray  #: (N, 6) q_i, m
    readings: np.ndarray  #: (N, 4) [alpha, beta, phi, d_m], rad and m
    true_poses: np.ndarray = None  #: (N, 6) true pose of each instant, or None if not recorded

    def __post_init__(self):
        legs = np.asarray(self.leg_lengths, dtype=float).reshape(-1, 6)
        count = legs.shape[0]
        object.__setattr__(self, 'leg_lengths', legs)
        object.__setattr__(self, 'readings',
                           np.asarray(self.readings, dtype=float).reshape(count, 4))
        if self.true_poses is not None:
            object.__setattr__(self, 'true_poses',
                               np.asarray(self.true_poses, dtype=float).reshape(count, 6))

    def __len__(self):
        return int(self.leg_lengths.shape[0])

    @property
    def has_true_pose(self):
        return self.true_poses is not None and len(self) > 0

    def sample(self, index):
        """``(q (6,), readings (4,), true_pose (6,) or None)`` of instant ``index`` (cyclic)."""
        if len(self) == 0:
            raise IndexError('empty sample stream')
        i = int(index) % len(self)
        true_pose = self.true_poses[i] if self.true_poses is not None else None
        return self.leg_lengths[i], self.readings[i], true_pose


@dataclasses.dataclass(frozen=True, eq=False)
class RecordedPosture:
    """One recorded posture: what was commanded and what the sensors said after settling."""

    posture: int  #: posture number k (1-based, in commanded order)
    commanded_pose: np.ndarray  #: (6,) [x, y, z, psi, theta, phi], m and rad
    stream: SampleStream
    command_id: str = ''  #: the recorded command's id ('' from samples.csv)

    def __post_init__(self):
        object.__setattr__(self, 'commanded_pose',
                           np.asarray(self.commanded_pose, dtype=float).reshape(6))


def _quaternions(poses):
    poses = np.asarray(poses, dtype=float).reshape(-1, 6)
    return matrix_to_quaternion(euler_to_matrix(poses[:, 3:]))


@dataclasses.dataclass(frozen=True, eq=False)
class RecordedRun:
    """The postures of a recorded run (see the module docstring)."""

    source: Path  #: the file read
    kind: str  #: :data:`SOURCE_SAMPLES` or :data:`SOURCE_RECORDING`
    postures: tuple  #: of :class:`RecordedPosture`, in recorded order
    #: Stream before the first command: the recorded idle samples, else the last posture's
    #: stream (the platform rests where the recorded run left it; never the first posture, which
    #: a calibrator would take for a device still reporting the previous posture).
    initial_stream: SampleStream
    #: Commands that gave no posture: ``[(k, reason), ...]`` (rejected, never settled, no samples).
    skipped: tuple = ()
    options: dict = dataclasses.field(default_factory=dict)  #: run options stored in the file

    def __post_init__(self):
        if not self.postures:
            raise ReplayError(f'{self.source}: no recorded posture to replay')
        poses = np.array([p.commanded_pose for p in self.postures])
        object.__setattr__(self, '_positions', poses[:, :3].copy())
        object.__setattr__(self, '_quaternions', _quaternions(poses))

    def __len__(self):
        return len(self.postures)

    @property
    def has_true_pose(self):
        """True if the recording holds the true pose of every replayed sample of some posture."""
        return self.initial_stream.has_true_pose or any(
            p.stream.has_true_pose for p in self.postures)

    @property
    def commanded_poses(self):
        """(M, 6) recorded commanded poses."""
        return np.array([p.commanded_pose for p in self.postures])

    # --- loading ---------------------------------------------------------------------------

    @classmethod
    def load(cls, path, sync_tolerance=None):
        """A run directory (its ``samples.csv``, else its ``recording.mcap``), a ``samples.csv``
        or an MCAP recording (``.mcap``); :class:`ReplayError` naming the file otherwise."""
        if path is None or not str(path).strip():
            raise ReplayError('no run given: a run directory, samples.csv or recording.mcap')
        path = Path(os.path.expanduser(str(path)))
        if path.is_dir():
            samples, mcap = path / SAMPLES_FILE, path / recording.RECORDING_FILE
            if samples.is_file():
                return cls.from_samples(samples)
            if mcap.is_file():
                return cls.from_recording(mcap, sync_tolerance)
            raise ReplayError(f'{path}: run directory without {SAMPLES_FILE} or '
                              f'{recording.RECORDING_FILE}')
        if not path.exists():
            raise ReplayError(f'{path}: no such file or directory')
        if path.suffix.lower() == '.mcap':
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
                posture=int(samples.posture[m]), commanded_pose=samples.commanded_poses[m],
                stream=SampleStream(samples.leg_lengths[m:m + 1], samples.readings[m:m + 1]))
            for m in range(len(samples)))
        if not postures:
            raise ReplayError(f'{path}: no posture rows to replay')
        return cls(source=path, kind=SOURCE_SAMPLES, postures=postures,
                   initial_stream=postures[-1].stream)

    @classmethod
    def from_recording(cls, path, sync_tolerance=None):
        """The synchronised samples after each posture's settle, from an MCAP recording.

        Each pose command starts a posture; its ``settled`` status (of the same ``command_id``)
        starts the collection at the start the calibrator noted (MCAP metadata), else at the
        status's receive time; sensor samples stamped from then on, up to the next command, are
        paired like the calibrator pairs them. ``sync_tolerance`` (s) defaults to the
        recording's stored option, else the calibrator's default.
        """
        path = Path(path)
        try:
            return cls._from_recording(path, sync_tolerance)
        except recording.RecordingError as error:
            raise ReplayError(str(error)) from None

    @classmethod
    def _from_recording(cls, path, sync_tolerance):
        from gsp_msgs_py import conversions

        info = recording.recording_info(path)
        options = recording.recording_options(path)
        if sync_tolerance is None:
            sync_tolerance = options.get('sync_tolerance', DEFAULTS['sync_tolerance'])
        try:
            sync_tolerance = float(sync_tolerance)
        except (TypeError, ValueError):
            raise ReplayError(f'{path}: sync_tolerance {sync_tolerance!r} is not a number'
                              ) from None
        if not (math.isfinite(sync_tolerance) and sync_tolerance >= 0.0):
            raise ReplayError(f'{path}: sync_tolerance {sync_tolerance!r} must be >= 0 s')
        notes = recording.collection_notes(info, path)

        initial = _Segment(None, None, 0)
        segments = []
        by_id = {}
        wanted = (names.TOPIC_POSE_COMMAND, names.TOPIC_PLATFORM_STATUS,
                  names.TOPIC_TRUE_POSE) + _SENSOR_TOPICS
        for topic, _, log_time, msg, _ in recording.read_recording(path, topics=wanted):
            try:
                if topic == names.TOPIC_POSE_COMMAND:
                    command_id = conversions.command_id_from_stamp(msg.header.stamp)
                    number = notes.get(command_id, (None, None))[0] or len(segments) + 1
                    segment = _Segment(command_id, conversions.pose_stamped_to_pose(msg),
                                       number)
                    segments.append(segment)
                    by_id[command_id] = segment
                elif topic == names.TOPIC_PLATFORM_STATUS:
                    status = conversions.parse_status(msg)
                    segment = by_id.get(status.command_id)
                    if segment is None:
                        continue
                    if status.settled and segment.settled_ns is None:
                        segment.settled_ns = int(log_time)
                    elif status.rejected and segment.settled_ns is None:
                        segment.rejected = status.reason or 'rejected'
                else:
                    segment = segments[-1] if segments else initial
                    segment.add(topic, msg, conversions)
            except (ValueError, TypeError):
                continue  # malformed or non-finite: the calibrator drops it too

        postures, skipped = [], []
        for segment in segments:
            if segment.rejected:
                skipped.append((segment.number, f'rejected: {segment.rejected}'))
                continue
            if segment.settled_ns is None:
                skipped.append((segment.number, 'never settled'))
                continue
            start = notes.get(segment.command_id, (None, None))[1]
            stream = segment.stream(segment.settled_ns if start is None else start,
                                    sync_tolerance, first=True)
            if len(stream) == 0:
                skipped.append((segment.number, 'no synchronised sample after settling'))
                continue
            postures.append(RecordedPosture(segment.number, segment.pose, stream,
                                            segment.command_id))
        if not postures:
            raise ReplayError(f'{path}: no settled posture with synchronised samples '
                              f'({len(segments)} pose command(s) recorded)')
        initial_stream = initial.stream(None, sync_tolerance, first=False)
        if len(initial_stream) == 0:
            initial_stream = postures[-1].stream
        return cls(source=path, kind=SOURCE_RECORDING, postures=tuple(postures),
                   initial_stream=initial_stream, skipped=tuple(skipped),
                   options=dict(options, sync_tolerance=sync_tolerance))

    # --- lookup ----------------------------------------------------------------------------

    def distances(self, commanded_pose):
        """``(position (M,) m, orientation (M,) rad)`` of ``commanded_pose`` to each posture."""
        pose = np.asarray(commanded_pose, dtype=float)
        if pose.shape != (6,):
            raise ValueError(f'pose: expected [x, y, z, psi, theta, phi], got shape {pose.shape}')
        if not np.all(np.isfinite(pose)):
            raise ValueError(f'pose: non-finite component(s) in {pose.tolist()}')
        position = np.linalg.norm(self._positions - pose[:3], axis=1)
        quaternion = _quaternions(pose)[0]
        chord = np.minimum(np.linalg.norm(self._quaternions - quaternion, axis=1),
                           np.linalg.norm(self._quaternions + quaternion, axis=1))
        # Unit quaternions a rotation angle t apart are 2 sin(t / 4) apart (accurate near 0).
        angle = 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))
        return position, angle

    def match(self, commanded_pose, tolerance=1e-6):
        """The :class:`RecordedPosture` commanded at ``commanded_pose``, or None.

        It must lie within ``tolerance`` (m for the position, rad for the rotation angle between
        the orientations); the nearest one wins (the first of equals). ValueError for a pose
        that is not 6 finite values.
        """
        position, angle = self.distances(commanded_pose)
        distance = np.maximum(position, angle)
        best = int(np.argmin(distance))
        if distance[best] <= float(tolerance):
            return self.postures[best]
        return None


class _Segment:
    """Sensor samples received between one pose command and the next (recording loader)."""

    def __init__(self, command_id, pose, number):
        self.command_id = command_id
        self.pose = pose
        self.number = number
        self.settled_ns = None
        self.rejected = ''
        self.legs = {}  # stamp_ns -> q (6,)
        self.device = {}  # stamp_ns -> [alpha, beta, phi, d_m], NaN until received
        self.true_poses = {}  # stamp_ns -> X (6,)

    def add(self, topic, msg, conversions):
        stamp = conversions.stamp_to_nanoseconds(msg.header.stamp)
        if topic == names.TOPIC_TRUE_POSE:
            self.true_poses[stamp] = conversions.pose_stamped_to_pose(msg)
            return
        if topic == names.TOPIC_LEG_LENGTHS:
            self.legs[stamp] = conversions.msg_to_leg_lengths(msg)
            return
        if topic == names.TOPIC_INCLINOMETER:
            columns, values = (0, 1), conversions.msg_to_inclinometer(msg)
        elif topic == names.TOPIC_ENCODER:
            columns, values = (2,), (conversions.msg_to_encoder(msg),)
        else:
            columns, values = (3,), (conversions.msg_to_lvdt(msg),)
        row = self.device.setdefault(stamp, np.full(4, np.nan))
        row[list(columns)] = values

    def stream(self, start_ns, tolerance, first):
        """The calibrator's pairs of samples stamped from ``start_ns`` (None: all), in stamp
        order: the first (or last) :data:`MAX_STREAM_SAMPLES` leg-length samples."""
        legs = sorted(s for s in self.legs if start_ns is None or s >= start_ns)
        legs = legs[:MAX_STREAM_SAMPLES] if first else legs[-MAX_STREAM_SAMPLES:]
        if not legs:
            return SampleStream(np.zeros((0, 6)), np.zeros((0, 4)))
        margin = int(round(tolerance * 1e9))
        device = [s for s, row in self.device.items()
                  if legs[0] - margin <= s <= legs[-1] + margin
                  and (start_ns is None or s >= start_ns) and np.all(np.isfinite(row))]
        collector = SampleCollector(tolerance, 1, max_buffer=len(legs) + len(device) + 1)
        collector.start(legs[0] - margin if start_ns is None else start_ns)
        for stamp in legs:
            collector.add_leg_lengths(stamp, self.legs[stamp])
        for stamp in device:
            row = self.device[stamp]
            collector.add_inclinometer(stamp, row[0], row[1])
            collector.add_encoder(stamp, row[2])
            collector.add_lvdt(stamp, row[3])
        pairs = collector.pairs()
        q = np.array([self.legs[leg] for leg, _ in pairs]).reshape(-1, 6)
        readings = np.array([self.device[dev] for _, dev in pairs]).reshape(-1, 4)
        return SampleStream(q, readings, self._true_poses([leg for leg, _ in pairs], margin))

    def _true_poses(self, stamps, margin):
        """True pose of each leg-length stamp (same stamp, else nearest within the tolerance);
        None unless every stamp has one."""
        if not self.true_poses or not stamps:
            return None
        known = np.array(sorted(self.true_poses), dtype=np.int64)
        poses = []
        for stamp in stamps:
            i = int(np.searchsorted(known, stamp))
            near = [j for j in (i - 1, i) if 0 <= j < known.size]
            j = min(near, key=lambda j: abs(int(known[j]) - stamp))
            if abs(int(known[j]) - stamp) > margin:
                return None
            poses.append(self.true_poses[int(known[j])])
        return np.array(poses)
