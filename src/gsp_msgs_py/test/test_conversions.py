"""Round trips, by-name lookup and error messages of gsp_msgs_py.conversions."""

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState

from gsp_msgs_py import names
from gsp_msgs_py.conversions import (
    command_id_from_stamp,
    encoder_to_msg,
    inclinometer_to_msg,
    leg_lengths_to_msg,
    lvdt_to_msg,
    make_progress,
    make_status,
    msg_to_encoder,
    msg_to_inclinometer,
    msg_to_leg_lengths,
    msg_to_lvdt,
    parse_progress,
    parse_status,
    pose_stamped_to_pose,
    pose_to_pose_stamped,
    seconds_to_stamp,
    stamp_to_nanoseconds,
    stamp_to_seconds,
)


def random_poses(count, seed=0):
    rng = np.random.default_rng(seed)
    poses = np.empty((count, 6))
    poses[:, :3] = rng.uniform(-0.2, 0.8, (count, 3))
    poses[:, 3] = rng.uniform(-1.4, 1.4, count)  # psi, away from gimbal lock at pi/2
    poses[:, 4:] = rng.uniform(-math.pi + 1e-6, math.pi - 1e-6, (count, 2))
    return poses


# ------------------------------------------------------------------------------------ stamps


@pytest.mark.parametrize('seconds', [0.0, 1.5, 12345.000000001, 1.999999999, -2.25])
def test_stamp_round_trip(seconds):
    stamp = seconds_to_stamp(seconds)
    assert 0 <= stamp.nanosec < 1_000_000_000
    assert stamp_to_seconds(stamp) == pytest.approx(seconds, abs=1e-9)


def test_stamp_nanoseconds_and_command_id():
    stamp = Time(sec=3, nanosec=7)
    assert stamp_to_nanoseconds(stamp) == 3_000_000_007
    assert command_id_from_stamp(stamp) == '3000000007'
    assert stamp_to_seconds(2.5) == 2.5


def test_stamp_accepts_rclpy_time():
    from rclpy.time import Time as RclpyTime

    t = RclpyTime(seconds=4, nanoseconds=20)
    assert stamp_to_nanoseconds(t) == 4_000_000_020
    msg = encoder_to_msg(0.1, t)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (4, 20)


def test_stamp_rejects_non_finite():
    with pytest.raises(ValueError, match='non-finite'):
        seconds_to_stamp(float('nan'))


# ------------------------------------------------------------------------------ joint states


def test_leg_lengths_round_trip():
    q = np.array([0.01, -0.02, 0.03, 0.0, 0.05, -0.06])
    msg = leg_lengths_to_msg(q, seconds_to_stamp(10.25), names.FRAME_BASE)
    assert isinstance(msg, JointState)
    assert list(msg.name) == list(names.LEG_JOINT_NAMES)
    assert msg.header.frame_id == 'gsp_base'
    assert stamp_to_seconds(msg.header.stamp) == 10.25
    out = msg_to_leg_lengths(msg)
    assert out.shape == (6,)
    np.testing.assert_array_equal(out, q)


def test_leg_lengths_by_name_not_position():
    msg = JointState()
    msg.name = ['extra', 'leg_6', 'leg_5', 'leg_4', 'leg_3', 'leg_2', 'leg_1']
    msg.position = [99.0, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0]
    np.testing.assert_array_equal(msg_to_leg_lengths(msg), [1, 2, 3, 4, 5, 6])


def test_leg_lengths_missing_names_are_named():
    msg = JointState(name=['leg_1', 'leg_2', 'leg_4', 'leg_5', 'leg_6'], position=[0.0] * 5)
    with pytest.raises(ValueError, match=r"leg lengths: missing joint\(s\) \['leg_3'\]"):
        msg_to_leg_lengths(msg)


def test_leg_lengths_non_finite_is_named():
    msg = JointState(name=list(names.LEG_JOINT_NAMES), position=[0, 0, math.nan, 0, math.inf, 0])
    expected = r"non-finite value\(s\) for joint\(s\) \['leg_3', 'leg_5'\]"
    with pytest.raises(ValueError, match=expected):
        msg_to_leg_lengths(msg)


