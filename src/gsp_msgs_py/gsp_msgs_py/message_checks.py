"""Checks of incoming messages before they reach the core (no node, no rclpy context needed)."""

import math

from . import conversions

#: Largest accepted deviation of an orientation quaternion's norm from 1. Hand-typed
#: ``ros2 topic pub`` values such as ``{z: 0.7071, w: 0.7071}`` pass; the quaternion is normalised.
QUATERNION_NORM_TOLERANCE = 1e-3


def pose_in_frame(msg, frame_id, quaternion_tolerance=QUATERNION_NORM_TOLERANCE):
    """``X = [x, y, z, psi, theta, phi]`` (m, rad) of a PoseStamped expressed in ``frame_id``."""
    if msg.header.frame_id != frame_id:
        raise ValueError(f"pose: frame_id '{msg.header.frame_id}' is not '{frame_id}'")
    o = msg.pose.orientation
    norm = math.sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w)
    if not math.isfinite(norm):
        raise ValueError(
            f'pose: orientation quaternion is not finite: [{o.x}, {o.y}, {o.z}, {o.w}]'
        )
    if abs(norm - 1.0) > quaternion_tolerance:
        raise ValueError(f'pose: orientation quaternion is not of unit length (norm {norm:.6g})')
    return conversions.pose_stamped_to_pose(msg)
