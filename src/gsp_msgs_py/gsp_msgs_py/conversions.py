"""Conversions between standard ROS 2 messages and the numpy arrays of ``gsp_kinematics``."""

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import Pose, PoseStamped
from sensor_msgs.msg import JointState

from gsp_kinematics import rotation

from . import names

_NS_PER_S = 1_000_000_000


def seconds_to_stamp(seconds):
    """``builtin_interfaces/Time`` for a time in seconds (rounded to the nanosecond)."""
    seconds = float(seconds)
    if not math.isfinite(seconds):
        raise ValueError(f'cannot make a stamp from non-finite seconds {seconds!r}')
    total_ns = int(round(seconds * _NS_PER_S))
    sec, nanosec = divmod(total_ns, _NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def stamp_to_nanoseconds(stamp):
    """Integer nanoseconds of a stamp (``Time`` message, ``rclpy.time.Time`` or seconds)."""
    if hasattr(stamp, 'nanoseconds'):  # rclpy.time.Time
        return int(stamp.nanoseconds)
    if hasattr(stamp, 'sec') and hasattr(stamp, 'nanosec'):  # a Time, or one from mcap
        return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)
    if isinstance(stamp, (int, float, np.floating, np.integer)):
        time_msg = seconds_to_stamp(stamp)
        return int(time_msg.sec) * _NS_PER_S + int(time_msg.nanosec)
    raise TypeError(f'unsupported stamp type {type(stamp).__name__}')


def stamp_to_seconds(stamp):
    """Float seconds of a stamp (``Time`` message, ``rclpy.time.Time`` or seconds)."""
    if isinstance(stamp, (int, float, np.floating, np.integer)):
        return float(stamp)
    return stamp_to_nanoseconds(stamp) / _NS_PER_S


def _to_stamp(stamp):
    if stamp is None:
        return Time()
    if isinstance(stamp, Time):
        return Time(sec=stamp.sec, nanosec=stamp.nanosec)
    if hasattr(stamp, 'to_msg'):  # rclpy.time.Time
        return stamp.to_msg()
    return seconds_to_stamp(stamp)


def command_id_from_stamp(stamp):
    """Command id of a pose command: its ``header.stamp`` in integer nanoseconds, as a string."""
    return str(stamp_to_nanoseconds(stamp))


def _make_joint_state(joint_names, values, stamp, frame_id, what):
    values = np.asarray(values, dtype=float)
    if values.shape != (len(joint_names),):
        raise ValueError(
            f'{what}: expected {len(joint_names)} values for {list(joint_names)}, '
            f'got shape {values.shape}'
        )
    bad = [n for n, v in zip(joint_names, values, strict=True) if not math.isfinite(v)]
    if bad:
        raise ValueError(f'{what}: non-finite value(s) for {bad}: {values.tolist()}')
    msg = JointState()
    msg.header.stamp = _to_stamp(stamp)
    msg.header.frame_id = frame_id
    msg.name = list(joint_names)
    msg.position = values.tolist()
    return msg


def _read_joint_state(msg, joint_names, what):
    msg_names = list(msg.name)
    positions = list(msg.position)
    if len(positions) != len(msg_names):
        raise ValueError(
            f'{what}: JointState has {len(msg_names)} names but {len(positions)} positions'
        )
    index = {name: i for i, name in enumerate(msg_names)}
    duplicated = [n for n in joint_names if msg_names.count(n) > 1]
    if duplicated:
        raise ValueError(f'{what}: duplicated joint name(s) {duplicated}')
    missing = [n for n in joint_names if n not in index]
    if missing:
        raise ValueError(f'{what}: missing joint(s) {missing}; message has names {msg_names}')
    values = np.array([positions[index[n]] for n in joint_names], dtype=float)
    bad = [n for n, v in zip(joint_names, values, strict=True) if not math.isfinite(v)]
    if bad:
        raise ValueError(f'{what}: non-finite value(s) for joint(s) {bad}')
    return values


def leg_lengths_to_msg(q, stamp=None, frame_id=names.FRAME_BASE):
    """JointState ``leg_1..leg_6`` (positions ``q_i`` in m) for ``/gsp/platform/leg_lengths``."""
    return _make_joint_state(names.LEG_JOINT_NAMES, q, stamp, frame_id, 'leg lengths')


def msg_to_leg_lengths(msg):
    """``q`` as ``np.ndarray(6)`` (m) from a leg-lengths JointState, looked up by name."""
    return _read_joint_state(msg, names.LEG_JOINT_NAMES, 'leg lengths')


def device_truth_to_msg(readings, stamp=None, frame_id=names.FRAME_BASE):
    """JointState ``alpha, beta, phi, d_m`` (rad, rad, rad, m) for ``/gsp/platform/device_truth``."""
    return _make_joint_state(
        names.DEVICE_READING_NAMES, readings, stamp, frame_id, 'device readings'
    )


