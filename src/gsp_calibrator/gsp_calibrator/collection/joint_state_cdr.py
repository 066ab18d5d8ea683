"""A ``sensor_msgs/JointState`` read straight from its CDR bytes (pure, no rclpy).
See docs/architecture.md#synchronisation."""

import struct
from types import SimpleNamespace

_HEADER = 4
_UINT = {'<': struct.Struct('<I'), '>': struct.Struct('>I')}
_STAMP = {'<': struct.Struct('<iI'), '>': struct.Struct('>iI')}
#: ``[(bytes, names), ...]``: the name lists met so far (a topic's names rarely change), each
#: with its bytes from its count on; parsing bytes that start with them gives them again.
_NAMES = []
_MAX_CACHED_NAMES = 16


def _align(offset, size):
    return offset + (-(offset - _HEADER) % size)


def _uint(data, order, offset, length):
    offset = _align(offset, 4)
    if offset + 4 > length:
        raise ValueError('JointState CDR message ends early')
    return _UINT[order].unpack_from(data, offset)[0], offset + 4


def _string(data, order, offset, length):
    size, offset = _uint(data, order, offset, length)
    end = offset + size
    if size == 0 or end > length:
        raise ValueError('JointState CDR message has a malformed string')
    return bytes(data[offset : end - 1]).decode('utf-8'), end


def _names(data, order, offset, length):
    """The name list at ``offset`` and the offset after it."""
    for key, names in _NAMES:
        if data[offset : offset + len(key)] == key:
            return list(names), offset + len(key)
    count, end = _uint(data, order, offset, length)
    names = []
    for _ in range(count):
        name, end = _string(data, order, end, length)
        names.append(name)
    if len(_NAMES) < _MAX_CACHED_NAMES:
        _NAMES.append((bytes(data[offset:end]), names))
    return list(names), end


def _doubles(data, order, offset, length):
    count, offset = _uint(data, order, offset, length)
    if not count:
        return (), offset
    offset = _align(offset, 8)
    end = offset + 8 * count
    if end > length:
        raise ValueError('JointState CDR message ends early')
    return struct.unpack_from(f'{order}{count}d', data, offset), end


def read_joint_state(data):
    """The fields of the ``sensor_msgs/JointState`` CDR ``data`` (bytes); ValueError if they are
    not one."""
    length = len(data)
    if length < _HEADER + 8 or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError('not a CDR-encapsulated JointState message')
    order = '<' if data[1] == 1 else '>'
    sec, nanosec = _STAMP[order].unpack_from(data, _HEADER)
    frame_id, offset = _string(data, order, _HEADER + 8, length)
    name, offset = _names(data, order, offset, length)
    position, offset = _doubles(data, order, offset, length)
    velocity, offset = _doubles(data, order, offset, length)
    effort, offset = _doubles(data, order, offset, length)
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec), frame_id=frame_id),
        name=name,
        position=position,
        velocity=velocity,
        effort=effort,
    )
