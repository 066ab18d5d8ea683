"""``recording.mcap``: every message on the suite's topics during a run, as rosbag2 writes it.

The file is an MCAP file with profile ``ros2``: one schema per message type (encoding ``ros2msg``,
the complete concatenated ``.msg`` definition exactly as rosbag2's local definition source builds
it), one channel per topic (message encoding ``cdr``, rosbag2's ``offered_qos_profiles`` channel
metadata), ``log_time`` = receive time and ``publish_time`` in nanoseconds. ``ros2 bag info
recording.mcap``, ``ros2 bag play recording.mcap`` (storage ``mcap``) and Foxglove read it.

* :class:`McapRecorder` writes one file atomically (``<path>.tmp``, then ``os.replace`` on close).
* :func:`read_recording` iterates over ``(topic, type_name, log_time_ns, message)``.
* :func:`samples_from_recording` rebuilds the ``samples.csv`` rows of a run from the recorded
  pose commands, statuses, leg lengths and device readings, with the calibrator's own
  :class:`gsp_calibrator.collector.SampleCollector`.
* :class:`RunRecorder` records the suite's topics from inside a node (raw CDR subscriptions).

Nothing here needs a ROS context except :class:`RunRecorder`; message definitions are looked up
through the ament index (``AMENT_PREFIX_PATH``) and, failing that, ``<sys.prefix>/share``.
"""

import collections
import importlib
import json
import os
import re
import sys
import threading
import time

import numpy as np

from gsp_msgs_py import names

from .collector import SampleCollector
from .run_directory import Samples

RECORDING_FILE = 'recording.mcap'
PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
DEFINITION_SEPARATOR = '=' * 80 + '\n'

#: MCAP metadata record holding the run's options (written by :class:`RunRecorder`).
RUN_METADATA_NAME = 'gsp_calibration'
#: MCAP metadata record of one posture's collection start (see :meth:`RunRecorder.note_collection_start`).
POSTURE_METADATA_NAME = 'gsp_posture'

#: Topics :class:`RunRecorder` records by default: every topic of the suite.
SUITE_TOPICS = dict(names.TOPIC_TYPES)

# Field types of a .msg line, as rosbag2's LocalMessageDefinitionSource matches them.
_MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16', 'int32',
    'uint32', 'int64', 'uint64', 'string', 'wstring',
})
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
        f"no .msg definition of {package}/msg/{name}: looked for {', '.join(tried)} "
        f"(is package '{package}' installed and AMENT_PREFIX_PATH set? "
        f"AMENT_PREFIX_PATH={os.environ.get('AMENT_PREFIX_PATH', '<unset>')})"
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
    """The complete ``ros2msg`` definition of ``type_name``, as rosbag2 stores it.

    The type's own ``.msg`` text comes first; every type it depends on, recursively and once,
    follows as ``"\\n" + "=" * 80 + "\\nMSG: pkg/Type\\n" + text`` (depth first, dependencies of
    each definition in sorted order: rosbag2's ``LocalMessageDefinitionSource``).
    """
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
        return (f'  {key}:\n    sec: {_INFINITE["sec"]}\n    nsec: {_INFINITE["nsec"]}\n')

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


# --- writing -----------------------------------------------------------------------------------