def msg_to_device_truth(msg):
    """``[alpha, beta, phi, d_m]`` as ``np.ndarray(4)`` from a device_truth JointState."""
    return _read_joint_state(msg, names.DEVICE_READING_NAMES, 'device readings')


def inclinometer_to_msg(alpha, beta, stamp=None, frame_id=names.FRAME_BASE):
    """JointState ``alpha``, ``beta`` (rad) for ``/gsp/device/inclinometer``."""
    return _make_joint_state(
        names.INCLINOMETER_JOINT_NAMES, [alpha, beta], stamp, frame_id, 'inclinometer'
    )


def msg_to_inclinometer(msg):
    """``(alpha, beta)`` floats (rad) from an inclinometer JointState."""
    alpha, beta = _read_joint_state(msg, names.INCLINOMETER_JOINT_NAMES, 'inclinometer')
    return float(alpha), float(beta)


def encoder_to_msg(phi, stamp=None, frame_id=names.FRAME_BASE):
    """JointState ``phi`` (rad) for ``/gsp/device/encoder``."""
    return _make_joint_state(names.ENCODER_JOINT_NAMES, [phi], stamp, frame_id, 'encoder')


def msg_to_encoder(msg):
    """``phi`` float (rad) from an encoder JointState."""
    return float(_read_joint_state(msg, names.ENCODER_JOINT_NAMES, 'encoder')[0])


def lvdt_to_msg(d_m, stamp=None, frame_id=names.FRAME_BASE):
    """JointState ``d_m`` (m) for ``/gsp/device/lvdt``."""
    return _make_joint_state(names.LVDT_JOINT_NAMES, [d_m], stamp, frame_id, 'lvdt')


def msg_to_lvdt(msg):
    """``d_m`` float (m) from an LVDT JointState."""
    return float(_read_joint_state(msg, names.LVDT_JOINT_NAMES, 'lvdt')[0])


def pose_to_pose_stamped(X, stamp=None, frame_id=names.FRAME_BASE):  # noqa: N803 (paper notation)
    """PoseStamped for ``X = [x, y, z, psi, theta, phi]`` (m, rad) of the platform frame."""
    X = np.asarray(X, dtype=float)  # noqa: N806
    if X.shape != (6,):
        raise ValueError(f'pose: expected X = [x, y, z, psi, theta, phi], got shape {X.shape}')
    if not np.all(np.isfinite(X)):
        raise ValueError(f'pose: non-finite component(s) in X = {X.tolist()}')
    msg = PoseStamped()
    msg.header.stamp = _to_stamp(stamp)
    msg.header.frame_id = frame_id
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in X[:3])
    # The unit quaternion [x, y, z, w] (w >= 0) of R = R_Y(theta) R_X(psi) R_z(phi).
    quaternion = rotation.matrix_to_quaternion(rotation.euler_to_matrix(X[3:]))
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
    return msg


def pose_stamped_to_pose(msg):
    """``X = [x, y, z, psi, theta, phi]`` (``np.ndarray(6)``, |psi| <= pi/2) of a PoseStamped (or
    Pose); its quaternion is normalised here (ValueError if not finite or of zero norm)."""
    pose = msg.pose if isinstance(msg, PoseStamped) else msg
    if not isinstance(pose, Pose):
        raise TypeError(f'expected PoseStamped or Pose, got {type(msg).__name__}')
    p, o = pose.position, pose.orientation
    position = np.array([p.x, p.y, p.z], dtype=float)
    if not np.all(np.isfinite(position)):
        raise ValueError(f'pose: non-finite position {position.tolist()}')
    quaternion = np.array([o.x, o.y, o.z, o.w], dtype=float)
    try:
        matrix = rotation.quaternion_to_matrix(quaternion)  # non-finite or zero norm: ValueError
    except ValueError:
        raise ValueError(
            f'invalid orientation quaternion [x, y, z, w] = {quaternion.tolist()}'
        ) from None
    return np.concatenate([position, rotation.matrix_to_euler(matrix)])


_LEVEL_OF_STATE = {
    names.STATE_SETTLED: DiagnosticStatus.OK,
    names.STATE_MOVING: DiagnosticStatus.WARN,
    names.STATE_REJECTED: DiagnosticStatus.ERROR,
}


def _level_to_int(level):
    if isinstance(level, (bytes, bytearray)):
        return level[0] if level else 0
    return int(level)


def _key_values(msg, what, required):
    values = {kv.key: kv.value for kv in msg.values}
    missing = [k for k in required if k not in values]
    if missing:
        raise ValueError(f'{what}: missing key(s) {missing}; message has keys {list(values)}')
    return values


@dataclass(frozen=True)
class PlatformStatus:
    """Parsed ``/gsp/platform/status``; ``level`` is the int diagnostic level (0 OK .. 2 ERROR)."""

    command_id: str
    state: str
    reason: str
    level: int

    @property
    def settled(self):
        return self.state == names.STATE_SETTLED

    @property
    def moving(self):
        return self.state == names.STATE_MOVING

    @property
    def rejected(self):
        return self.state == names.STATE_REJECTED


