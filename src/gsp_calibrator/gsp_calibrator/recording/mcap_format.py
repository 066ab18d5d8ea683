"""ROS 2 message definitions and QoS metadata as rosbag2 stores them in MCAP (no ROS context)."""

import functools
import importlib
import os
import re
import sys

DEFINITION_SEPARATOR = '=' * 80 + '\n'

# Field types of a .msg line, as rosbag2's LocalMessageDefinitionSource matches them.
_MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVE_TYPES = frozenset(
    'bool byte char float32 float64 int8 uint8 int16 uint16 int32 uint32 int64 uint64 string '
    'wstring'.split()
)
_TYPE_NAME = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:(msg)/)?([A-Za-z][A-Za-z0-9_]*)$')

# rmw's "infinite" duration, as rosbag2 (Jazzy, metadata version 9) writes a default QoS.
_INFINITE = {'sec': 9223372036, 'nsec': 854775807}


class RecordingError(ValueError):
    """A recording cannot be written or read; the message names the file, topic or type."""


class MessageDefinitionError(RecordingError):
    """A message type's ``.msg`` definition cannot be found."""


# --- message definitions ---------------------------------------------------------------------


def split_type_name(type_name):
    """``('sensor_msgs', 'JointState')`` of ``sensor_msgs/msg/JointState`` or ``sensor_msgs/JointState``."""
    match = _TYPE_NAME.match(str(type_name))
    if not match:
        raise MessageDefinitionError(
            f"message type {type_name!r} is not of the form 'pkg/msg/Type' (or 'pkg/Type')"
        )
    return match.group(1), match.group(3)


def normalise_type_name(type_name):
    """``pkg/msg/Type`` of a type name given as ``pkg/msg/Type`` or ``pkg/Type``."""
    package, name = split_type_name(type_name)
    return f'{package}/msg/{name}'


def msg_file(type_name):
    """Path of the ``.msg`` file of ``type_name``; :class:`MessageDefinitionError` if none."""
    from ament_index_python.packages import get_package_share_directory

    package, name = split_type_name(type_name)
    shares = [os.path.join(sys.prefix, 'share', package)]
    try:
        shares.insert(0, get_package_share_directory(package))
    except (LookupError, ValueError, OSError):  # not in the ament index
        pass
    tried = [os.path.join(share, 'msg', name + '.msg') for share in dict.fromkeys(shares)]
    for path in tried:
        if os.path.isfile(path):
            return path
    raise MessageDefinitionError(
        f'no .msg definition of {package}/msg/{name}: looked for {", ".join(tried)} '
        f"(is package '{package}' installed and AMENT_PREFIX_PATH set? "
        f'AMENT_PREFIX_PATH={os.environ.get("AMENT_PREFIX_PATH", "<unset>")})'
    )


def _msg_dependencies(text, package):
    dependencies = set()
    for match in _MSG_FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:
            continue
        dependencies.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(dependencies)


@functools.cache
def message_definition(type_name):
    """The complete ``ros2msg`` definition of ``type_name``, as rosbag2 stores it."""
    seen = set()

    def append(dependency):
        with open(msg_file(dependency), encoding='utf-8') as stream:
            result = stream.read()
        package, _ = split_type_name(dependency)
        for child in _msg_dependencies(result, package):
            if child not in seen:
                seen.add(child)
                result += '\n' + DEFINITION_SEPARATOR + f'MSG: {child}\n' + append(child)
        return result

    return append(normalise_type_name(type_name))


def message_type_name(message):
    """``pkg/msg/Type`` of a generated ROS 2 message object."""
    cls = type(message)
    package = cls.__module__.split('.')[0]
    return f'{package}/msg/{cls.__name__}'


def message_class(type_name):
    """The Python class of ``pkg/msg/Type``; :class:`RecordingError` if it is not importable."""
    package, name = split_type_name(type_name)
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError) as error:
        raise RecordingError(
            f'message type {normalise_type_name(type_name)} is not importable: {error}'
        ) from None


def qos_profiles_yaml(qos):
    """rosbag2's ``offered_qos_profiles`` channel metadata (Jazzy format) of one QoS profile."""

    def duration(key):
        return f'  {key}:\n    sec: {_INFINITE["sec"]}\n    nsec: {_INFINITE["nsec"]}\n'

    return (
        f'- history: {qos.history.name.lower()}\n'
        f'  depth: {int(qos.depth)}\n'
        f'  reliability: {qos.reliability.name.lower()}\n'
        f'  durability: {qos.durability.name.lower()}\n'
        + duration('deadline')
        + duration('lifespan')
        + '  liveliness: automatic\n'
        + duration('liveliness_lease_duration')
        + '  avoid_ros_namespace_conventions: false'
    )