class McapRecorder:
    """Writes ``path`` (an MCAP file rosbag2 and Foxglove read) atomically.

    Messages go to ``<path>.tmp``; :meth:`close` finishes the file (summary, indexes) and renames
    it over ``path``. :meth:`abort` removes the temporary file. Thread-safe. As a context manager
    the file is closed (kept) even when the block raises: recorded data is never thrown away.
    """

    def __init__(self, path, compression='zstd', chunk_size=1024 * 1024, library=None):
        from mcap.writer import CompressionType, Writer

        self.path = os.fspath(path)
        self.temporary_path = self.path + '.tmp'
        types = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                 None: CompressionType.NONE, 'none': CompressionType.NONE}
        if compression not in types:
            raise RecordingError(f'unknown compression {compression!r}: zstd, lz4 or none')
        directory = os.path.dirname(os.path.abspath(self.path))
        os.makedirs(directory, exist_ok=True)
        self._stream = open(self.temporary_path, 'wb')  # noqa: SIM115 (closed in close/abort)
        try:
            try:
                self._writer = Writer(self._stream, chunk_size=chunk_size,
                                      compression=types[compression])
            except Exception:  # compression library missing: write uncompressed chunks
                self._writer = Writer(self._stream, chunk_size=chunk_size,
                                      compression=CompressionType.NONE)
            self._writer.start(profile=PROFILE, library=library or _library_identifier())
        except BaseException:
            self._stream.close()
            os.unlink(self.temporary_path)
            raise
        self._lock = threading.Lock()
        self._schemas = {}  # type name -> schema id
        self._channels = {}  # topic -> (channel id, type name)
        self._sequence = collections.Counter()
        self.message_count = 0
        #: Messages written per topic.
        self.counts = collections.Counter()
        self.closed = False

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def add_topic(self, topic, type_name, qos=None):
        """Register ``topic`` (``pkg/msg/Type``); idempotent. ``qos``: the publisher's profile."""
        type_name = normalise_type_name(type_name)
        with self._lock:
            self._check_open()
            if topic in self._channels:
                if self._channels[topic][1] != type_name:
                    raise RecordingError(
                        f'topic {topic} is already recorded as {self._channels[topic][1]}, '
                        f'not {type_name}'
                    )
                return self._channels[topic][0]
            if type_name not in self._schemas:
                definition = message_definition(type_name)
                self._schemas[type_name] = self._writer.register_schema(
                    name=type_name, encoding=SCHEMA_ENCODING, data=definition.encode('utf-8'))
            metadata = {}
            if qos is None:
                from gsp_msgs_py.qos import TOPIC_QOS

                qos = TOPIC_QOS.get(topic)
            if qos is not None:
                metadata['offered_qos_profiles'] = qos_profiles_yaml(qos)
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding=MESSAGE_ENCODING,
                schema_id=self._schemas[type_name], metadata=metadata)
            self._channels[topic] = (channel_id, type_name)
            return channel_id

    def write(self, topic, message, log_time_ns=None, publish_time_ns=None):
        """Write one message: a ROS 2 message object or its CDR bytes (``raw=True``).

        ``log_time_ns``: receive time (default now); ``publish_time_ns`` defaults to it. A topic
        not yet added is added from the message's type (raw bytes need :meth:`add_topic` first).
        """
        if isinstance(message, (bytes, bytearray, memoryview)):
            data = bytes(message)
            if topic not in self._channels:
                raise RecordingError(f'raw message on {topic}: add_topic() the topic first')
        else:
            from rclpy.serialization import serialize_message

            if topic not in self._channels:
                self.add_topic(topic, message_type_name(message))
            data = serialize_message(message)
        log_time_ns = time.time_ns() if log_time_ns is None else int(log_time_ns)
        publish_time_ns = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        with self._lock:
            self._check_open()
            channel_id = self._channels[topic][0]
            self._sequence[channel_id] += 1
            self._writer.add_message(
                channel_id=channel_id, log_time=log_time_ns, publish_time=publish_time_ns,
                sequence=self._sequence[channel_id] & 0xFFFFFFFF, data=data)
            self.message_count += 1
            self.counts[topic] += 1

    def add_metadata(self, name, data):
        """An MCAP metadata record ``name`` of string key/values (ignored by rosbag2 play)."""
        with self._lock:
            self._check_open()
            self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    @property
    def topics(self):
        """``{topic: type_name}`` registered so far."""
        return {topic: type_name for topic, (_, type_name) in self._channels.items()}

    def close(self):
        """Finish the file and move it to :attr:`path` (atomic). Idempotent; returns the path."""
        with self._lock:
            if self.closed:
                return self.path
            self.closed = True
            try:
                self._writer.finish()
                self._stream.flush()
                os.fsync(self._stream.fileno())
            finally:
                self._stream.close()
            os.chmod(self.temporary_path, 0o644)
            os.replace(self.temporary_path, self.path)
        return self.path

    def abort(self):
        """Discard the recording (the temporary file is removed, :attr:`path` untouched)."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            self._stream.close()
            try:
                os.unlink(self.temporary_path)
            except FileNotFoundError:
                pass

    def _check_open(self):
        if self.closed:
            raise RecordingError(f'{self.path}: the recording is closed')


def _library_identifier():
    try:
        from importlib.metadata import version

        mcap_version = version('mcap')
    except Exception:  # pragma: no cover
        mcap_version = '?'
    return f'gsp_calibrator recording; mcap-python/{mcap_version}'


# --- reading ---------------------------------------------------------------------------------

RecordedMessage = collections.namedtuple(
    'RecordedMessage', 'topic type_name log_time_ns message publish_time_ns')
RecordedMessage.__doc__ = 'One recorded message (log and publish time in ns).'


def _open_reader(path):
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    path = os.fspath(path)
    try:
        stream = open(path, 'rb')  # noqa: SIM115 (closed by the caller)
    except OSError as error:
        raise RecordingError(f'{path}: cannot open ({error.strerror})') from error
    try:
        return stream, make_reader(stream)
    except (McapError, ValueError, EOFError) as error:
        stream.close()
        raise RecordingError(f'{path}: not an MCAP file ({error})') from error


def _dynamic_decoder(schema):
    from mcap_ros2.decoder import DecoderFactory

    decoder = DecoderFactory().decoder_for(MESSAGE_ENCODING, schema)
    if decoder is None:
        raise RecordingError(f'cannot decode schema {schema.name!r} ({schema.encoding})')
    return decoder


def read_recording(path, topics=None, raw=False):
    """Iterate over the messages of an MCAP recording in log-time order.

    Yields :class:`RecordedMessage` ``(topic, type_name, log_time_ns, message, publish_time_ns)``;
    ``message`` is the ROS 2 message object (``rclpy.serialization.deserialize_message`` of the
    generated class; a dynamically decoded object from the schema when the class is not
    importable), or the CDR bytes with ``raw=True``. ``topics`` restricts the topics read.
    """
    from mcap.exceptions import McapError

    stream, reader = _open_reader(path)
    classes = {}
    try:
        if isinstance(topics, str):
            topics = [topics]
        try:
            for schema, channel, record in reader.iter_messages(topics=topics,
                                                                log_time_order=True):
                if channel.message_encoding != MESSAGE_ENCODING:
                    raise RecordingError(
                        f'{path}: topic {channel.topic} is encoded as '
                        f'{channel.message_encoding!r}, not cdr')
                type_name = schema.name if schema is not None else ''
                if raw:
                    message = bytes(record.data)
                else:
                    message = _decode(classes, schema, channel, record, path)
                yield RecordedMessage(channel.topic, type_name, record.log_time, message,
                                      record.publish_time)
        except McapError as error:
            raise RecordingError(f'{path}: corrupt MCAP file ({error})') from error
    finally:
        stream.close()


def _decode(classes, schema, channel, record, path):
    from rclpy.serialization import deserialize_message

    if schema is None:
        raise RecordingError(f'{path}: topic {channel.topic} has no schema')
    decode = classes.get(schema.id)
    if decode is None:
        try:
            cls = message_class(schema.name)

            def decode(data, cls=cls):
                return deserialize_message(data, cls)
        except RecordingError:
            decode = _dynamic_decoder(schema)
        classes[schema.id] = decode
    try:
        return decode(bytes(record.data))
    except Exception as error:
        raise RecordingError(
            f'{path}: cannot decode a {schema.name} message on {channel.topic} '
            f'at log time {record.log_time} ns ({error})') from error


def recording_info(path):
    """``{topics: {topic: {type, count}}, start_ns, end_ns, message_count, metadata: {name: [dict]}}``."""
    stream, reader = _open_reader(path)
    try:
        summary = reader.get_summary()
        topics, start, end, count = {}, None, None, 0
        if summary is not None and summary.statistics is not None:
            stats = summary.statistics
            for channel_id, channel in summary.channels.items():
                schema = summary.schemas.get(channel.schema_id)
                topics[channel.topic] = {
                    'type': schema.name if schema else '',
                    'count': int(stats.channel_message_counts.get(channel_id, 0)),
                }
            count = int(stats.message_count)
            if count:
                start, end = int(stats.message_start_time), int(stats.message_end_time)
        else:  # no summary: scan
            for schema, channel, record in reader.iter_messages(log_time_order=False):
                entry = topics.setdefault(
                    channel.topic, {'type': schema.name if schema else '', 'count': 0})
                entry['count'] += 1
                count += 1
                start = record.log_time if start is None else min(start, record.log_time)
                end = record.log_time if end is None else max(end, record.log_time)
        metadata = collections.defaultdict(list)
        for record in reader.iter_metadata():
            metadata[record.name].append(dict(record.metadata))
        return {'topics': topics, 'start_ns': start, 'end_ns': end, 'message_count': count,
                'metadata': dict(metadata), 'profile': reader.get_header().profile}
    finally:
        stream.close()


def recording_options(path):
    """The run options stored in the recording (``{}`` if none), e.g. ``sync_tolerance``."""
    entries = recording_info(path)['metadata'].get(RUN_METADATA_NAME, [])
    options = {}
    for entry in entries:
        for key, value in entry.items():
            try:
                options[key] = json.loads(value)
            except json.JSONDecodeError:
                options[key] = value
    return options


# --- samples from a recording -------------------------------------------------------------------


def _stamp_ns(msg):
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


_SENSOR_STREAMS = {
    names.TOPIC_LEG_LENGTHS: ('leg_lengths', 'add_leg_lengths'),
    names.TOPIC_INCLINOMETER: ('inclinometer', 'add_inclinometer'),
    names.TOPIC_ENCODER: ('encoder', 'add_encoder'),
    names.TOPIC_LVDT: ('lvdt', 'add_lvdt'),
}


def _sensor_values(topic, msg):
    """``values`` tuple of a sensor message (as the calibrator reads it); ValueError if unusable."""
    from gsp_msgs_py import conversions

    if topic == names.TOPIC_LEG_LENGTHS:
        return (conversions.msg_to_leg_lengths(msg),)
    if topic == names.TOPIC_INCLINOMETER:
        return conversions.msg_to_inclinometer(msg)
    if topic == names.TOPIC_ENCODER:
        return (conversions.msg_to_encoder(msg),)
    return (conversions.msg_to_lvdt(msg),)


def noise_std_from_options(options):
    """The collector's 10 channel noise stds ``[q_1..q_6, alpha, beta, phi, d_m]`` (m, rad).

    From ``options['noise_std']`` (10 values), else the ``sigma_*`` options, else the calibrator's
    default sigmas (the calibrator builds its collector from its sigma parameters).
    """
    if options.get('noise_std') is not None:
        values = np.asarray(options['noise_std'], dtype=float).reshape(-1)
        if values.shape != (10,):
            raise RecordingError(f'noise_std must hold 10 values, got {values.tolist()}')
        return values
    from .settings import DEFAULTS

    def sigma(name):
        return float(options.get(name, DEFAULTS[name]))

    return np.array([sigma('sigma_leg_lengths')] * 6 + [sigma('sigma_inclinometer')] * 2
                    + [sigma('sigma_encoder'), sigma('sigma_lvdt')])


def samples_from_recording(path, sync_tolerance=None, samples_per_posture=None, noise_std=None):
    """Rebuild the ``samples.csv`` rows (:class:`~gsp_calibrator.run_directory.Samples`).

    Replays the recorded messages in log-time order through the calibrator's
    :class:`~gsp_calibrator.collector.SampleCollector`, driven as the calibrator node drives it:

    * each ``pose_command`` is the awaited posture (numbered 1, 2, ... in command order; a
      rejected or unfinished one gives no row and keeps its number); the previous posture's
      readings are its row's (for the first posture: the last complete device instant received
      before the command);
    * the awaited command's ``settled`` status starts the collection, with those previous
      readings, at the time the node noted with :meth:`RunRecorder.note_collection_start` (else at
      the status's receive time); sensor samples stamped from then on count, including any
      received just before the status;
    * the row is the collector's consistent window, taken as soon as the collector is ready.

    ``sync_tolerance`` (s), ``samples_per_posture`` and ``noise_std`` (10 channel stds, see
    :func:`noise_std_from_options`) default to the options stored by :meth:`RunRecorder.start`;
    :class:`RecordingError` if the first two are not known.
    """
    from gsp_msgs_py import conversions

    info = recording_info(path)
    stored = recording_options(path)
    if sync_tolerance is None:
        sync_tolerance = stored.get('sync_tolerance')
    if samples_per_posture is None:
        samples_per_posture = stored.get('samples_per_posture')
    if sync_tolerance is None or samples_per_posture is None:
        raise RecordingError(
            f'{path}: sync_tolerance and samples_per_posture are not stored in the recording; '
            'give them explicitly')
    if noise_std is None:
        noise_std = noise_std_from_options(stored)
    notes = collection_notes(info, path)
    collector = SampleCollector(sync_tolerance, samples_per_posture, noise_std=noise_std)
    samples = Samples.empty()
    wanted = (names.TOPIC_POSE_COMMAND, names.TOPIC_PLATFORM_STATUS) + tuple(_SENSOR_STREAMS)
    awaited = None  # (command id, posture number, commanded pose) of the latest command
    collecting = False
    previous = None  # device readings of the previous posture
    latest = {}  # device stream -> (stamp_ns, values) of its latest usable message
    recent = collections.deque(maxlen=4 * collector.max_buffer)  # samples since the command
    checked_pairs = None
    count = 0
    for topic, _, log_time, msg, _ in read_recording(path, topics=wanted):
        try:
            if topic == names.TOPIC_POSE_COMMAND:
                command_id = conversions.command_id_from_stamp(msg.header.stamp)
                count += 1
                if count == 1 or previous is None:
                    previous = _latest_device_readings(latest)
                number = notes.get(command_id, (None, None))[0] or count
                awaited = (command_id, number, conversions.pose_stamped_to_pose(msg))
                collector.stop()
                collecting = False
                recent.clear()
                continue
            if topic == names.TOPIC_PLATFORM_STATUS:
                status = conversions.parse_status(msg)
                if awaited is None or status.command_id != awaited[0]:
                    continue
                if status.settled and not collecting:
                    collector.start(notes.get(status.command_id, (None, log_time))[1], previous)
                    collecting = True
                    for adder, stamp, values in recent:  # those stamped after the start count
                        getattr(collector, adder)(stamp, *values)
                    recent.clear()
                elif status.rejected:
                    collector.stop()
                    collecting = False
                    awaited = None
                    continue
                else:
                    continue
            else:
                stream, adder = _SENSOR_STREAMS[topic]
                stamp = _stamp_ns(msg)
                values = _sensor_values(topic, msg)
                if stream != 'leg_lengths':
                    latest[stream] = (stamp, values)
                if collecting:
                    getattr(collector, adder)(stamp, *values)
                elif awaited is not None:
                    recent.append((adder, stamp, values))
        except ValueError:
            continue  # a malformed or non-finite message: the calibrator drops it too
        if not collecting:
            continue
        # ready() is a function of the pairs: only ask again when they changed (it is costly).
        pairs = collector.pairs()
        if pairs == checked_pairs:
            continue
        checked_pairs = pairs
        if collector.ready():
            sample = collector.take_posture()
            samples.append(awaited[1], awaited[2], sample.leg_lengths, sample.readings,
                           sample.n_samples, sample.stamp)
            previous = sample.readings
            collecting = False
            awaited = None
    return samples


def _latest_device_readings(latest):
    items = [latest.get(stream) for stream in ('inclinometer', 'encoder', 'lvdt')]
    if any(item is None for item in items) or len({item[0] for item in items}) != 1:
        return None
    return np.concatenate([np.asarray(item[1], dtype=float) for item in items])


def collection_notes(info, path='<recording>'):
    """``{command_id: (posture or None, start_ns)}`` noted by :meth:`RunRecorder.note_collection_start`."""
    notes = {}
    for entry in info['metadata'].get(POSTURE_METADATA_NAME, []):
        try:
            posture = entry.get('posture')
            notes[str(entry['command_id'])] = (
                int(posture) if posture not in (None, '', 'None') else None,
                int(entry['start_ns']))
        except (KeyError, ValueError) as error:
            raise RecordingError(f'{path}: malformed {POSTURE_METADATA_NAME} metadata {entry}'
                                 ) from error
    return notes


# --- recording from a node ---------------------------------------------------------------------


class RunRecorder:
    """Records the suite's topics from inside a node into ``recording.mcap``.

    Subscriptions (``raw=True``: CDR bytes, no deserialisation) are created by :meth:`start` with
    each topic's profile of :data:`gsp_msgs_py.qos.TOPIC_QOS` (sensor QoS for the streams, the
    publishers' QoS for the others) and destroyed by :meth:`stop`. Each message is written with
    its receive time on the node's clock, the time base of the calibrator's collector. Callbacks
    run in the recorder's own callback group, so they never wait for the node's other callbacks.

    ``persistent=True``: the subscriptions are created once, here, and kept for the node's
    lifetime (messages outside a recording are dropped at once). Destroying a subscription while
    another thread's executor builds its wait set can raise ``InvalidHandle`` (ros2/rclpy#1206).
    """

    def __init__(self, node, topics=None, callback_group=None, persistent=False):
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

        self.node = node
        self.topics = dict(SUITE_TOPICS if topics is None else topics)
        self.callback_group = callback_group or MutuallyExclusiveCallbackGroup()
        self.persistent = bool(persistent)
        self._recorder = None
        self._subscriptions = []
        self._lock = threading.Lock()
        if self.persistent:
            self._subscribe()

    def _subscribe(self):
        from gsp_msgs_py.qos import SENSOR_QOS, TOPIC_QOS

        for topic, type_name in self.topics.items():
            self._subscriptions.append(self.node.create_subscription(
                message_class(type_name), topic, self._callback(topic),
                TOPIC_QOS.get(topic, SENSOR_QOS), callback_group=self.callback_group, raw=True))

    @property
    def recording(self):
        return self._recorder is not None

    @property
    def path(self):
        return self._recorder.path if self._recorder is not None else None

    @property
    def counts(self):
        """Messages recorded per topic so far (empty when not recording)."""
        recorder = self._recorder
        return dict(recorder.counts) if recorder is not None else {}

    def start(self, path, options=None):
        """Start recording to ``path`` (e.g. ``run_dir / 'recording.mcap'``).

        ``options`` (e.g. ``{'sync_tolerance': 0.002, 'samples_per_posture': 5}``) are stored in
        the file so that offline re-identification uses the same ones by default.
        """
        from gsp_msgs_py.qos import SENSOR_QOS, TOPIC_QOS

        self.stop()
        recorder = McapRecorder(path)
        try:
            for topic, type_name in self.topics.items():
                recorder.add_topic(topic, type_name, TOPIC_QOS.get(topic, SENSOR_QOS))
            if options:
                recorder.add_metadata(RUN_METADATA_NAME,
                                      {k: json.dumps(_plain(v)) for k, v in options.items()})
        except BaseException:
            recorder.abort()
            raise
        with self._lock:
            self._recorder = recorder
        if not self.persistent:
            self._subscribe()
        return recorder.path

    def note_collection_start(self, command_id, start_ns, posture=None):
        """Note that the samples of command ``command_id`` count from ``start_ns`` (node clock).

        Optional (an MCAP metadata record, ignored by rosbag2): with it,
        :func:`samples_from_recording` starts each posture exactly where the calibrator's
        collector did, instead of at the receive time of the ``settled`` status.
        """
        with self._lock:
            if self._recorder is not None:
                self._recorder.add_metadata(POSTURE_METADATA_NAME, {
                    'posture': '' if posture is None else int(posture),
                    'command_id': str(command_id), 'start_ns': int(start_ns)})

    def stop(self, drain_s=0.0):
        """Stop recording and close the file (atomic); returns its path, or None if idle.

        ``drain_s``: first wait this long (s) so that messages published just before (the last
        progress, the result) are received; the recorder's callbacks must be able to run
        meanwhile (a multi-threaded executor: they have their own callback group).
        """
        if drain_s > 0.0 and self._recorder is not None:
            time.sleep(drain_s)
        if not self.persistent:
            self.close_subscriptions()
        with self._lock:
            recorder, self._recorder = self._recorder, None
        if recorder is None:
            return None
        return recorder.close()

    def close_subscriptions(self):
        """Destroy the subscriptions (with ``persistent``: when the node is destroyed)."""
        subscriptions, self._subscriptions = self._subscriptions, []
        for subscription in subscriptions:
            self.node.destroy_subscription(subscription)

    def _callback(self, topic):
        clock = self.node.get_clock()

        def on_message(data):
            if self._recorder is None:  # not recording: drop at once
                return
            now = clock.now().nanoseconds
            with self._lock:
                recorder = self._recorder
                if recorder is None:
                    return
                try:
                    recorder.write(topic, data, now)
                except RecordingError:
                    return

        return on_message


def settings_options(settings):
    """Options of a calibrator run worth storing in its recording (see :meth:`RunRecorder.start`).

    ``settings``: a :class:`gsp_calibrator.settings.CalibratorSettings` (or anything with the same
    attributes); :func:`samples_from_recording` and ``gsp_reidentify`` read them back.
    """
    options = {}
    for name in ('sync_tolerance', 'samples_per_posture', 'formulation', 'posture_count',
                 'pool_size', 'seed', 'nominal_geometry_file'):
        if hasattr(settings, name):
            options[name] = getattr(settings, name)
    if hasattr(settings, 'free_parameters'):
        options['free_parameters'] = list(settings.free_parameters)
    sigmas = getattr(settings, 'sigmas', None)
    if sigmas is not None:
        options.update(sigma_leg_lengths=sigmas.leg_lengths,
                       sigma_inclinometer=sigmas.inclinometer, sigma_encoder=sigmas.encoder,
                       sigma_lvdt=sigmas.lvdt)
    return options


def _plain(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
