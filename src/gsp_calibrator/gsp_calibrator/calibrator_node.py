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

import os
import threading
import time
import traceback

import numpy as np
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
)
from .run_directory import RunDirectory, RunDirectoryError, Samples
from .settings import PARAMETERS, CalibratorSettings, check_parameters
from .sources import SecondSource, SingleSourceGuard

WARN_THROTTLE_S = 1.0
WATCHDOG_PERIOD_S = 0.05  #: how often waits and the protocol check their timeouts
MAX_CACHED_SELECTIONS = 4
#: Topics the node publishes, in the order of its publisher attributes.
OUTPUTS = (
    names.TOPIC_POSE_COMMAND,
    names.TOPIC_CALIBRATION_PROGRESS,
    names.TOPIC_CALIBRATION_RESULT,
)


class RunFailed(Exception):
    """Ends a run early; the message says why (e.g. names the silent topic)."""


def _other_calibrators(node):
    """Nodes named like this one, elsewhere, that publish pose commands (a second calibrator)."""
    own = (node.get_name(), node.get_namespace())
    return sorted(
        {
            f'{info.node_namespace.rstrip("/")}/{info.node_name}'
            for info in node.get_publishers_info_by_topic(names.TOPIC_POSE_COMMAND)
            if info.node_name == names.NODE_CALIBRATOR
            and (info.node_name, info.node_namespace) != own
        }
    )


