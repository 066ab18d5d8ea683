"""``calibrator`` node: a whole calibration on ``/gsp/calibrator/calibrate`` (std_srvs/Trigger),
the rest of an unfinished one on ``/gsp/calibrator/resume``, the check on ``/gsp/calibrator/check``.
See docs/nodes.md, docs/architecture.md."""

import os
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from std_srvs.srv import Trigger

from gsp_calibrator.collection import events, protocol
from gsp_calibrator.node.posture_link import PostureLink
from gsp_calibrator.node.result_delivery import ResultDelivery
from gsp_calibrator.node.sensor_intake import LISTENER_TICK_S, SensorIntake
from gsp_calibrator.node.threads import (
    SensorListener,
    ThreadResults,
    Waits,
    await_thread,
    new_future,
    run_in_thread,
)
from gsp_calibrator.recording.recorder import RunRecorder
from gsp_calibrator.run import postures
from gsp_calibrator.run.flow import CalibrationRun
from gsp_calibrator.run.health import calibrator_health
from gsp_calibrator.run.host import RunHost
from gsp_calibrator.run.record import RunWriteError, WriteFailed
from gsp_calibrator.settings import PARAMETERS, CalibratorSettings, validate_parameters
from gsp_calibrator.upkeep.check_flow import new_check
from gsp_msgs_py import conversions, names, node_tools, parameter_specs, qos
from gsp_msgs_py.diagnostics import Component, DiagnosticsPublisher
from gsp_msgs_py.executors import MultiThreadedExecutor

WARN_THROTTLE_S = 1.0
WATCHDOG_PERIOD_S = 0.05  #: how often waits and the protocol check their timeouts
#: Longest time (s) a busy thread keeps the GIL while another waits for it (Python's default:
#: 0.005, up to 5 ms at each hand-over between the node's executor and listener threads).
GIL_SWITCH_INTERVAL_S = 0.0005
MAX_CACHED_SELECTIONS = 4
#: The Trigger services: (name, resume an unfinished run, ``new_run(host, settings, resume)``:
#: a calibration or the check of docs/upkeep.md).
SERVICES = (
    (names.SERVICE_CALIBRATE, False, CalibrationRun),
    (names.SERVICE_RESUME, True, CalibrationRun),
    (names.SERVICE_CHECK, False, new_check),
)
#: Topics the node publishes, in the order of its publisher attributes.
OUTPUTS = (
    names.TOPIC_POSE_COMMAND,
    names.TOPIC_CALIBRATION_PROGRESS,
    names.TOPIC_CALIBRATION_RESULT,
)


