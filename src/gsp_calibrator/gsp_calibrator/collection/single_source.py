"""One source per sensor topic: readings from two publishers are never paired (pure, no rclpy).
See docs/faults.md."""

from gsp_calibrator.collection.topics import read_sensor
from gsp_msgs_py import names


def other_calibrators(publishers, own_name, own_namespace):
    """``['/ns/calibrator', ...]``: the calibrators among ``publishers`` (the
    ``TopicEndpointInfo`` of the pose-command publishers) other than ``own_namespace/own_name``."""
    return sorted(
        {
            f'{info.node_namespace.rstrip("/")}/{info.node_name}'
            for info in publishers
            if info.node_name == names.NODE_CALIBRATOR
            and (info.node_name, info.node_namespace) != (own_name, own_namespace)
        }
    )


class SecondSource:
    """A final posture event: ``topic`` has readings from more than one publisher."""

    def __init__(self, topic, publishers):
        self.topic = topic
        self.message = (
            f'topic {topic} has {publishers} publishers whose readings interleave: readings from '
            'two sources are never paired; stop the other publisher (a second driver, simulator '
            'or replay?) and resume'
        )


class SingleSourceGuard:
    """Watches the publication sequence numbers of each topic (:func:`check` per reading)."""

    def __init__(self):
        self._last = {}

    def reset(self):
        self._last.clear()

    def check(self, topic, sequence, publisher_count):
        """None, or a :class:`SecondSource` for a reading with ``sequence`` on ``topic``."""
        if sequence is None:
            return None
        last = self._last.get(topic)
        self._last[topic] = sequence
        if last is None or sequence > last:
            return None
        count = publisher_count()
        return SecondSource(topic, count) if count > 1 else None

    def validate_reading(self, topic, msg, sequence, publisher_count):
        """:meth:`check` for a sensor message ``msg``; None for an unusable one (the collection
        protocol drops it anyway)."""
        try:
            read_sensor(topic, msg)
        except (ValueError, TypeError):
            return None
        return self.check(topic, sequence, publisher_count)
