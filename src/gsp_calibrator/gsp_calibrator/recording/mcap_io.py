"""Writing and reading ``recording.mcap`` files (MCAP, profile ``ros2``; no ROS context needed).
See docs/data.md."""

import collections
import json
import os
import threading
import time
from struct import error as struct_error

from gsp_calibrator.recording.mcap_format import (
    RecordingError,
    message_class,
    message_definition,
    message_type_name,
    normalise_type_name,
    qos_profiles_yaml,
)

PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'

#: MCAP metadata record holding the run's options (written by ``RunRecorder``).
RUN_METADATA_NAME = 'gsp_calibration'


# --- writing -----------------------------------------------------------------------------------


class McapRecorder:
    """Writes ``path`` (an MCAP file rosbag2 and Foxglove read) atomically."""

    def __init__(self, path, crash_safe=False):
        from mcap.writer import Writer

        self.path = os.fspath(path)
        self.temporary_path = self.path + '.tmp'
        os.makedirs(os.path.dirname(os.path.abspath(self.path)), exist_ok=True)
        self._stream = open(self.temporary_path, 'wb')  # noqa: SIM115 (closed in close/abort)
        self.crash_safe = bool(crash_safe)
        try:
            self._writer = Writer(self._stream, use_chunking=not self.crash_safe)
            self._writer.start(profile=PROFILE, library=_library_identifier())
            self._flush_if_crash_safe()
        except BaseException:
            self._stream.close()
            os.unlink(self.temporary_path)
            raise
        self._lock = threading.Lock()
        self._schemas = {}  # type name -> schema id
        self._channels = {}  # topic -> (channel id, type name)
        #: Messages written per topic (each channel's sequence numbers).
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
                    name=type_name, encoding=SCHEMA_ENCODING, data=definition.encode('utf-8')
                )
            metadata = {}
            if qos is None:
                from gsp_msgs_py.qos import TOPIC_QOS

                qos = TOPIC_QOS.get(topic)
            if qos is not None:
                metadata['offered_qos_profiles'] = qos_profiles_yaml(qos)
            channel_id = self._writer.register_channel(
                topic=topic,
                message_encoding=MESSAGE_ENCODING,
                schema_id=self._schemas[type_name],
                metadata=metadata,
            )
            self._channels[topic] = (channel_id, type_name)
            self._flush_if_crash_safe()
            return channel_id

    def write(self, topic, message, log_time_ns=None, publish_time_ns=None):
        """Write one message: a ROS 2 message object or its CDR bytes (``raw=True``)."""
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
            self._writer.add_message(
                channel_id=channel_id,
                log_time=log_time_ns,
                publish_time=publish_time_ns,
                sequence=(self.counts[topic] + 1) & 0xFFFFFFFF,
                data=data,
            )
            self.counts[topic] += 1
            self._flush_if_crash_safe()

    def add_metadata(self, name, data):
        """An MCAP metadata record ``name`` of string key/values (ignored by rosbag2 play)."""
        with self._lock:
            self._check_open()
            self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})
            self._flush_if_crash_safe()

    def _flush_if_crash_safe(self):
        if self.crash_safe:
            self._stream.flush()  # to the OS: survives the process, not a power cut

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


