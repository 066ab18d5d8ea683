"""checks.pose_in_frame: frame, finite values and unit quaternion of incoming poses."""

import math

import numpy as np
import pytest

from gsp_msgs_py import conversions, names
from gsp_msgs_py.message_checks import pose_in_frame

X = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])


def test_good_pose_round_trips():
    msg = conversions.pose_to_pose_stamped(X, 1.5, names.FRAME_BASE)
    np.testing.assert_allclose(pose_in_frame(msg, names.FRAME_BASE), X, atol=1e-12)


def test_slightly_non_unit_quaternion_is_normalised():
    msg = conversions.pose_to_pose_stamped(X, None, names.FRAME_BASE)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (round(v, 4) for v in (o.x, o.y, o.z, o.w))
    np.testing.assert_allclose(pose_in_frame(msg, names.FRAME_BASE), X, atol=1e-3)


@pytest.mark.parametrize(
    'field, value, words',
    [
        ('frame', 'world', "frame_id 'world' is not 'gsp_base'"),
        ('frame', '', "frame_id '' is not"),
        ('w', 2.0, 'unit length'),
        ('w', math.nan, 'not finite'),
        ('x', math.inf, 'not finite'),
        ('px', math.nan, 'non-finite'),
    ],
)
def test_bad_poses_raise_value_error_with_the_reason(field, value, words):
    msg = conversions.pose_to_pose_stamped(X, None, names.FRAME_BASE)
    if field == 'frame':
        msg.header.frame_id = value
    elif field == 'px':
        msg.pose.position.x = value
    else:
        setattr(msg.pose.orientation, field, value)
    with pytest.raises(ValueError, match=words):
        pose_in_frame(msg, names.FRAME_BASE)
