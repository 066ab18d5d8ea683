"""``calibrator`` node: runs a whole calibration on ``/gsp/calibrator/calibrate`` (std_srvs/Trigger).

A run selects postures (core, condition-number criterion), commands each on
``/gsp/platform/pose_command`` and collects its averaged row from ``/gsp/platform/status``,
``/gsp/platform/leg_lengths`` and the three ``/gsp/device/*`` topics, then identifies the
parameters. It reports on ``/gsp/calibrator/progress``, writes the run directory (``samples.csv``
after every posture, ``result.yaml``, ``recording.mcap``, ``result.json``, ``report.md``),
latches the calibrated geometry YAML on ``/gsp/calibrator/result`` and, with ``apply_result``,
sets the ``geometry.*`` parameters of the platform controller through its parameter service.
See docs/nodes.md (parameters, topics) and docs/architecture.md (protocol, concurrency).

This wrapper only moves messages and waits. The collection protocol is
:class:`.protocol.CollectionProtocol`: every status and sensor message goes to it with its
receive time, a watchdog timer polls it, and its events (row ready, posture skipped, topic
silent) end each posture. The rest is in plain modules: :mod:`.calibration` (selection,
identification, response text), :mod:`.run_directory`, :mod:`.recording`, :mod:`.report`,
:mod:`.settings`; the waiting machinery is :mod:`.node_waiting`.

Concurrency: the Trigger callback is a coroutine in its own reentrant group, so a second call is
answered at once while a run awaits. The status subscription and the parameter client sit in a
reentrant group; the watchdog timer in a mutually exclusive group of its own (one executor thread
at most: a reentrant timer is dispatched again while it waits for the lock, and its piled-up
calls would take every thread of the executor). The sensor topics are taken by a
:class:`.node_waiting.SensorListener` (node ``<name>_sensors``, own thread), the recording by a
second one (``<name>_recorder``). The protocol is guarded by one lock.
"""

import collections
import os
import threading
import time
import traceback

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import Trigger

from gsp_kinematics.geometry import geometry_to_parameters, geometry_to_yaml
from gsp_msgs_py import conversions, names, node_tools, qos

from . import calibration, protocol, recording, run_state
from .node_waiting import (
    ParameterSetter,
    SensorListener,
    ThreadResults,
    Waits,
    await_thread,
    first_timeout,
    new_future,
    run_in_thread,
    system_checks,
)
from .run_session import RunRefused, RunSession, RunWriteError, WriteFailed
from .settings import PARAMETERS, CalibratorSettings, check_parameters
from .sources import SecondSource, SingleSourceGuard, other_calibrators

WARN_THROTTLE_S = 1.0
WATCHDOG_PERIOD_S = 0.05  #: how often waits and the protocol check their timeouts
MAX_CACHED_SELECTIONS = 4
#: Topics the node publishes, in the order of its publisher attributes.
OUTPUTS = (
    names.TOPIC_POSE_COMMAND,
    names.TOPIC_CALIBRATION_PROGRESS,
    names.TOPIC_CALIBRATION_RESULT,
)
#: Final posture events that end the run.
RUN_FAILURES = (protocol.TopicSilent, protocol.NoSynchronisedSample, SecondSource, WriteFailed)


class RunFailed(Exception):
    """Ends a run early; the message says why (e.g. names the silent topic)."""


