"""``calibrator`` node: runs a whole calibration on ``/gsp/calibrator/calibrate`` (std_srvs/Trigger).

A run selects postures (core, condition-number criterion), commands each on
``/gsp/platform/pose_command`` and collects its averaged row from ``/gsp/platform/status``,
``/gsp/platform/leg_lengths`` and the three ``/gsp/device/*`` topics, then identifies the
parameters. It reports on ``/gsp/calibrator/progress``, writes the run directory (``samples.csv``
a row per posture, ``state.json``, ``result.yaml``, ``recording.mcap``, ``result.json``,
``report.md``), latches the calibrated geometry YAML on ``/gsp/calibrator/result`` and, with
``apply_result``, sets the ``geometry.*`` parameters of the platform controller through its
parameter service. See docs/nodes.md (parameters, topics) and docs/architecture.md (protocol,
concurrency).

This wrapper only moves messages and waits. The collection protocol is
:class:`.collection.protocol.CollectionProtocol`: every status and sensor message goes to it with its
receive time (a status also with its publish instant: a posture's samples count from the
publication of its ``settled``, :func:`.collection.protocol.settle_start_ns`), a watchdog timer polls it for
timeouts, and its events (row ready, posture skipped, topic silent) end each posture. The course of a run is :class:`.run.flow.CalibrationRun`
(a coroutine), its files :class:`.run.session.RunSession`; the waiting machinery is
:mod:`.node_threads`, the second-source guard
:class:`.collection.single_source.SingleSourceGuard`. The end of a posture (in the
thread of the message that ended it) appends the row to samples.csv and commands the next
posture at once; the run coroutine reports it afterwards and rewrites state.json.

Concurrency: the Trigger callback is a coroutine in its own reentrant group, so a second call is
answered at once while a run awaits. The status subscription and the parameter client sit in a
reentrant group; the watchdog timer in a mutually exclusive group of its own (one executor thread
at most: a reentrant timer is dispatched again while it waits for the lock, and its piled-up
calls would take every thread of the executor). The sensor topics are taken by a
:class:`.node_threads.SensorListener` (node ``<name>_sensors``, own thread), the recording by a
second one (``<name>_recorder``). The protocol and the run are guarded by one lock.
"""

import os
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from std_srvs.srv import Trigger

from gsp_calibrator.calibrator_host import CalibratorRunHost
from gsp_calibrator.collection import protocol, topics
from gsp_calibrator.collection.single_source import SingleSourceGuard
from gsp_calibrator.node_threads import (
    EventQueue,
    SensorListener,
    ThreadResults,
    Waits,
)
from gsp_calibrator.recording.recorder import RunRecorder
from gsp_calibrator.result_delivery import ResultDelivery
from gsp_calibrator.run.flow import RUN_FAILURES, CalibrationRun
from gsp_calibrator.run.health import calibrator_health
from gsp_calibrator.run.session import RunWriteError, WriteFailed
from gsp_calibrator.settings import PARAMETERS, CalibratorSettings, check_parameters
from gsp_msgs_py import conversions, names, node_tools, parameter_specs, qos
from gsp_msgs_py.diagnostics import Component, DiagnosticsPublisher
from gsp_msgs_py.executors import MultiThreadedExecutor

WARN_THROTTLE_S = 1.0
WATCHDOG_PERIOD_S = 0.05  #: how often waits and the protocol check their timeouts
#: Longest time (s) a busy thread keeps the GIL while another waits for it (Python's default:
#: 0.005). The node's threads (executor, sensor listener, recorder) share one GIL: the message
#: that completes a posture, and the next command, would otherwise wait up to 5 ms for the
#: recorder's thread at each hand-over.
GIL_SWITCH_INTERVAL_S = 0.0005
MAX_CACHED_SELECTIONS = 4
#: Topics the node publishes, in the order of its publisher attributes.
OUTPUTS = (
    names.TOPIC_POSE_COMMAND,
    names.TOPIC_CALIBRATION_PROGRESS,
    names.TOPIC_CALIBRATION_RESULT,
)


