"""Every node's health on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``), as
``diagnostic_updater`` publishes it: the ROS convention rqt_robot_monitor, the diagnostic
aggregator and Foxglove read.
"""

import collections

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from . import names, qos
from .health import ERROR, LEVEL_NAMES, Health

WARN_THROTTLE_S = 5.0


def status_name(node_name, component):
    """The status name of ``component`` of node ``node_name``: ``'<node name>: <component>'``
    (diagnostic_updater's convention)."""
    return f'{node_name}: {component}'


def node_of_status(name):
    """The node name of a status named by :func:`status_name` ('' if it has no ``': '``)."""
    node, separator, _ = name.partition(': ')
    return node if separator else ''


def health_to_status(health, name, hardware_id):
    """``DiagnosticStatus`` of ``health``; ``level`` as the message's one byte."""
    return DiagnosticStatus(
        level=bytes([health.level]),
        name=str(name),
        message=health.message,
        hardware_id=str(hardware_id),
        values=[KeyValue(key=key, value=value) for key, value in health.values.items()],
    )


def status_to_health(msg):
    """``(name, hardware_id, Health)`` of a ``DiagnosticStatus``; ValueError naming the status if
    its level is not OK, WARN, ERROR or STALE."""
    level = msg.level[0] if isinstance(msg.level, (bytes, bytearray)) else int(msg.level)
    if level not in LEVEL_NAMES:
        raise ValueError(f'diagnostic status {msg.name!r}: unknown level {level}')
    values = {kv.key: kv.value for kv in msg.values}
    return msg.name, msg.hardware_id, Health(level, msg.message, values)


#: One status a node reports: ``name`` (``'<node name>: <name>'`` on the topic), its
#: ``hardware_id`` and ``health()`` (a :class:`Health`).
Component = collections.namedtuple('Component', 'name hardware_id health')


class DiagnosticsPublisher:
    """Publishes the health of ``components`` (:class:`Component`) of ``node`` on
    ``/diagnostics`` every ``period_s`` s.

    The timer has its own callback group, so a ``health()`` only reads what other callbacks
    write; one that raises is reported as ERROR: a node never dies of its own report.
    """

    def __init__(self, node, period_s, components):
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

        self._node = node
        self.components = tuple(components)
        self._publisher = node.create_publisher(
            DiagnosticArray, names.TOPIC_DIAGNOSTICS, qos.DIAGNOSTICS_QOS
        )
        self._timer = node.create_timer(
            float(period_s), self.publish, callback_group=MutuallyExclusiveCallbackGroup()
        )

    def _health(self, component):
        try:
            health = component.health()
            if not isinstance(health, Health):
                raise TypeError(f'health() returned {type(health).__name__}, not Health')
            return health
        except Exception as error:  # a bug in a report must not take the node down
            self._node.get_logger().warning(
                f'health of {component.name!r} not available: {error}',
                throttle_duration_sec=WARN_THROTTLE_S,
            )
            return Health(ERROR, f'health report failed: {error}')

    def statuses(self):
        """The ``DiagnosticStatus`` of every component, now."""
        node_name = self._node.get_name()
        return [
            health_to_status(
                self._health(component),
                status_name(node_name, component.name),
                component.hardware_id,
            )
            for component in self.components
        ]

    def publish(self):
        """Publish one ``DiagnosticArray`` of every component (the timer calls it)."""
        msg = DiagnosticArray(status=self.statuses())
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._publisher.publish(msg)


class DiagnosticsListener:
    """Keeps the latest status of each name heard on ``/diagnostics`` by ``node``:
    :attr:`reports` ``{name: Health}`` and :attr:`hardware_ids` ``{name: hardware_id}``. A status
    with an unknown level is not kept: its error is in :attr:`malformed`."""

    def __init__(self, node):
        self.reports = {}
        self.hardware_ids = {}
        self.malformed = []
        node.create_subscription(
            DiagnosticArray, names.TOPIC_DIAGNOSTICS, self._on_array, qos.DIAGNOSTICS_QOS
        )

    def _on_array(self, msg):
        for status in msg.status:
            try:
                name, hardware_id, health = status_to_health(status)
            except ValueError as error:
                self.malformed.append(str(error))
                continue
            self.reports[name] = health
            self.hardware_ids[name] = hardware_id