class CalibratorNode(Node):
    """Calibration service node; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_CALIBRATOR, **kwargs)
        values = node_tools.declare_parameters(
            self, PARAMETERS, validate=lambda values: check_parameters({}, values)
        )
        try:
            self._settings = CalibratorSettings.from_values(values)
        except ValueError as error:
            raise node_tools.ConfigurationError(str(error)) from None
        node_tools.watch_parameters(
            self, PARAMETERS, apply=self._apply_parameters, validate=check_parameters
        )

        self._lock = threading.RLock()  # guards the protocol and the run
        self._running = False
        self._sensors_active = False  # sensor and status messages are dropped while False
        self._protocol = None  # CollectionProtocol of the current (or last) run
        self._session = None  # RunSession of the current run
        self._finals = collections.deque()  # final posture events not yet reported
        self._finals_future = None  # completed when an event joins _finals
        self._failure = None  # the event that ends the current run
        self._posture_count = 0
        self._sources = SingleSourceGuard()
        self._waits = Waits(time.monotonic)
        self._selections = ThreadResults(MAX_CACHED_SELECTIONS)  # posture selections

        self._service_group = ReentrantCallbackGroup()
        self._data_group = ReentrantCallbackGroup()
        self._parameter_setter = ParameterSetter(self, self._data_group)
        self._command_pub, self._progress_pub, self._result_pub = node_tools.create_publishers(
            self, OUTPUTS
        ).values()
        self._sensors = SensorListener.beside(
            self, 'sensors', {t: self._sensor_callback(t) for t in protocol.SENSOR_TOPICS}
        )
        self._recorder_listener = SensorListener.beside(
            self,
            'recorder',
            {},
            setup=lambda node: recording.RunRecorder(node, persistent=True),
            on_error=self._on_recording_error,
        )
        self._recorder = self._recorder_listener.extra
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
        for service, callback in (
            (names.SERVICE_CALIBRATE, self._on_calibrate),
            (names.SERVICE_RESUME, self._on_resume),
        ):
            self.create_service(Trigger, service, callback, callback_group=self._service_group)

        # Posture selection takes seconds: start it now for the current parameters.
        self._selection_future(self._settings)
        self.get_logger().info(
            f'calibrator ready: {names.SERVICE_CALIBRATE}, {names.SERVICE_RESUME} '
            f'({self._settings.describe()})'
        )

    def _apply_parameters(self, _changes):
        """The next run uses the new values (a running one keeps its own)."""
        try:
            self._settings = CalibratorSettings.from_values(
                node_tools.parameter_values(self, PARAMETERS)
            )
        except ValueError as error:  # validated already; a file may have vanished since
            self.get_logger().error(f'parameters not applied: {error}')
            return
        self._selection_future(self._settings)

    # ------------------------------------------------------------------ messages and events

    def _now_ns(self):
        return self.get_clock().now().nanoseconds

    def _sensor_callback(self, topic):
        def callback(msg, info):
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
            if events:
                self._handle(events)

        return callback

    def _on_status(self, msg):
        try:
            status = conversions.parse_status(msg)
        except ValueError as error:
            self.get_logger().warning(
                f'ignoring a malformed status: {error}', throttle_duration_sec=WARN_THROTTLE_S
            )
            return
        with self._lock:
            events = self._protocol.status(status, self._now_ns()) if self._sensors_active else []
        self._handle(events)

    def _on_watchdog(self):
        self._waits.poll()
        with self._lock:
            events = self._protocol.poll(self._now_ns()) if self._sensors_active else []
        self._handle(events)

    def _on_recording_error(self, error):
        """A recording write failed (recorder thread): the run ends, naming the file."""
        path = self._recorder.path
        if not isinstance(error, OSError) or path is None:
            self.get_logger().error(f'recording: {error}', throttle_duration_sec=WARN_THROTTLE_S)
            return
        self._handle([WriteFailed(str(RunWriteError(f'{path}.tmp', error)))])

    def _handle(self, events):
        """Act on the protocol's events (any thread)."""
        for event in events:
            if isinstance(event, protocol.CollectionStarted):
                self._recorder.note_collection_start(
                    event.command_id, event.start_ns, posture=event.posture
                )
                self._progress(
                    event.posture,
                    names.PHASE_COLLECTING,
                    f'posture {event.posture} of {self._posture_count}: collecting',
                )
            elif isinstance(event, protocol.SampleDropped):
                self.get_logger().warning(event.message, throttle_duration_sec=WARN_THROTTLE_S)
            elif isinstance(event, protocol.FINAL_EVENTS + RUN_FAILURES):
                self._end_posture(event)

    def _end_posture(self, event):
        """Keep the row (samples.csv) or the skip of a posture and command the next one at once,
        from the event; the run coroutine reports it (and ends the run on a failure)."""
        next_events = []
        with self._lock:
            if not self._sensors_active or self._session is None or self._failure is not None:
                return
            if isinstance(event, protocol.RowReady):
                try:
                    self._session.add_row(event)
                except RunWriteError as error:
                    event = WriteFailed(str(error))
            elif isinstance(event, protocol.PostureSkipped):
                self._session.skip(event)
            if isinstance(event, RUN_FAILURES):
                self._failure = event
            else:
                next_events = self._command_next()
            self._finals.append(event)
            future, self._finals_future = self._finals_future, None
        if future is not None and not future.done():
            future.set_result(None)
        self._handle(next_events)

    def _command_next(self):
        """Command the run's next posture (with the lock held); the protocol's events."""
        posture = self._session.next_posture()
        if posture is None:
            return []
        k, pose = posture
        stamp = self.get_clock().now()
        command_id = conversions.command_id_from_stamp(stamp)
        events = self._protocol.command(k, pose, command_id, stamp.nanoseconds)
        self._command_pub.publish(conversions.pose_to_pose_stamped(pose, stamp.to_msg()))
        self._progress(k, names.PHASE_MOVING, f'posture {k} of {self._posture_count}: moving')
        return events

    async def _next_final(self):
        """The next final posture event (awaits one if none is queued)."""
        with self._lock:
            future = None
            if not self._finals:
                future = self._finals_future = self._new_future()
        if future is not None:
            await future
        with self._lock:
            return self._finals.popleft()

    # --------------------------------------------------------------------------- helpers

    def _new_future(self):
        return new_future(self.executor)

    def _wait_for(self, predicate, timeout_s):
        """Future of ``WAIT_OK`` once ``predicate()`` holds, else ``WAIT_TIMEOUT`` (s)."""
        return self._waits.add(predicate, timeout_s, self._new_future())

    def _await_thread(self, concurrent_future):
        return await_thread(concurrent_future, self._new_future())

    def _progress(self, index, phase, message='', residuals=None, level=None, **extra):
        """Publish the run's progress at posture ``index`` (0 before the first)."""
        count = self._posture_count
        self._progress_pub.publish(
            conversions.make_progress(
                max(0, min(index, count)),
                count,
                phase,
                residuals,
                message,
                level=level,
                extra={k: str(v) for k, v in extra.items()},
            )
        )

    def _selection_future(self, settings):
        """The (possibly running, cached) posture selection of ``settings``."""
        args = calibration.selection_arguments(settings)
        return self._selections.get(
            calibration.selection_key(*args), calibration.choose_postures, *args
        )

    def _save_state(self, phase=None, stop_reason=None):
        """Rewrite the current run's state.json; an error is logged (the run is ending)."""
        try:
            if self._session is not None:
                self._session.save(phase, stop_reason)
        except RunWriteError as error:
            self.get_logger().error(f'{run_state.STATE_FILE} not written: {error}')

    def destroy_node(self):
        self._sensors_active = False
        session = self._session
        if self._running and session is not None and session.state is not None:
            if session.state.phase != run_state.PHASE_DONE:
                self._save_state(
                    run_state.PHASE_INTERRUPTED, 'the calibrator shut down during the run'
                )
        recorder = getattr(self, '_recorder', None)
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

    # --------------------------------------------------------------------------- the run

    async def _on_calibrate(self, request, response):
        """Trigger callback: one whole calibration (a second call meanwhile fails at once)."""
        return await self._serve(response, resume=False)

    async def _on_resume(self, request, response):
        """Trigger callback: continue ``resume_run_directory`` or the latest unfinished run."""
        return await self._serve(response, resume=True)

    async def _serve(self, response, resume):
        with self._lock:
            if self._running:
                response.success = False
                response.message = 'calibration already running'
                self.get_logger().warning('calibrate: refused, a calibration is already running')
                return response
            self._running = True
        try:
            response.success, response.message = await self._calibrate(self._settings, resume)
        except GeneratorExit:
            # The executor dropped the task: the node is going down. Nothing may be awaited
            # now (an await here would hang the garbage collector that closes the coroutine);
            # destroy_node() closes the recording and marks the run interrupted.
            self._sensors_active = False
            raise
        except Exception as error:  # the node must survive any failure of a run
            if not self.context.ok():  # shut down meanwhile (Ctrl-C, SIGTERM): not a crash
                self._sensors_active = False
                response.success, response.message = False, 'the calibrator shut down'
                return response  # destroy_node() closes the recording, marks the run
            self.get_logger().error(f'calibration crashed: {error}\n{traceback.format_exc()}')
            response.success, response.message = False, f'calibration failed: {error}'
        with self._lock:
            self._sensors_active = False
        self._waits.cancel()
        try:
            # Drain (the last progress, the result) and close the file off the executor.
            await self._await_thread(run_in_thread(self._recorder.stop, drain_s=0.2))
        except Exception as error:
            self.get_logger().error(f'recording not closed: {error}')
        finally:
            with self._lock:
                self._running = False
                if self._session is not None:
                    self._session.close()
                self._session = None
        return response

    def _open_session(self, settings, resume):
        """The run's :class:`RunSession`; RunFailed (with its message) if it cannot start."""
        others = other_calibrators(
            self.get_publishers_info_by_topic(names.TOPIC_POSE_COMMAND),
            self.get_name(),
            self.get_namespace(),
        )
        if others:
            raise RunFailed(
                f'another calibrator publishes on {names.TOPIC_POSE_COMMAND} ({", ".join(others)})'
                ': two calibrators must not drive one platform; run refused'
            )
        try:
            session = RunSession.resume(settings, os.getpid()) if resume else None
            return session or RunSession.create(settings.output_root)
        except RunRefused as error:
            raise RunFailed(str(error)) from None
        except OSError as error:  # unwritable or full output_root: nothing has moved
            raise RunFailed(
                f'cannot write the run directory under {settings.output_root}: {error}'
            ) from None

    async def _calibrate(self, settings, resume=False):
        """One run, or the rest of an unfinished one; ``(success, message)``."""
        log = self.get_logger()
        started = time.monotonic()
        try:
            session = self._open_session(settings, resume)
        except RunFailed as error:
            log.error(str(error))
            return False, str(error)
        for recovered in session.recovered:
            log.warning(
                f'recovered {recovered["message_count"]} messages of a recording left '
                f'unfinished into {recovered["path"]}'
            )
        log.info(f'calibration {"resumed" if resume else "started"}: run directory {session.run}')
        try:
            part = recording.next_recording_file(session.run.path)
            self._recorder.start(part, options=recording.settings_options(settings))
        except (OSError, ValueError, ImportError) as error:  # the run goes on without it
            part = None
            log.error(f'not recording the run: {error}')
        count = settings.posture_count
        collection = protocol.CollectionProtocol.for_settings(settings)
        with self._lock:
            self._protocol, self._session, self._failure = collection, session, None
            self._posture_count = count
            self._finals.clear()
            self._sources.reset()
            self._sensors_active = True
        try:
            await self._begin(settings, session, collection, part)
            await self._wait_for_system(settings, collection)
            await self._collect(settings)
        except (RunFailed, RunWriteError) as error:
            self._save_state(run_state.PHASE_FAILED, str(error))
            message = calibration.failure_message(error, len(session.samples), session.run)
            log.error(message)
            self._progress(len(session.samples), names.PHASE_FAILED, str(error))
            return False, message
        with self._lock:
            self._sensors_active = False
        return await self._identify(settings, session, collection, started)

    async def _begin(self, settings, session, collection, part):
        """Select the postures of a new run (a resumed one keeps its own); write state.json."""
        log, count = self.get_logger(), settings.posture_count
        self._progress(
            0, names.PHASE_SELECTING, f'selecting {count} postures from {settings.pool_size}'
        )
        poses = None
        if session.state is None:
            try:
                selection = await self._await_thread(self._selection_future(settings))
            except (calibration.CalibrationError, RuntimeError, ValueError) as error:
                raise RunFailed(f'posture selection failed: {error}') from None
            log.info(
                f'{len(selection.poses)} postures selected (scaled condition number '
                f'{selection.condition_number:.4g})'
            )
            poses = selection.poses
        session.begin(settings, poses, os.getpid(), part)
        if session.resumed:
            log.info(
                f'resuming: {len(session.samples)} rows kept, '
                f'{len(session.remaining)} postures to go'
            )
            if len(session.samples):
                collection.continue_after(session.samples.readings[-1])

    async def _wait_for_system(self, settings, collection):
        """Wait until platform_sim listens to commands and every sensor topic has spoken."""
        checks = system_checks(
            self,
            self._command_pub,
            collection.heard,
            protocol.SENSOR_TOPICS,
            settings.topic_timeout,
        )
        failure = await first_timeout(self._wait_for, settings.topic_timeout, checks)
        if failure:
            raise RunFailed(failure)
        if self._failure is not None:
            raise RunFailed(self._failure.message)

    async def _collect(self, settings):
        """Command every posture left (each from the end of the previous one, see
        :meth:`_end_posture`) and report each as it ends; RunFailed on a failure."""
        with self._lock:
            events = self._command_next()
        self._handle(events)
        while True:
            with self._lock:
                if (
                    self._session.commanded_all
                    and self._protocol.posture is None
                    and not self._finals
                ):
                    return
            event = await self._next_final()
            if isinstance(event, RUN_FAILURES):
                raise RunFailed(event.message)
            self._report_posture(settings, event)
            self._session.save()

    def _report_posture(self, settings, event):
        """Log and publish the end of a posture (its row, or its skip)."""
        log, k, count = self.get_logger(), event.posture, self._posture_count
        if isinstance(event, protocol.PostureSkipped):
            log.warning(f'posture {k}/{count} skipped: {event.reason}')
            self._progress(
                k,
                names.PHASE_MOVING,
                f'posture {k} of {count} skipped: {event.reason}',
                level=DiagnosticStatus.WARN,
                skipped=k,
            )
            return
        row = event.sample
        if event.dropped:
            log.warning(
                f'posture {k}/{count}: dropped {event.dropped} synchronised sample(s) '
                'inconsistent with the rest (glitch, or a stream still reporting the '
                'previous posture)'
            )
        residuals = calibration.posture_residuals(
            settings.nominal, event.pose, row.leg_lengths, row.readings
        )
        message = f'posture {k} of {count}: {row.n_samples} samples averaged'
        self._progress(k, names.PHASE_COLLECTING, message, residuals)
        log.info(f'posture {k}/{count}: {row.n_samples} samples averaged')

    async def _identify(self, settings, session, collection, started):
        """Identify over every row, write the results, publish and apply; ``(success, text)``."""
        log, count = self.get_logger(), settings.posture_count
        self._save_state(run_state.PHASE_IDENTIFYING)
        self._progress(
            count,
            names.PHASE_IDENTIFYING,
            f'identifying {settings.free_count} parameters from {len(session.samples)} postures',
        )
        finished = await self._await_thread(
            run_in_thread(
                calibration.finish_run,
                session.run,
                settings,
                session.samples,
                collection.summary(),
                recording.settings_options(settings),
                session.spread_table(),
            )
        )
        if finished.report_error:
            log.error(f'report not written: {finished.report_error}')
        outcome, summary = finished.outcome, finished.summary
        residuals = outcome.result.residual_rms if outcome.result is not None else None
        if not outcome.success:
            log.error(summary)
            self._save_state(run_state.PHASE_FAILED, outcome.message)
            self._progress(count, names.PHASE_FAILED, outcome.message, residuals)
            return False, summary
        self._save_state(run_state.PHASE_DONE)
        geometry = outcome.geometry
        result_yaml = geometry_to_yaml(geometry, comment=calibration.RESULT_COMMENT)
        self._result_pub.publish(String(data=result_yaml))
        # A result the goodness of fit rejects is written and latched, but applied only on demand.
        success = outcome.fit_accepted or settings.apply_rejected_fit
        if settings.apply_result and success:
            success, reason = await self._apply_to_platform(settings, geometry)
            summary += '\n' + reason
        summary += f'\ncalibration time: {time.monotonic() - started:.2f} s'
        (log.info if success else log.error)(summary)
        phase = names.PHASE_DONE if success else names.PHASE_FAILED
        run_path = session.run.path
        self._progress(count, phase, summary.splitlines()[0], residuals, run_directory=run_path)
        return success, calibration.format_response(summary, geometry)

    async def _apply_to_platform(self, settings, geometry):
        """Set the controller's ``geometry.*`` atomically; ``(applied, human message)``."""
        node_name = settings.platform_node_name
        applied, why = await self._parameter_setter.set(
            node_name, geometry_to_parameters(geometry), settings.topic_timeout, self._wait_for
        )
        if not applied:
            return False, f'NOT applied: {why}'
        self.get_logger().info(f'calibrated geometry applied to /{node_name}')
        return True, f'applied to /{node_name} (geometry.* parameters)'


def main(args=None):
    """Console script ``calibrator``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(
        CalibratorNode,
        args,
        executor=lambda: MultiThreadedExecutor(num_threads=max(2, os.cpu_count() or 2)),
        logger_name=names.NODE_CALIBRATOR,
    )


if __name__ == '__main__':
    raise SystemExit(main())