def test_joint_state_length_mismatch_and_duplicates():
    msg = JointState(name=list(names.LEG_JOINT_NAMES), position=[0.0] * 5)
    with pytest.raises(ValueError, match='6 names but 5 positions'):
        msg_to_leg_lengths(msg)
    msg = JointState(name=['phi', 'phi'], position=[0.1, 0.2])
    with pytest.raises(ValueError, match=r"encoder: duplicated joint name\(s\) \['phi'\]"):
        msg_to_encoder(msg)


def test_leg_lengths_to_msg_validates():
    with pytest.raises(ValueError, match='expected 6 values'):
        leg_lengths_to_msg([0.0] * 5)
    with pytest.raises(ValueError, match=r"non-finite value\(s\) for \['leg_2'\]"):
        leg_lengths_to_msg([0.0, math.nan, 0, 0, 0, 0])


def test_device_round_trips():
    stamp = seconds_to_stamp(1.0)
    msg = inclinometer_to_msg(0.01, -0.02, stamp)
    assert list(msg.name) == ['alpha', 'beta']
    assert msg_to_inclinometer(msg) == (0.01, -0.02)
    msg = encoder_to_msg(1.25, stamp)
    assert list(msg.name) == ['phi']
    assert msg_to_encoder(msg) == 1.25
    msg = lvdt_to_msg(-0.003, stamp)
    assert list(msg.name) == ['d_m']
    assert msg_to_lvdt(msg) == -0.003
    assert isinstance(msg_to_lvdt(msg), float)


def test_device_errors_name_the_payload():
    with pytest.raises(ValueError, match=r"inclinometer: missing joint\(s\) \['beta'\]"):
        msg_to_inclinometer(JointState(name=['alpha'], position=[0.0]))
    with pytest.raises(ValueError, match=r"lvdt: missing joint\(s\) \['d_m'\]"):
        msg_to_lvdt(JointState(name=['phi'], position=[0.0]))


# ------------------------------------------------------------------------------------- poses


def test_quaternion_is_eq2_with_w_non_negative():
    # Eq (2) itself is tested in gsp_kinematics (test_core_rotation); here: the spelling of it.
    for x in random_poses(200, seed=1):
        psi, theta, phi = x[3:]
        msg = pose_to_pose_stamped(x)
        o = msg.pose.orientation
        quat = np.array([o.x, o.y, o.z, o.w])
        assert quat[3] >= 0
        assert math.isclose(np.linalg.norm(quat), 1.0, rel_tol=1e-12)
        expected = Rotation.from_euler('YXZ', [theta, psi, phi]).as_matrix()
        np.testing.assert_allclose(Rotation.from_quat(quat).as_matrix(), expected, atol=1e-12)
        o.x, o.y, o.z, o.w = (-2.0 * quat).tolist()  # any scale and sign
        np.testing.assert_allclose(pose_stamped_to_pose(msg), x, atol=1e-9)


def test_pose_round_trip():
    for x in random_poses(200, seed=2):
        msg = pose_to_pose_stamped(x, seconds_to_stamp(3.0), names.FRAME_BASE)
        assert isinstance(msg, PoseStamped)
        assert msg.header.frame_id == 'gsp_base'
        q = msg.pose.orientation
        assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0, rel_tol=1e-12)
        np.testing.assert_allclose(pose_stamped_to_pose(msg), x, atol=1e-9)
        np.testing.assert_allclose(pose_stamped_to_pose(msg.pose), x, atol=1e-9)


def test_pose_from_scipy_quaternion():
    x = np.array([0.1, -0.2, 0.9, 0.3, -0.4, 2.0])
    msg = PoseStamped()
    qx, qy, qz, qw = Rotation.from_euler('YXZ', [x[4], x[3], x[5]]).as_quat()
    scale = 3.0  # un-normalised quaternions are accepted
    msg.pose.orientation.x, msg.pose.orientation.y = scale * qx, scale * qy
    msg.pose.orientation.z, msg.pose.orientation.w = scale * qz, scale * qw
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x[:3]
    np.testing.assert_allclose(pose_stamped_to_pose(msg), x, atol=1e-12)