def make_status(command_id, state, reason=''):
    """DiagnosticStatus for ``/gsp/platform/status``."""
    if state not in _LEVEL_OF_STATE:
        raise ValueError(f'status: unknown state {state!r}; expected one of {list(names.STATES)}')
    msg = DiagnosticStatus()
    msg.level = _LEVEL_OF_STATE[state]
    msg.name = names.STATUS_NAME
    msg.hardware_id = names.STATUS_HARDWARE_ID
    msg.message = str(reason) if reason else state
    msg.values = [
        KeyValue(key=names.KEY_COMMAND_ID, value=str(command_id)),
        KeyValue(key=names.KEY_STATE, value=state),
        KeyValue(key=names.KEY_REASON, value=str(reason)),
    ]
    return msg


def parse_status(msg):
    """:class:`PlatformStatus` of a ``/gsp/platform/status`` message; ValueError if malformed."""
    values = _key_values(msg, 'status', (names.KEY_COMMAND_ID, names.KEY_STATE, names.KEY_REASON))
    state = values[names.KEY_STATE]
    if state not in _LEVEL_OF_STATE:
        raise ValueError(f'status: unknown state {state!r}; expected one of {list(names.STATES)}')
    level = _level_to_int(msg.level)
    expected = _level_to_int(_LEVEL_OF_STATE[state])
    if level != expected:
        raise ValueError(
            f'status: level {level} does not match state {state!r} (expects {expected})'
        )
    return PlatformStatus(values[names.KEY_COMMAND_ID], state, values[names.KEY_REASON], level)


@dataclass(frozen=True)
class CalibrationProgress:
    """Parsed ``/gsp/calibrator/progress``."""

    posture_index: int
    posture_count: int
    phase: str
    residuals: object = None
    message: str = ''
    level: int = 0
    extra: dict = field(default_factory=dict)


def _jsonable_residuals(residuals):
    if residuals is None:
        return None
    if isinstance(residuals, Mapping):
        return {str(k): float(v) for k, v in residuals.items()}
    return [float(v) for v in np.asarray(residuals, dtype=float).reshape(-1)]


def make_progress(
    posture_index,
    posture_count,
    phase,
    residuals=None,
    message='',
    *,
    level=None,
    extra=None,
):
    """DiagnosticStatus for ``/gsp/calibrator/progress``: posture k of M, phase, residuals."""
    posture_index, posture_count = int(posture_index), int(posture_count)
    if posture_count < 0 or not 0 <= posture_index <= max(posture_count, 0):
        raise ValueError(
            f'progress: posture index {posture_index} of {posture_count} is out of range'
        )
    if not phase:
        raise ValueError('progress: phase must be a non-empty string')
    if level is None:
        level = DiagnosticStatus.ERROR if phase == names.PHASE_FAILED else DiagnosticStatus.OK
    msg = DiagnosticStatus()
    msg.level = level if isinstance(level, bytes) else bytes([int(level)])
    msg.name = names.PROGRESS_NAME
    msg.hardware_id = names.STATUS_HARDWARE_ID
    msg.message = str(message) if message else f'{phase} {posture_index}/{posture_count}'
    values = [
        KeyValue(key=names.KEY_POSTURE_INDEX, value=str(posture_index)),
        KeyValue(key=names.KEY_POSTURE_COUNT, value=str(posture_count)),
        KeyValue(key=names.KEY_PHASE, value=str(phase)),
        KeyValue(key=names.KEY_RESIDUALS, value=json.dumps(_jsonable_residuals(residuals))),
    ]
    reserved = {kv.key for kv in values}
    for key, value in (extra or {}).items():
        if key in reserved:
            raise ValueError(f'progress: extra key {key!r} is reserved')
        values.append(KeyValue(key=str(key), value=str(value)))
    msg.values = values
    return msg


def parse_progress(msg):
    """:class:`CalibrationProgress` of a ``/gsp/calibrator/progress`` message."""
    required = (names.KEY_POSTURE_INDEX, names.KEY_POSTURE_COUNT, names.KEY_PHASE)
    values = _key_values(msg, 'progress', required)
    try:
        index = int(values[names.KEY_POSTURE_INDEX])
        count = int(values[names.KEY_POSTURE_COUNT])
    except ValueError as exc:
        raise ValueError(f'progress: posture index/count are not integers: {exc}') from None
    residuals = None
    if names.KEY_RESIDUALS in values:
        try:
            residuals = json.loads(values[names.KEY_RESIDUALS])
        except json.JSONDecodeError as exc:
            raise ValueError(f'progress: residuals are not valid JSON: {exc}') from None
    extra = {k: v for k, v in values.items() if k not in required + (names.KEY_RESIDUALS,)}
    return CalibrationProgress(
        posture_index=index,
        posture_count=count,
        phase=values[names.KEY_PHASE],
        residuals=residuals,
        message=msg.message,
        level=_level_to_int(msg.level),
        extra=extra,
    )
