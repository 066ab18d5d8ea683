"""ROS 2 message definitions and QoS metadata as rosbag2 stores them in MCAP (no ROS context)."""

import importlib
import os
import re
import sys

DEFINITION_SEPARATOR = '=' * 80 + '\n'

# Field types of a .msg line, as rosbag2's LocalMessageDefinitionSource matches them.
_MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVE_TYPES = frozenset(
    {
        'bool',
        'byte',
        'char',
        'float32',
        'float64',
        'int8',
        'uint8',
        'int16',
        'uint16',
        'int32',
        'uint32',
        'int64',
        'uint64',
        'string',
        'wstring',
    }
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


def _share_directories(package):
    directories = []
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )

        try:
            directories.append(get_package_share_directory(package))
        except (PackageNotFoundError, LookupError, ValueError, OSError):
            pass
    except ImportError:  # pragma: no cover - ament_index_python ships with rclpy
        pass
    fallback = os.path.join(sys.prefix, 'share', package)
    if fallback not in directories:
        directories.append(fallback)
    return directories


def msg_file(type_name):
    """Path of the ``.msg`` file of ``type_name``; :class:`MessageDefinitionError` if none."""
    package, name = split_type_name(type_name)
    tried = []
    for share in _share_directories(package):
        path = os.path.join(share, 'msg', name + '.msg')
        if os.path.isfile(path):
            return path
        tried.append(path)
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


_DEFINITION_CACHE = {}


def message_definition(type_name):
    """The complete ``ros2msg`` definition of ``type_name``, as rosbag2 stores it."""
    root = normalise_type_name(type_name)
    if root in _DEFINITION_CACHE:
        return _DEFINITION_CACHE[root]
    texts = {}

    def load(dependency):
        key = normalise_type_name(dependency)
        if key not in texts:
            with open(msg_file(key), encoding='utf-8') as stream:
                texts[key] = stream.read()
        return texts[key]

    seen = set()

    def append(dependency, depth):
        if depth <= 0:
            raise MessageDefinitionError(f'{root}: message definitions nest too deeply')
        text = load(dependency)
        package, _ = split_type_name(dependency)
        result = text
        for child in _msg_dependencies(text, package):
            if child not in seen:
                seen.add(child)
                result += '\n' + DEFINITION_SEPARATOR + f'MSG: {child}\n' + append(child, depth - 1)
        return result

    definition = append(root, 50)
    _DEFINITION_CACHE[root] = definition
    return definition


def message_type_name(message):
    """``pkg/msg/Type`` of a generated ROS 2 message object."""
    cls = type(message)
    package = cls.__module__.split('.')[0]
    return f'{package}/msg/{cls.__name__}'


def message_class(type_name):
    """The Python class of ``pkg/msg/Type`` (rosidl_runtime_py when present, else importlib)."""
    type_name = normalise_type_name(type_name)
    try:
        from rosidl_runtime_py.utilities import get_message
    except ImportError:
        get_message = None
    if get_message is not None:
        try:
            return get_message(type_name)
        except (AttributeError, ModuleNotFoundError, ValueError) as error:
            raise RecordingError(f'message type {type_name} is not importable: {error}') from None
    package, name = split_type_name(type_name)
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError) as error:
        raise RecordingError(f'message type {type_name} is not importable: {error}') from None


def qos_profiles_yaml(qos):
    """rosbag2's ``offered_qos_profiles`` channel metadata (Jazzy format) of one QoS profile."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

    history = 'keep_all' if qos.history == HistoryPolicy.KEEP_ALL else 'keep_last'
    reliability = {
        ReliabilityPolicy.BEST_EFFORT: 'best_effort',
        ReliabilityPolicy.RELIABLE: 'reliable',
    }.get(qos.reliability, 'system_default')
    durability = {
        DurabilityPolicy.TRANSIENT_LOCAL: 'transient_local',
        DurabilityPolicy.VOLATILE: 'volatile',
    }.get(qos.durability, 'system_default')

    def duration(key):
        return f'  {key}:\n    sec: {_INFINITE["sec"]}\n    nsec: {_INFINITE["nsec"]}\n'

    return (
        f'- history: {history}\n'
        f'  depth: {int(qos.depth)}\n'
        f'  reliability: {reliability}\n'
        f'  durability: {durability}\n'
        + duration('deadline')
        + duration('lifespan')
        + '  liveliness: automatic\n'
        + duration('liveliness_lease_duration')
        + '  avoid_ros_namespace_conventions: false'
    )