def recover_recording(temporary_path):
    """Finalise the ``<path>.tmp`` of a recorder that never closed (its process was killed): its
    complete records, up to the first incomplete one, into ``<path>`` (never overwritten),
    atomically. Returns ``{'path', 'message_count', 'truncated'}``."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    temporary_path = os.fspath(temporary_path)
    path = temporary_path.removesuffix('.tmp')
    if os.path.exists(path):
        raise RecordingError(f'{path} exists already: not overwritten by a recovery')
    output_tmp = path + '.recovering'
    count, truncated = 0, False
    with open(temporary_path, 'rb') as source, open(output_tmp, 'wb') as output:
        writer = Writer(output, compression=CompressionType.NONE)
        writer.start(profile=PROFILE, library=_library_identifier() + ' (recovered)')
        schemas, channels = {}, {}  # ids in the source -> ids in the output
        try:
            for record in StreamReader(source).records:
                if isinstance(record, Schema):
                    schemas[record.id] = writer.register_schema(
                        record.name, record.encoding, record.data
                    )
                elif isinstance(record, Channel):
                    channels[record.id] = writer.register_channel(
                        record.topic,
                        record.message_encoding,
                        schemas.get(record.schema_id, 0),
                        dict(record.metadata),
                    )
                elif isinstance(record, Message) and record.channel_id in channels:
                    writer.add_message(
                        channels[record.channel_id],
                        log_time=record.log_time,
                        data=record.data,
                        publish_time=record.publish_time,
                        sequence=record.sequence,
                    )
                    count += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
        except (McapError, EOFError, ValueError, struct_error):
            truncated = True  # the record being written at the kill: incomplete, dropped
        writer.finish()
        output.flush()
        os.fsync(output.fileno())
    os.replace(output_tmp, path)
    os.unlink(temporary_path)
    return {'path': path, 'message_count': count, 'truncated': truncated}


def recover_recordings(directory):
    """:func:`recover_recording` for every ``*.mcap.tmp`` in ``directory``; the results."""
    recovered = []
    for name in sorted(os.listdir(directory)):
        if name.endswith('.mcap.tmp'):
            recovered.append(recover_recording(os.path.join(directory, name)))
    return recovered


def _library_identifier():
    from importlib.metadata import version

    return f'gsp_calibrator recording; mcap-python/{version("mcap")}'


# --- reading ---------------------------------------------------------------------------------

RecordedMessage = collections.namedtuple(
    'RecordedMessage', 'topic type_name log_time_ns message publish_time_ns'
)


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


def read_recording(path, topics=None):
    """The messages (:data:`RecordedMessage`, log and publish time in ns) of an MCAP recording
    in log-time order."""
    from mcap.exceptions import McapError
    from rclpy.serialization import deserialize_message

    stream, reader = _open_reader(path)
    classes = {}  # schema id -> message class
    try:
        for schema, channel, record in reader.iter_messages(topics=topics, log_time_order=True):
            if channel.message_encoding != MESSAGE_ENCODING:
                raise RecordingError(
                    f'{path}: topic {channel.topic} is encoded as '
                    f'{channel.message_encoding!r}, not cdr'
                )
            if schema is None:
                raise RecordingError(f'{path}: topic {channel.topic} has no schema')
            if schema.id not in classes:
                classes[schema.id] = message_class(schema.name)
            try:
                message = deserialize_message(bytes(record.data), classes[schema.id])
            except Exception as error:
                raise RecordingError(
                    f'{path}: cannot decode a {schema.name} message on {channel.topic} '
                    f'at log time {record.log_time} ns ({error})'
                ) from error
            yield RecordedMessage(
                channel.topic, schema.name, record.log_time, message, record.publish_time
            )
    except McapError as error:
        raise RecordingError(f'{path}: corrupt MCAP file ({error})') from error
    finally:
        stream.close()


def recording_info(path):
    """``{topics: {topic: {type, count}}, start_ns, end_ns, message_count, metadata: {name: [dict]}}``."""
    stream, reader = _open_reader(path)
    try:
        summary = reader.get_summary()  # every recording written here has one
        stats, topics, start, end = summary.statistics, {}, None, None
        for channel_id, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            topics[channel.topic] = {
                'type': schema.name if schema else '',
                'count': int(stats.channel_message_counts.get(channel_id, 0)),
            }
        count = int(stats.message_count)
        if count:
            start, end = int(stats.message_start_time), int(stats.message_end_time)
        metadata = collections.defaultdict(list)
        for record in reader.iter_metadata():
            metadata[record.name].append(dict(record.metadata))
        return {
            'topics': topics,
            'start_ns': start,
            'end_ns': end,
            'message_count': count,
            'metadata': dict(metadata),
            'profile': reader.get_header().profile,
        }
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