class CalibratorNode(Node):
    """Calibration service node; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_CALIBRATOR, **kwargs)
        values = parameter_specs.declare_parameters(
            self, PARAMETERS, validate=lambda values: validate_parameters({}, values)
        )
        try:
            self._settings = CalibratorSettings.from_values(values)
        except ValueError as error:
            raise parameter_specs.ConfigurationError(str(error)) from None
        parameter_specs.watch_parameters(
            self, PARAMETERS, apply=self._apply_parameters, validate=validate_parameters
        )

        self._lock = threading.Lock()  # guards _running and _run
        self._running = False
        self._run = None  # CalibrationRun of the current (or last) run
        self._waits = Waits(time.monotonic)
        self._selections = ThreadResults(MAX_CACHED_SELECTIONS)  # posture selections

        self._intake = SensorIntake(
            self._now_ns,
            lambda topic: self._recorder_listener.node.count_publishers(topic),
            self._wire_times_on_clock,
        )
        self._last_progress = None

        self._service_group = ReentrantCallbackGroup()
        self._data_group = ReentrantCallbackGroup()
        self.command_publisher, self._progress_pub, result_publisher = node_tools.create_publishers(
            self, OUTPUTS
        ).values()
        self._results = ResultDelivery(self, result_publisher, self._data_group)
        # One subscription per topic: the recorder writes each sensor batch, then hands it to
        # the collection (the rebuild sees exactly the messages the collector saw).
        self._recorder_listener = SensorListener(
            self, 'recorder', self._setup_recorder, self._on_recording_error
        )
        self.recorder = self._recorder_listener.extra
        self.postures = PostureLink(
            lambda: new_future(self.executor), self._new_command, self.recorder, self._on_event
        )
        self._intake.postures = self.postures
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
        for service, resume, new_run in SERVICES:
            callback = self._service(resume, new_run)
            self.create_service(Trigger, service, callback, callback_group=self._service_group)

        self._diagnostics = DiagnosticsPublisher(
            self,
            values['diagnostics_period'],
            [Component('calibration', names.PROGRESS_NAME, self._health)],
        )
        # Posture selection takes seconds: start it now for the current parameters.
        self._selection(self._settings)
        self.get_logger().info(
            f'calibrator ready: {", ".join(service for service, *_ in SERVICES)} '
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
        self._selection(self._settings)

    # ------------------------------------------------------------------ messages and events

    def _now_ns(self):
        return self.get_clock().now().nanoseconds

    def _wire_times_on_clock(self):
        """Whether the middleware's timestamps are on the node's clock (not under use_sim_time)."""
        return not self.get_clock().ros_time_is_active

    def _setup_recorder(self, node):
        """The recorder on the listener ``node``, handing the sensor batches to the collection."""
        recorder = RunRecorder(node, persistent=True, forward=self._intake.callbacks())
        node.create_timer(LISTENER_TICK_S, self._intake.tick)
        return recorder

    def _on_status(self, msg, info):
        try:
            status = conversions.parse_status(msg)
        except ValueError as error:
            self.get_logger().warning(
                f'ignoring a malformed status: {error}', throttle_duration_sec=WARN_THROTTLE_S
            )
            return

        def step(collection):
            now_ns = self._now_ns()
            published_ns = info.get('source_timestamp') if self._wire_times_on_clock() else None
            start_ns = protocol.settle_start_ns(published_ns, now_ns, collection.topic_timeout)
            return collection.status(status, now_ns, start_ns)

        self.postures.feed(step)

    def _on_watchdog(self):
        self._waits.poll()
        self.postures.feed(lambda collection: collection.poll(self._now_ns()))

    def _on_recording_error(self, error):
        """A recording write failed (recorder thread): the run ends, naming the file."""
        path = self.recorder.path
        if not isinstance(error, OSError) or path is None:
            self.get_logger().error(f'recording: {error}', throttle_duration_sec=WARN_THROTTLE_S)
            return
        self.postures.fail(WriteFailed(str(RunWriteError(f'{path}.tmp', error))))

    def _on_event(self, event):
        """Act on the protocol's events that do not end a posture (any thread)."""
        if isinstance(event, events.CollectionStarted):
            try:
                self.recorder.note_collection_start(
                    event.command_id, event.start_ns, posture=event.posture
                )
            except OSError as error:  # a full disk: the run ends, as on a message write
                self._on_recording_error(error)
            self._progress(
                event.posture,
                names.PHASE_COLLECTING,
                f'posture {event.posture} of {self._posture_count()}: collecting',
            )
        elif isinstance(event, events.SampleDropped):
            self.get_logger().warning(event.message, throttle_duration_sec=WARN_THROTTLE_S)

    def _new_command(self, pose):
        """``(command_id, now_ns, publish)`` of a command of ``pose`` (:class:`.posture_link.PostureLink`)."""
        stamp = self.get_clock().now()
        msg = conversions.pose_to_pose_stamped(pose, stamp.to_msg())
        return (
            conversions.command_id_from_stamp(stamp),
            stamp.nanoseconds,
            lambda: self.command_publisher.publish(msg),
        )

    def _health(self):
        """The calibrator's health on /diagnostics (:func:`gsp_calibrator.run.health.calibrator_health`)."""
        record = self._run.record if self._run is not None else None
        return calibrator_health(
            self._running,
            self._last_progress,
            record.directory.path if record is not None else '',
            dict(self._intake.heard_ns),
            time.monotonic_ns(),
            self._settings.topic_timeout,
            lags=self._intake.lags.take(),
        )

    # --------------------------------------------------------------------- the run's host

    def _run_host(self):
        """The :class:`gsp_calibrator.run.host.RunHost` of a run: this node's graph, waits and threads."""

        def in_thread(function, *args, **kwargs):
            return self._await_thread(run_in_thread(function, *args, **kwargs))

        return RunHost(
            name=(self.get_name(), self.get_namespace()),
            log=self.get_logger(),
            command_publishers=lambda: self.get_publishers_info_by_topic(names.TOPIC_POSE_COMMAND),
            command_subscribers=lambda: self.command_publisher.get_subscription_count() - 1,
            status_publishers=lambda: self.count_publishers(names.TOPIC_PLATFORM_STATUS),
            recorder=self.recorder,
            postures=self.postures,
            wait_for=self._wait_for,
            in_thread=in_thread,
            await_thread=self._await_thread,
            selection=self._selection,
            progress=self._progress,
            deliver_result=lambda *args: self._results.deliver(*args, self._wait_for),
            shutting_down=lambda: not self.context.ok(),
            processing_lags=self._intake.lags,
        )

    def _wait_for(self, predicate, timeout_s):
        """Future of ``WAIT_OK`` once ``predicate()`` holds, else ``WAIT_TIMEOUT`` (s)."""
        return self._waits.add(predicate, timeout_s, new_future(self.executor))

    def _await_thread(self, concurrent_future):
        return await_thread(concurrent_future, new_future(self.executor))

    def _selection(self, settings):
        """The (possibly running, cached) posture selection of ``settings``."""
        args = postures.selection_arguments(settings)
        return self._selections.get(postures.selection_key(*args), postures.choose_postures, *args)

    def _posture_count(self):
        run = self._run
        if run is None:
            return 0
        state = run.record.state if run.record is not None else None
        return postures.commanded_count(run.settings, state)

    def _progress(self, index, phase, message='', residuals=None, warning=False, **extra):
        """Publish the run's progress at posture ``index`` (0 before the first)."""
        count = self._posture_count()
        msg = conversions.make_progress(
            max(0, min(index, count)),
            count,
            phase,
            residuals,
            message,
            level=DiagnosticStatus.WARN if warning else None,
            extra={k: str(v) for k, v in extra.items()},
        )
        self._progress_pub.publish(msg)
        self._last_progress = conversions.parse_progress(msg)

    # --------------------------------------------------------------------------- the run

    def _service(self, resume, new_run):
        """The Trigger callback of one whole calibration, or (``resume``) the rest of an
        unfinished run (``resume_run_directory`` or the latest), or the check (docs/upkeep.md)."""

        async def serve(_request, response):
            with self._lock:
                if self._running:
                    response.success = False
                    response.message = 'calibration already running'
                    self.get_logger().warning(
                        'calibrate: refused, a calibration is already running'
                    )
                    return response
                self._running = True
                self._run = new_run(self._run_host(), self._settings, resume)
            with self.postures.lock:
                self._intake.sources.reset()
            response.success, response.message = await self._run.serve()
            if self.context.ok():  # else going down: destroy_node() marks the run interrupted
                self._waits.cancel()
                with self._lock:
                    self._running = False
            return response

        return serve

    def destroy_node(self):
        # Under the link's lock: a row the sensor thread is adding now is complete before the
        # run's final state.json is written, so state.json and samples.csv agree after a SIGTERM.
        postures = getattr(self, 'postures', None)  # not before __init__ made it
        if postures is not None:
            postures.stop()
        if self._running and self._run is not None:
            self._run.interrupted()
        recorder = getattr(self, 'recorder', None)
        if recorder is not None:
            try:
                recorder.stop()
            except Exception as error:  # never keep the node from going down
                self.get_logger().error(f'recording not closed: {error}')
        listener = getattr(self, '_recorder_listener', None)
        if listener is not None:
            listener.close()
        return super().destroy_node()


def main(args=None):
    """Console script ``calibrator``; returns 1 if the parameters prevent start-up."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return node_tools.run_node(
        CalibratorNode,
        args,
        executor=lambda: MultiThreadedExecutor(num_threads=max(2, os.cpu_count() or 2)),
        logger_name=names.NODE_CALIBRATOR,
    )


if __name__ == '__main__':
    raise SystemExit(main())