class CalibratorNode(CalibratorRunHost, Node):
    """Calibration service node; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_CALIBRATOR, **kwargs)
        values = parameter_specs.declare_parameters(
            self, PARAMETERS, validate=lambda values: check_parameters({}, values)
        )
        try:
            self._settings = CalibratorSettings.from_values(values)
        except ValueError as error:
            raise parameter_specs.ConfigurationError(str(error)) from None
        parameter_specs.watch_parameters(
            self, PARAMETERS, apply=self._apply_parameters, validate=check_parameters
        )

        self._lock = threading.RLock()  # guards the protocol and the run
        self._running = False
        self._sensors_active = False  # sensor and status messages are dropped while False
        self._protocol = None  # CollectionProtocol of the current (or last) run
        self._run = None  # CalibrationRun of the current run
        self._session = None  # its RunSession once collecting
        self.finals = EventQueue(self._new_future)  # final posture events not yet reported
        # Final events the protocol has emitted (with the lock held) and _end_posture has not
        # yet taken (ids): between the two the protocol is idle and `finals` may be empty.
        self._ending = set()
        self.failure = None  # the event that ended the current run
        self._sources = SingleSourceGuard()
        self._waits = Waits(time.monotonic)
        self._selections = ThreadResults(MAX_CACHED_SELECTIONS)  # posture selections

        # For /diagnostics: receive time (monotonic ns) of each sensor topic's latest message,
        # run or not, and the latest progress published.
        self._heard_ns = dict.fromkeys(topics.SENSOR_TOPICS)
        self._last_progress = None

        self._service_group = ReentrantCallbackGroup()
        self._data_group = ReentrantCallbackGroup()
        self.command_publisher, self._progress_pub, result_publisher = node_tools.create_publishers(
            self, OUTPUTS
        ).values()
        self._results = ResultDelivery(self, result_publisher, self._data_group)
        self._sensors = SensorListener.beside(
            self, 'sensors', {t: self._sensor_callback(t) for t in topics.SENSOR_TOPICS}
        )
        self._recorder_listener = SensorListener.beside(
            self,
            'recorder',
            {},
            setup=lambda node: RunRecorder(node, persistent=True),
            on_error=self._on_recording_error,
        )
        self.recorder = self._recorder_listener.extra
        self.create_subscription(
            DiagnosticStatus,
            names.TOPIC_PLATFORM_STATUS,
            self._on_status,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
            callback_group=self._data_group,
        )
        self.create_timer(
            WATCHDOG_PERIOD_S, self._on_watchdog, callback_group=MutuallyExclusiveCallbackGroup()
        )
        for service, resume in ((names.SERVICE_CALIBRATE, False), (names.SERVICE_RESUME, True)):
            self.create_service(
                Trigger, service, self._service(resume), callback_group=self._service_group
            )

        self._diagnostics = DiagnosticsPublisher(
            self,
            values['diagnostics_period'],
            [Component('calibration', names.PROGRESS_NAME, self._health)],
        )
        # Posture selection takes seconds: start it now for the current parameters.
        self.selection_future(self._settings)
        self.get_logger().info(
            f'calibrator ready: {names.SERVICE_CALIBRATE}, {names.SERVICE_RESUME} '
            f'({self._settings.describe()})'
        )

    def _apply_parameters(self, _changes):
        """The next run uses the new values (a running one keeps its own)."""
        try:
            self._settings = CalibratorSettings.from_values(
                parameter_specs.parameter_values(self, PARAMETERS)
            )
        except ValueError as error:  # validated already; a file may have vanished since
            self.get_logger().error(f'parameters not applied: {error}')
            return
        self.selection_future(self._settings)

    # ------------------------------------------------------------------ messages and events

    def _now_ns(self):
        return self.get_clock().now().nanoseconds

    def _sensor_callback(self, topic):
        def callback(msg, info):
            self._heard_ns[topic] = time.monotonic_ns()
            if not self._sensors_active:  # no run: drop at once
                return
            with self._lock:
                failure = self._sources.check_reading(
                    topic,
                    msg,
                    info.get('publication_sequence_number'),
                    lambda: self._sensors.node.count_publishers(topic),
                )
                events = [failure] if failure else self._protocol.sensor(topic, msg, self._now_ns())
                self._note_finals(events)
            if events:
                self._handle(events)

        return callback

    def _on_status(self, msg, info):
        try:
            status = conversions.parse_status(msg)
        except ValueError as error:
            self.get_logger().warning(
                f'ignoring a malformed status: {error}', throttle_duration_sec=WARN_THROTTLE_S
            )
            return
        with self._lock:
            events = []
            if self._sensors_active:
                now_ns = self._now_ns()
                start_ns = protocol.settle_start_ns(
                    info.get('source_timestamp'), now_ns, self._protocol.topic_timeout
                )
                events = self._note_finals(self._protocol.status(status, now_ns, start_ns))
        self._handle(events)

    def _on_watchdog(self):
        self._waits.poll()
        with self._lock:
            events = self._protocol.poll(self._now_ns()) if self._sensors_active else []
            self._note_finals(events)
        self._handle(events)

    def _on_recording_error(self, error):
        """A recording write failed (recorder thread): the run ends, naming the file."""
        path = self.recorder.path
        if not isinstance(error, OSError) or path is None:
            self.get_logger().error(f'recording: {error}', throttle_duration_sec=WARN_THROTTLE_S)
            return
        self._handle([WriteFailed(str(RunWriteError(f'{path}.tmp', error)))])

    def _handle(self, events):
        """Act on the protocol's events (any thread)."""
        for event in events:
            if isinstance(event, events.CollectionStarted):
                try:
                    self.recorder.note_collection_start(
                        event.command_id, event.start_ns, posture=event.posture
                    )
                except OSError as error:  # a full disk: the run ends, as on a message write
                    self._on_recording_error(error)
                count = self._settings_count()
                self.progress(
                    event.posture,
                    names.PHASE_COLLECTING,
                    f'posture {event.posture} of {count}: collecting',
                )
            elif isinstance(event, events.SampleDropped):
                self.get_logger().warning(event.message, throttle_duration_sec=WARN_THROTTLE_S)
            elif isinstance(event, events.FINAL_EVENTS + RUN_FAILURES):
                self._end_posture(event)

    def _note_finals(self, events):
        """Note the final events among ``events`` (the lock held) until they are taken."""
        self._ending.update(
            id(event) for event in events if isinstance(event, events.FINAL_EVENTS + RUN_FAILURES)
        )
        return events

    def _end_posture(self, event):
        """Keep the row (samples.csv) or the skip of a posture and command the next one at once,
        from the event's own thread; the run coroutine reports it (and ends on a failure)."""
        next_events = []
        with self._lock:
            self._ending.discard(id(event))
            if not self._sensors_active or self._session is None or self.failure is not None:
                return
            event = self._session.end_posture(event)
            if isinstance(event, RUN_FAILURES):
                self.failure = event
            else:
                next_events = self._command_next()
            self.finals.put(event)
        self._handle(next_events)

    def _command_next(self):
        """Command the run's next posture (with the lock held); the protocol's events."""
        posture = self._session.next_posture()
        if posture is None:
            return []
        k, pose = posture
        stamp = self.get_clock().now()
        command_id = conversions.command_id_from_stamp(stamp)
        events = self._note_finals(self._protocol.command(k, pose, command_id, stamp.nanoseconds))
        self.command_publisher.publish(conversions.pose_to_pose_stamped(pose, stamp.to_msg()))
        count = self._settings_count()
        self.progress(k, names.PHASE_MOVING, f'posture {k} of {count}: moving')
        return events

    def _health(self):
        """The calibrator's health on /diagnostics (:func:`.run.health.calibrator_health`)."""
        session = self._run.session if self._run is not None else None
        return calibrator_health(
            self._running,
            self._last_progress,
            session.run.path if session is not None else '',
            dict(self._heard_ns),
            time.monotonic_ns(),
            self._settings.topic_timeout,
        )

    # --------------------------------------------------------------------------- the run

    def _service(self, resume):
        async def callback(request, response):
            """Trigger: one whole calibration, or (``resume``) the rest of an unfinished run:
            ``resume_run_directory`` or the latest. A second call meanwhile fails at once."""
            return await self._serve(response, resume)

        return callback

    async def _serve(self, response, resume):
        with self._lock:
            if self._running:
                response.success = False
                response.message = 'calibration already running'
                self.get_logger().warning('calibrate: refused, a calibration is already running')
                return response
            self._running = True
            self._run = CalibrationRun(self, self._settings, resume)
        response.success, response.message = await self._run.serve()
        return response

    def destroy_node(self):
        # Under the lock: a row the sensor thread is adding now is complete before the run's
        # final state.json is written, so state.json and samples.csv agree after a SIGTERM.
        if hasattr(self, '_lock'):  # not before __init__ made it
            self.stop_collection()
        if self._running and self._run is not None:
            self._run.interrupted()
        recorder = getattr(self, 'recorder', None)
        if recorder is not None:
            try:
                recorder.stop()
            except Exception as error:  # never keep the node from going down
                self.get_logger().error(f'recording not closed: {error}')
        for name in ('_recorder_listener', '_sensors'):
            listener = getattr(self, name, None)
            if listener is not None:
                listener.close()
        return super().destroy_node()


def share_the_gil_promptly():
    """Set the process's GIL switch interval to :data:`GIL_SWITCH_INTERVAL_S`; the previous one."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return previous


def main(args=None):
    """Console script ``calibrator``; returns 1 if the parameters prevent start-up."""
    share_the_gil_promptly()
    return node_tools.run_node(
        CalibratorNode,
        args,
        executor=lambda: MultiThreadedExecutor(num_threads=max(2, os.cpu_count() or 2)),
        logger_name=names.NODE_CALIBRATOR,
    )


if __name__ == '__main__':
    raise SystemExit(main())