def test_pose_errors():
    with pytest.raises(ValueError, match='got shape'):
        pose_to_pose_stamped([0.0] * 5)
    with pytest.raises(ValueError, match='non-finite'):
        pose_to_pose_stamped([0, 0, math.nan, 0, 0, 0])
    zero_quaternion = PoseStamped()
    zero_quaternion.pose.orientation.w = 0.0
    with pytest.raises(ValueError, match='invalid orientation quaternion'):
        pose_stamped_to_pose(zero_quaternion)
    for bad in ([0.0, 0.0, math.nan, 1.0], [1e-12, 0.0, 0.0, 0.0]):
        o = zero_quaternion.pose.orientation
        o.x, o.y, o.z, o.w = bad
        with pytest.raises(ValueError, match=r'invalid orientation quaternion \[x, y, z, w\] = \['):
            pose_stamped_to_pose(zero_quaternion)
    with pytest.raises(TypeError):
        pose_stamped_to_pose(JointState())


# ------------------------------------------------------------------------------------ status


@pytest.mark.parametrize(
    'state, level',
    [
        ('settled', DiagnosticStatus.OK),
        ('moving', DiagnosticStatus.WARN),
        ('rejected', DiagnosticStatus.ERROR),
    ],
)
def test_status_round_trip(state, level):
    reason = 'unreachable: leg_2 too long' if state == 'rejected' else ''
    msg = make_status('123', state, reason)
    assert isinstance(msg, DiagnosticStatus)
    assert msg.level == level
    status = parse_status(msg)
    assert status.command_id == '123'
    assert status.state == state
    assert status.level == level[0]
    assert getattr(status, state)
    if state == 'rejected':
        assert msg.message == status.reason == 'unreachable: leg_2 too long'
    else:
        assert msg.message == state


def test_status_errors():
    with pytest.raises(ValueError, match="unknown state 'done'"):
        make_status(1, 'done')
    msg = make_status(1, 'settled')
    msg.values = [kv for kv in msg.values if kv.key != 'command_id']
    with pytest.raises(ValueError, match=r"status: missing key\(s\) \['command_id'\]"):
        parse_status(msg)
    msg = make_status(1, 'settled')
    msg.level = DiagnosticStatus.ERROR
    with pytest.raises(ValueError, match='does not match state'):
        parse_status(msg)


# ---------------------------------------------------------------------------------- progress


def test_progress_round_trip_mapping():
    residuals = {'leg_rms': 1.5e-5, 'device_rms': np.float64(2e-6)}
    msg = make_progress(3, 20, names.PHASE_COLLECTING, residuals, extra={'run': 'r1'})
    progress = parse_progress(msg)
    assert (progress.posture_index, progress.posture_count) == (3, 20)
    assert progress.phase == 'collecting'
    assert progress.residuals == {'leg_rms': 1.5e-5, 'device_rms': 2e-6}
    assert progress.extra == {'run': 'r1'}
    assert progress.level == 0
    assert progress.message == 'collecting 3/20'


def test_progress_round_trip_sequence_and_failure():
    msg = make_progress(0, 0, names.PHASE_FAILED, np.array([1.0, 2.0]), 'no postures')
    progress = parse_progress(msg)
    assert progress.residuals == [1.0, 2.0]
    assert progress.level == DiagnosticStatus.ERROR[0]
    assert progress.message == 'no postures'
    assert parse_progress(make_progress(1, 2, 'moving')).residuals is None


def test_progress_errors():
    with pytest.raises(ValueError, match='out of range'):
        make_progress(5, 4, 'moving')
    with pytest.raises(ValueError, match='reserved'):
        make_progress(1, 4, 'moving', extra={'phase': 'x'})
    msg = DiagnosticStatus(values=[KeyValue(key='phase', value='moving')])
    with pytest.raises(ValueError, match=r"missing key\(s\) \['posture_index', 'posture_count'\]"):
        parse_progress(msg)