def _system_checks(node, collection, timeout):
    """``[(predicate, failure message)]`` a run waits on before its first posture."""
    checks = [
        (
            lambda: node._command_pub.get_subscription_count() > 0,
            f'no subscriber on {names.TOPIC_POSE_COMMAND} within {timeout:g} s '
            '(is platform_sim running?)',
        ),
        (
            lambda: node.count_publishers(names.TOPIC_PLATFORM_STATUS) > 0,
            f'topic {names.TOPIC_PLATFORM_STATUS} is silent: no publisher within {timeout:g} s '
            '(is platform_sim running?)',
        ),
    ]
    for topic in protocol.SENSOR_TOPICS:
        message = f'topic {topic} is silent: no message within {timeout:g} s'
        checks.append((lambda t=topic: collection.heard(t), message))
    return checks


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

        self._lock = threading.RLock()  # guards the protocol and the run state
        self._running = False
        self._sensors_active = False  # sensor and status messages are dropped while False
        self._protocol = None  # CollectionProtocol of the current (or last) run
        self._posture_future = None  # completed by the event that ends the awaited posture
        self._posture_count = 0
        self._sources = SingleSourceGuard()
        self._source_failure = None  # SecondSource seen during the current run
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
            self, 'recorder', {}, setup=lambda node: recording.RunRecorder(node, persistent=True)
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
        self.create_service(
            Trigger, names.SERVICE_CALIBRATE, self._on_calibrate, callback_group=self._service_group
        )
        self.create_service(
            Trigger, names.SERVICE_RESUME, self._on_resume, callback_group=self._service_group
        )
        self._run = None  # (RunDirectory, RunState) of the current run

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
            if self._second_source(topic, msg, info):
                return
            with self._lock:
                events = self._protocol.sensor(topic, msg, self._now_ns())
            if events:
                self._handle(events)

        return callback

    def _second_source(self, topic, msg, info):
        """Whether ``msg`` (a valid reading) shows a second publisher; ends the posture if so."""
        try:
            protocol.read_sensor(topic, msg)
        except (ValueError, TypeError):
            return False  # dropped by the protocol anyway
        with self._lock:
            failure = self._sources.check(
                topic,
                info.get('publication_sequence_number'),
                lambda: self._sensors.node.count_publishers(topic),
            )
            if failure is None:
                return False
            self._source_failure = self._source_failure or failure
            future = self._posture_future
        if future is not None and not future.done():
            future.set_result(failure)
        return True

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
            elif isinstance(event, protocol.FINAL_EVENTS):
                future = self._posture_future
                if future is not None and not future.done():
                    future.set_result(event)

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
        """Rewrite the current run's state.json (atomic); a write error is logged, never raised:
        samples.csv and the recording go on."""
        if self._run is None:
            return
        run, state = self._run
        if phase is not None:
            state.phase = phase
        if stop_reason is not None:
            state.stop_reason = stop_reason
        try:
            run_state.write_state(run.path, state)
        except OSError as error:
            self.get_logger().error(f'{run_state.STATE_FILE} not written: {error}')

    def destroy_node(self):
        self._sensors_active = False
        if self._running and self._run is not None and self._run[1].phase != run_state.PHASE_DONE:
            self._save_state(run_state.PHASE_INTERRUPTED, 'the calibrator shut down during the run')
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
            self._posture_future = None
        self._waits.cancel()
        try:
            # Drain (the last progress, the result) and close the file off the executor.
            await self._await_thread(run_in_thread(self._recorder.stop, drain_s=0.2))
        except Exception as error:
            self.get_logger().error(f'recording not closed: {error}')
        finally:
            with self._lock:
                self._running = False
                self._run = None
        return response

    def _open_run(self, settings, resume):
        """``(run, state or None, samples, postures to collect or None)``; RunFailed if refused."""
        if not resume:
            run = RunDirectory.create(settings.output_root)
            samples = Samples.empty()
            run.write_samples(samples)  # fails at once on an unwritable output_root
            return run, None, samples, None
        try:
            if settings.resume_run_directory:
                path = settings.resume_run_directory
            else:
                path = run_state.latest_unfinished_run(settings.output_root, os.getpid())
            run = RunDirectory(path)
            state = run_state.read_state(run.path)
            samples = run.read_samples()
            run_state.check_resume(state, settings, samples)
        except (run_state.ResumeRefused, RunDirectoryError) as error:
            raise RunFailed(f'resume refused: {error}') from None
        for recovered in recording.recover_recordings(run.path):
            self.get_logger().warning(
                f'recovered {recovered["message_count"]} messages of a recording left '
                f'unfinished into {recovered["path"]}'
            )
        state.sessions += 1
        return run, state, samples, run_state.postures_to_collect(state, samples)

    async def _calibrate(self, settings, resume=False):
        """One run, or the rest of an unfinished one; ``(success, message)``."""
        log = self.get_logger()
        started = time.monotonic()
        others = _other_calibrators(self)
        if others:
            message = (
                f'another calibrator publishes on {names.TOPIC_POSE_COMMAND} ({", ".join(others)})'
                ': two calibrators must not drive one platform; run refused'
            )
            log.error(message)
            return False, message
        try:
            run, state, samples, remaining = self._open_run(settings, resume)
        except RunFailed as error:
            log.error(str(error))
            return False, str(error)
        except OSError as error:  # unwritable or full output_root: nothing has moved
            message = f'cannot write the run directory under {settings.output_root}: {error}'
            log.error(message)
            return False, message
        log.info(f'calibration {"resumed" if resume else "started"}: run directory {run.path}')
        try:
            part = recording.next_recording_file(run.path)
            self._recorder.start(part, options=recording.settings_options(settings))
        except (OSError, ValueError, ImportError) as error:  # the run goes on without it
            part = None
            log.error(f'not recording the run: {error}')
        # Per posture collected in this session: the sample std of the 6 legs and 4 readings
        # (the noise estimates; a resumed run has none for its earlier rows, so none are made).
        spreads = []
        count = settings.posture_count
        collection = protocol.CollectionProtocol.for_settings(settings)
        with self._lock:
            self._protocol = collection
            self._posture_count = count
            self._sources.reset()
            self._source_failure = None
            self._sensors_active = True
        try:
            self._progress(
                0, names.PHASE_SELECTING, f'selecting {count} postures from {settings.pool_size}'
            )
            if state is None:
                try:
                    selection = await self._await_thread(self._selection_future(settings))
                except (calibration.CalibrationError, RuntimeError, ValueError) as error:
                    raise RunFailed(f'posture selection failed: {error}') from None
                log.info(
                    f'{len(selection.poses)} postures selected (scaled condition number '
                    f'{selection.condition_number:.4g})'
                )
                state = run_state.RunState(
                    run_state.selection_options(settings), selection.poses.tolist()
                )
                remaining = list(range(1, len(selection.poses) + 1))
            else:
                log.info(f'resuming: {len(samples)} rows kept, {len(remaining)} postures to go')
                if len(samples):
                    collection.continue_after(samples.readings[-1])
            state.pid = os.getpid()
            state.phase, state.stop_reason = run_state.PHASE_COLLECTING, ''
            if part is not None:
                state.recordings.append(os.path.basename(part))
            self._run = (run, state)
            self._save_state()
            await self._wait_for_system(settings, collection)
            poses = state.poses
            for k in remaining:
                row = await self._collect_posture(settings, k, count, poses[k - 1])
                if row is None:
                    state.record_skip(k, collection.summary()['skipped'][-1]['reason'])
                else:
                    samples.append(
                        k, poses[k - 1], row.leg_lengths, row.readings, row.n_samples, row.stamp
                    )
                    spreads.append(np.concatenate([row.leg_lengths_std, row.readings_std]))
                    run.write_samples(samples)
                    state.record_done(k)
                self._save_state()
        except RunFailed as error:
            run.write_samples(samples)
            self._save_state(run_state.PHASE_FAILED, str(error))
            message = calibration.failure_message(error, len(samples), run)
            log.error(message)
            self._progress(len(samples), names.PHASE_FAILED, str(error))
            return False, message
        except OSError as error:  # disk full mid-run: the files written so far are intact
            message = f'run stopped: cannot write {run.path} ({error}); rows so far are kept'
            self._save_state(run_state.PHASE_FAILED, message)
            log.error(message)
            self._progress(len(samples), names.PHASE_FAILED, message)
            return False, message
        with self._lock:
            self._sensors_active = False
        self._save_state(run_state.PHASE_IDENTIFYING)

        self._progress(
            count,
            names.PHASE_IDENTIFYING,
            f'identifying {settings.free_count} parameters from {len(samples)} postures',
        )
        finished = await self._await_thread(
            run_in_thread(
                calibration.finish_run,
                run,
                settings,
                samples,
                collection.summary(),
                recording.settings_options(settings),
                np.array(spreads).reshape(-1, 10),
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
        self._progress(count, phase, summary.splitlines()[0], residuals, run_directory=run.path)
        return success, calibration.format_response(summary, geometry)

    async def _wait_for_system(self, settings, collection):
        """Wait until platform_sim listens to commands and every sensor topic has spoken."""
        checks = _system_checks(self, collection, settings.topic_timeout)
        failure = await first_timeout(self._wait_for, settings.topic_timeout, checks)
        if failure:
            raise RunFailed(failure)
        if self._source_failure is not None:
            raise RunFailed(self._source_failure.message)

    async def _collect_posture(self, settings, k, count, pose):
        """Command posture k and await the protocol's verdict: its row, or None if skipped."""
        stamp = self.get_clock().now()
        command_id = conversions.command_id_from_stamp(stamp)
        future = self._new_future()
        with self._lock:
            if self._source_failure is not None:
                raise RunFailed(self._source_failure.message)
            self._posture_future = future
            events = self._protocol.command(k, pose, command_id, stamp.nanoseconds)
        self._command_pub.publish(conversions.pose_to_pose_stamped(pose, stamp.to_msg()))
        self._progress(k, names.PHASE_MOVING, f'posture {k} of {count}: moving')
        self._handle(events)
        event = await future
        log = self.get_logger()
        if isinstance(event, (protocol.TopicSilent, protocol.NoSynchronisedSample, SecondSource)):
            raise RunFailed(event.message)
        if isinstance(event, protocol.PostureSkipped):
            log.warning(f'posture {k}/{count} skipped: {event.reason}')
            self._progress(
                k,
                names.PHASE_MOVING,
                f'posture {k} of {count} skipped: {event.reason}',
                level=DiagnosticStatus.WARN,
                skipped=k,
            )
            return None
        row = event.sample
        if event.dropped:
            log.warning(
                f'posture {k}/{count}: dropped {event.dropped} synchronised sample(s) '
                'inconsistent with the rest (glitch, or a stream still reporting the '
                'previous posture)'
            )
        residuals = calibration.posture_residuals(
            settings.nominal, pose, row.leg_lengths, row.readings
        )
        self._progress(
            k,
            names.PHASE_COLLECTING,
            f'posture {k} of {count}: {row.n_samples} samples averaged',
            residuals,
        )
        log.info(f'posture {k}/{count}: {row.n_samples} samples averaged')
        return row

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
