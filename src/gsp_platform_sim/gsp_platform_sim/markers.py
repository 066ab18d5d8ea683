"""RViz view of the platform: polygon and line points (pure numpy) and the MarkerArray message."""

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from gsp_kinematics.rotation import euler_to_matrix

LINE_WIDTH = 0.01  #: m
MARKER_NAMESPACE = 'gsp_platform'

# id, name, marker type, colour (r, g, b, a)
_MARKERS = (
    (0, 'base', Marker.LINE_STRIP, (0.6, 0.6, 0.6, 1.0)),
    (1, 'platform', Marker.LINE_STRIP, (0.2, 0.4, 0.9, 1.0)),
    (2, 'legs', Marker.LINE_LIST, (0.95, 0.55, 0.1, 1.0)),
    (3, 'device_link', Marker.LINE_LIST, (0.1, 0.8, 0.3, 1.0)),
)


def platform_lines(geometry, pose):
    """Points (m, base frame) of the drawing of ``geometry`` at ``pose`` (6,)."""
    pose = np.asarray(pose, dtype=float)
    rotation = euler_to_matrix(pose[3:])
    platform_joints = geometry.platform_joints @ rotation.T + pose[:3]
    base_joints = geometry.base_joints
    legs = np.stack([base_joints, platform_joints], axis=1).reshape(12, 3)
    return {
        'base': np.vstack([base_joints, base_joints[:1]]),
        'platform': np.vstack([platform_joints, platform_joints[:1]]),
        'legs': legs,
        'device_link': np.vstack([np.zeros(3), pose[:3]]),
    }


def make_marker_array(geometry, pose, stamp, frame_id):
    """MarkerArray (base, platform, legs, device link) in ``frame_id`` at ``stamp`` (Time msg)."""
    lines = platform_lines(geometry, pose)
    markers = []
    for marker_id, name, marker_type, rgba in _MARKERS:
        marker = Marker()
        marker.header.stamp = stamp
        marker.header.frame_id = frame_id
        marker.ns = f'{MARKER_NAMESPACE}/{name}'
        marker.id = marker_id
        marker.type = marker_type
        marker.action = Marker.ADD
        marker.pose.orientation.w = 1.0
        marker.scale.x = LINE_WIDTH
        marker.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
        marker.points = [Point(x=x, y=y, z=z) for x, y, z in lines[name].tolist()]
        markers.append(marker)
    return MarkerArray(markers=markers)
