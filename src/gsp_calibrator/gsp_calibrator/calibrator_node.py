"""``calibrator`` node: runs a whole calibration on ``/gsp/calibrator/calibrate`` (std_srvs/Trigger).

A run selects postures (core, condition-number criterion), commands each on
``/gsp/platform/pose_command``, waits for its ``settled`` status on ``/gsp/platform/status``
(``rejected`` ones are skipped), collects ``samples_per_posture`` synchronised samples of
``/gsp/platform/leg_lengths`` and the three ``/gsp/device/*`` topics, averages them, and
identifies the parameters. It reports on ``/gsp/calibrator/progress``, writes the run directory
(``samples.csv`` after every posture, ``result.yaml``), latches the calibrated geometry YAML on
``/gsp/calibrator/result`` and, with ``apply_result``, sets the ``geometry.*`` parameters of the
platform controller through its parameter service.

The logic is in plain modules: :mod:`.collector` (stamp matching), :mod:`.calibration` (selection,
identification, checks, response text), :mod:`.run_directory` (files), :mod:`.settings`
(parameters). This wrapper only moves messages and waits.

Concurrency: the Trigger callback is a coroutine (``async def``) in its own reentrant group, so a
second call is answered at once while a run awaits. The status subscription, the watchdog timer
and the parameter client sit in a separate reentrant group; the node spins in a
``MultiThreadedExecutor``. Waits are ``rclpy.task.Future`` objects completed by those callbacks
(or by a worker thread for the CPU-heavy selection and identification); nothing blocks inside a
callback.

The four sensor streams (800 messages/s at 200 Hz) are taken by :class:`SensorListener`: a small
node of its own (``<name>_sensors``, no parameters) spun by a ``SingleThreadedExecutor`` in a
dedicated thread. Its subscriptions live as long as the node (destroying a subscription while
that thread builds its wait set can raise ``InvalidHandle``, ros2/rclpy#1206); outside a run the
callbacks drop every message at once. Measured on the 2-core machine under load, a
``MultiThreadedExecutor`` took these streams at ~560 messages/s with ~300 ms of lag (GIL
hand-offs to its pool), so samples piled up behind the settled status; the single-threaded
listener kept up (~2 ms median lag) at a third less CPU.

Every run directory also holds ``recording.mcap`` (every message on the suite's topics during the
run, :class:`.recording.RunRecorder` on a third internal node ``<name>_recorder`` with its own
thread and lifetime subscriptions) and, once identification gives a result, ``result.json``,
``report.md`` and its PNGs (:mod:`.report`, written in a worker thread).
"""

import concurrent.futures
import dataclasses
import math
import os
import threading
import time
import traceback

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import (
    ExternalShutdownException,
    MultiThreadedExecutor,
    ShutdownException,
    SingleThreadedExecutor,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from gsp_kinematics.geometry import geometry_to_parameters, geometry_to_yaml
from gsp_msgs_py import conversions, names, node_tools, qos

from . import calibration, recording, report
from .collector import ENCODER, INCLINOMETER, LEG_LENGTHS, LVDT, SampleCollector
from .run_directory import RESULT_FILE, SAMPLES_FILE, RunDirectory, Samples
from .settings import PARAMETERS, CalibratorSettings, check_parameters

WARN_THROTTLE_S = 1.0
WATCHDOG_PERIOD_S = 0.05  #: how often waits check their deadlines and silent topics
RESULT_COMMENT = 'calibrated by gsp_calibrator'
MAX_CACHED_SELECTIONS = 4
#: A posture is skipped when this many times samples_per_posture synchronised pairs hold no
#: consistent window (see gsp_calibrator.collector).
MAX_PAIRS_PER_SAMPLE = 20

#: Sensor topics and the collector stream each one feeds.
SENSOR_TOPICS = {
    names.TOPIC_LEG_LENGTHS: LEG_LENGTHS,
    names.TOPIC_INCLINOMETER: INCLINOMETER,
    names.TOPIC_ENCODER: ENCODER,
    names.TOPIC_LVDT: LVDT,
}

#: Sensor QoS (best effort, volatile, keep last) with a deep queue: the calibrator pairs samples
#: by stamp, so late samples are fine but lost ones are not. 1000 holds 5 s per topic at 200 Hz,
#: enough to ride out a starved process without losing one of the three device topics of an
#: instant (which would leave that instant incomplete).
SENSOR_SUBSCRIPTION_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=qos.SENSOR_QOS.reliability,
    durability=qos.SENSOR_QOS.durability)

WAIT_OK = 'ok'
WAIT_TIMEOUT = 'timeout'
WAIT_DEADLINE = 'deadline'


class ConfigurationError(node_tools.ConfigurationError):
    """A parameter value prevents the node from starting; the message names the parameter."""


class RunFailed(Exception):
    """Ends a run early; the message says why (e.g. names the silent topic)."""


@dataclasses.dataclass
class _Waiter:
    predicate: object  # () -> bool, evaluated under the node's lock
    timeout: float  # s without progress (or since the start) before WAIT_TIMEOUT
    watch: tuple  # topics that must not fall silent for topic_timeout
    topic_timeout: float
    started: float  # time.monotonic() of the start
    future: Future
    progress: object = None  # () -> value; a change restarts the timeout
    last_value: object = None
    last_change: float = 0.0
    deadline: float = math.inf  # s since the start before WAIT_DEADLINE, progress or not


def _run_in_thread(function, *args, **kwargs):
    """Run ``function`` in a daemon thread; a ``concurrent.futures.Future`` of its result."""
    result = concurrent.futures.Future()

    def target():
        if not result.set_running_or_notify_cancel():
            return
        try:
            result.set_result(function(*args, **kwargs))
        except BaseException as error:  # noqa: B036 (handed to the awaiting coroutine)
            result.set_exception(error)

    threading.Thread(target=target, name=f'calibrator-{function.__name__}', daemon=True).start()
    return result


def _has_non_finite(msg):
    return any(not math.isfinite(v) for v in msg.position)


class SensorListener:
    """Takes the sensor topics in a thread of its own (see the module docstring).

    ``callbacks`` maps each resolved topic name to its callback; the subscriptions are created
    before the thread starts and kept until :meth:`close` (see the module docstring). ``setup``:
    None or a function of the node called before the thread starts (its result is :attr:`extra`),
    to create further entities on the node. :meth:`close` stops the thread.
    """

    def __init__(self, name, namespace, context, callbacks, setup=None):
        self.callbacks = dict(callbacks)
        self.node = Node(name, namespace=namespace, context=context, use_global_arguments=False,
                         start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._subscriptions = []
        self._lock = threading.Lock()
        self.subscribe()
        self.extra = setup(self.node) if setup is not None else None
        self._thread = threading.Thread(target=self._spin, name=f'{name}-executor', daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except (ExternalShutdownException, ShutdownException):
            pass

    def subscribe(self):
        with self._lock:
            if self._subscriptions:
                return
            self._subscriptions = [
                self.node.create_subscription(JointState, topic, callback,
                                              SENSOR_SUBSCRIPTION_QOS)
                for topic, callback in self.callbacks.items()
            ]

    @property
    def subscribed(self):
        return bool(self._subscriptions)

    def close(self):
        self.executor.shutdown(timeout_sec=2.0)
        self._thread.join(timeout=2.0)
        self.node.destroy_node()


class CalibratorNode(Node):
    """Calibration service node; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_CALIBRATOR, **kwargs)
        try:
            for spec in PARAMETERS:
                self.declare_parameter(spec.name, spec.default, ParameterDescriptor(
                    description=spec.description + (f' ({spec.unit})' if spec.unit else ''),
                    additional_constraints=spec.constraints))
        except (InvalidParameterValueException, InvalidParameterTypeException) as error:
            raise ConfigurationError(str(error)) from None
        try:
            self._settings = CalibratorSettings.from_values(self._parameter_values())
        except ValueError as error:
            raise ConfigurationError(str(error)) from None
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._lock = threading.RLock()
        self._running = False
        self._sensors_active = False  # sensor callbacks drop every message while False
        self._awaited_posture = None
        self._waiters = []
        self._collector = SampleCollector(self._settings.sync_tolerance,
                                          self._settings.samples_per_posture)
        self._statuses = {}  # command_id -> PlatformStatus of the command being awaited
        self._awaited_command = None
        self._previous_readings = None  # device readings of the run's previous posture
        self._latest_device = {}  # stream -> (stamp_ns, values) of its latest finite message
        self._last_heard = {}  # topic -> time.monotonic() of its last message
        self._selections = {}  # calibration.selection_key -> concurrent Future of a selection
        self._parameter_clients = {}

        self._service_group = ReentrantCallbackGroup()
        self._data_group = ReentrantCallbackGroup()
        self._command_pub = self.create_publisher(
            PoseStamped, names.TOPIC_POSE_COMMAND, qos.TOPIC_QOS[names.TOPIC_POSE_COMMAND])
        self._progress_pub = self.create_publisher(
            DiagnosticStatus, names.TOPIC_CALIBRATION_PROGRESS,
            qos.TOPIC_QOS[names.TOPIC_CALIBRATION_PROGRESS])
        self._result_pub = self.create_publisher(
            String, names.TOPIC_CALIBRATION_RESULT, qos.TOPIC_QOS[names.TOPIC_CALIBRATION_RESULT])
        self._sensors = SensorListener(
            f'{self.get_name()}_sensors', self.get_namespace(), self.context,
            {self.resolve_topic_name(topic): self._make_sensor_callback(topic, stream)
             for topic, stream in SENSOR_TOPICS.items()})
        self._recorder_listener = SensorListener(
            f'{self.get_name()}_recorder', self.get_namespace(), self.context, {},
            setup=lambda node: recording.RunRecorder(node, persistent=True))
        self._recorder = self._recorder_listener.extra
        self.create_subscription(
            DiagnosticStatus, names.TOPIC_PLATFORM_STATUS, self._on_status,
            qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS], callback_group=self._data_group)
        self.create_timer(WATCHDOG_PERIOD_S, self._poll_waiters, callback_group=self._data_group)
        self.create_service(Trigger, names.SERVICE_CALIBRATE, self._on_calibrate,
                            callback_group=self._service_group)

        # Posture selection takes seconds: start it now for the current parameters.
        self._selection_future(self._settings)
        s = self._settings
        self.get_logger().info(
            f'calibrator ready: {names.SERVICE_CALIBRATE} (nominal {s.nominal_geometry_file}, '
            f'{s.posture_count} postures from a pool of {s.pool_size}, {s.samples_per_posture} '
            f'samples each, {s.formulation} formulation, {len(s.free_parameters)} free '
            f'parameters, output under {os.path.abspath(s.output_root)})')

    # ------------------------------------------------------------------------- parameters

    def _parameter_values(self):
        return {spec.name: self.get_parameter(spec.name).value for spec in PARAMETERS}

    def _validate_parameters(self, parameters):
        """on-set callback: reject a bad value with the reason."""
        changes = {p.name: p.value for p in parameters}
        reason = check_parameters(changes, self._parameter_values())
        return SetParametersResult(successful=not reason, reason=reason)

    def _apply_parameters(self, parameters):
        """post-set callback: the next run uses the new values (a running one keeps its own)."""
        try:
            self._settings = CalibratorSettings.from_values(self._parameter_values())
        except ValueError as error:  # validated already; a file may have vanished since
            self.get_logger().error(f'parameters not applied: {error}')
            return
        self._selection_future(self._settings)

    # --------------------------------------------------------------------------- messages

    def _make_sensor_callback(self, topic, stream):
        reader = {
            LEG_LENGTHS: lambda m: (conversions.msg_to_leg_lengths(m),),
            INCLINOMETER: conversions.msg_to_inclinometer,
            ENCODER: lambda m: (conversions.msg_to_encoder(m),),
            LVDT: lambda m: (conversions.msg_to_lvdt(m),),
        }[stream]
        adder = {
            LEG_LENGTHS: lambda c: c.add_leg_lengths,
            INCLINOMETER: lambda c: c.add_inclinometer,
            ENCODER: lambda c: c.add_encoder,
            LVDT: lambda c: c.add_lvdt,
        }[stream]

        def callback(msg):
            if not self._sensors_active:  # no run: drop at once
                return
            self._last_heard[topic] = time.monotonic()
            try:
                stamp_ns = conversions.stamp_to_nanoseconds(msg.header.stamp)
                values = reader(msg)
            except (ValueError, TypeError) as error:
                if isinstance(msg, JointState) and _has_non_finite(msg):
                    with self._lock:
                        self._collector.record_non_finite(stream)
                        dropped = self._collector.non_finite[stream]
                    self.get_logger().warning(
                        f'dropped a non-finite reading on {topic} ({dropped} so far)',
                        throttle_duration_sec=WARN_THROTTLE_S)
                else:
                    self.get_logger().warning(f'ignoring a malformed message on {topic}: {error}',
                                              throttle_duration_sec=WARN_THROTTLE_S)
                return
            with self._lock:
                adder(self._collector)(stamp_ns, *values)
                self._latest_device[stream] = (stamp_ns, values)
            self._poll_waiters()

        return callback

    def _on_status(self, msg):
        self._last_heard[names.TOPIC_PLATFORM_STATUS] = time.monotonic()
        try:
            status = conversions.parse_status(msg)
        except ValueError as error:
            self.get_logger().warning(f'ignoring a malformed status: {error}',
                                      throttle_duration_sec=WARN_THROTTLE_S)
            return
        with self._lock:
            if status.command_id != self._awaited_command:
                return
            self._statuses[status.command_id] = status
            if status.settled:
                # Samples count from the moment the settled status is received.
                start_ns = self.get_clock().now().nanoseconds
                self._collector.start(start_ns, self._previous_readings)
                self._recorder.note_collection_start(status.command_id, start_ns,
                                                     posture=self._awaited_posture)
        self._poll_waiters()

    # ------------------------------------------------------------------------------ waits

    def _new_future(self):
        future = Future(executor=self.executor)
        # A done callback makes the executor wake up (and resume the awaiting coroutine) at once.
        future.add_done_callback(lambda _: None)
        return future

    def _wait_for(self, predicate, timeout_s=math.inf, watch=(), topic_timeout=math.inf,
                  progress=None, deadline_s=math.inf):
        """Future of :data:`WAIT_OK` once ``predicate()`` holds, :data:`WAIT_TIMEOUT` after
        ``timeout_s`` (without a change of ``progress()``, if given), :data:`WAIT_DEADLINE`
        ``deadline_s`` after the start (progress or not), or the name of a ``watch`` topic silent
        for ``topic_timeout`` s."""
        now = time.monotonic()
        waiter = _Waiter(predicate, timeout_s, tuple(watch), topic_timeout, now,
                         self._new_future(), progress, None, now, deadline_s)
        with self._lock:
            self._waiters.append(waiter)
        self._poll_waiters()
        return waiter.future

    def _poll_waiters(self):
        """Complete the waits whose condition, deadline or silent topic has come."""
        now = time.monotonic()
        finished = []
        with self._lock:
            for waiter in list(self._waiters):
                outcome = None
                try:
                    if waiter.predicate():
                        outcome = WAIT_OK
                except Exception as error:  # a broken predicate must not kill the callbacks
                    outcome = f'error: {error}'
                if outcome is None:
                    for topic in waiter.watch:
                        heard = max(self._last_heard.get(topic, -math.inf), waiter.started)
                        if now - heard > waiter.topic_timeout:
                            outcome = topic
                            break
                if outcome is None and waiter.progress is not None:
                    value = waiter.progress()
                    if value != waiter.last_value:
                        waiter.last_value, waiter.last_change = value, now
                if outcome is None and now - waiter.last_change >= waiter.timeout:
                    outcome = WAIT_TIMEOUT
                if outcome is None and now - waiter.started >= waiter.deadline:
                    outcome = WAIT_DEADLINE
                if outcome is not None:
                    self._waiters.remove(waiter)
                    finished.append((waiter.future, outcome))
        for future, outcome in finished:
            if not future.done():
                future.set_result(outcome)

    def _await_thread(self, concurrent_future):
        """An rclpy Future completed with the result (or exception) of a concurrent Future."""
        future = self._new_future()

        def done(source):
            if future.done():
                return
            error = source.exception()
            if error is not None:
                future.set_exception(error)
            else:
                future.set_result(source.result())

        concurrent_future.add_done_callback(done)
        return future

    # ---------------------------------------------------------------------------- helpers

    def _progress(self, index, count, phase, message='', residuals=None, level=None, **extra):
        msg = conversions.make_progress(
            max(0, min(index, count)), count, phase, residuals, message, level=level,
            extra={k: str(v) for k, v in extra.items()})
        self._progress_pub.publish(msg)

    def _current_device_readings(self):
        """Latest complete device instant ``[alpha, beta, phi, d_m]`` received, or None."""
        with self._lock:
            latest = [self._latest_device.get(stream) for stream in (INCLINOMETER, ENCODER, LVDT)]
        if any(item is None for item in latest) or len({item[0] for item in latest}) != 1:
            return None
        return np.concatenate([np.asarray(item[1], dtype=float) for item in latest])

    def _subscribe_sensors(self):
        """Take the sensor topics (for a run); forget when they were last heard."""
        with self._lock:
            for topic in SENSOR_TOPICS:
                self._last_heard.pop(topic, None)
            self._latest_device.clear()
            self._sensors_active = True

    def _unsubscribe_sensors(self):
        """Drop the sensor messages again (the subscriptions stay, see the module docstring)."""
        with self._lock:
            self._sensors_active = False

    def destroy_node(self):
        self._sensors_active = False
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

    def _selection_future(self, settings):
        """The (possibly running, cached) posture selection of ``settings``."""
        free = list(settings.free_parameters)
        key = calibration.selection_key(
            settings.nominal, settings.posture_count, settings.pool_size, settings.seed,
            settings.sigmas, free, settings.formulation)
        with self._lock:
            future = self._selections.get(key)
            if future is None or (future.done() and future.exception() is not None):
                future = _run_in_thread(
                    calibration.choose_postures, settings.nominal, settings.posture_count,
                    settings.pool_size, settings.seed, settings.sigmas, free,
                    settings.formulation)
                self._selections[key] = future
                while len(self._selections) > MAX_CACHED_SELECTIONS:
                    self._selections.pop(next(iter(self._selections)))
        return future

    def _parameter_client(self, node_name):
        service = f'/{node_name}/set_parameters_atomically'
        client = self._parameter_clients.get(service)
        if client is None:
            client = self.create_client(SetParametersAtomically, service,
                                        callback_group=self._data_group)
            self._parameter_clients[service] = client
        return client, service

    # ---------------------------------------------------------------------------- service

    async def _on_calibrate(self, request, response):
        """Trigger callback: one whole calibration (a second call meanwhile fails at once)."""
        with self._lock:
            if self._running:
                response.success = False
                response.message = 'calibration already running'
                self.get_logger().warning('calibrate: refused, a calibration is already running')
                return response
            self._running = True
        try:
            response.success, response.message = await self._calibrate(self._settings)
        except Exception as error:  # the node must survive any failure of a run
            self.get_logger().error(f'calibration crashed: {error}\n{traceback.format_exc()}')
            response.success, response.message = False, f'calibration failed: {error}'
        finally:
            with self._lock:
                self._awaited_command = None
                self._awaited_posture = None
                self._collector.stop()
                for waiter in self._waiters:
                    if not waiter.future.done():
                        waiter.future.cancel()
                self._waiters.clear()
            self._unsubscribe_sensors()
            try:
                # Drain (the last progress, the result) and close the file off the executor.
                await self._await_thread(_run_in_thread(self._recorder.stop, drain_s=0.2))
            except Exception as error:
                self.get_logger().error(f'recording not closed: {error}')
            finally:
                with self._lock:
                    self._running = False
        return response

    async def _calibrate(self, settings):
        """One run; ``(success, message)``."""
        log = self.get_logger()
        started = time.monotonic()
        run = RunDirectory.create(settings.output_root)
        log.info(f'calibration started: run directory {run.path}')
        try:
            self._recorder.start(run.file(recording.RECORDING_FILE),
                                 options=recording.settings_options(settings))
        except (OSError, ValueError, ImportError) as error:  # the run goes on without it
            log.error(f'not recording the run: {error}')
        samples = Samples.empty()
        skipped = []
        run.write_samples(samples)
        sigmas = settings.sigmas
        noise_std = [sigmas.leg_lengths] * 6 + [sigmas.inclinometer] * 2 + [sigmas.encoder,
                                                                             sigmas.lvdt]
        with self._lock:
            self._collector = SampleCollector(
                settings.sync_tolerance, settings.samples_per_posture, noise_std=noise_std,
                max_buffer=max(2000, 2 * MAX_PAIRS_PER_SAMPLE * settings.samples_per_posture))
            self._previous_readings = None
        self._subscribe_sensors()
        count = settings.posture_count
        try:
            self._progress(0, count, names.PHASE_SELECTING,
                           f'selecting {count} postures from a pool of {settings.pool_size}')
            try:
                selection = await self._await_thread(self._selection_future(settings))
            except (calibration.CalibrationError, RuntimeError, ValueError) as error:
                raise RunFailed(f'posture selection failed: {error}') from None
            log.info(f'{len(selection.poses)} postures selected (scaled condition number '
                     f'{selection.condition_number:.4g})')
            await self._wait_for_system(settings)
            for k, pose in enumerate(selection.poses, start=1):
                row = await self._collect_posture(settings, k, count, pose, skipped)
                if row is None:
                    continue
                samples.append(k, pose, row.leg_lengths, row.readings, row.n_samples, row.stamp)
                self._previous_readings = row.readings
                run.write_samples(samples)
        except RunFailed as error:
            run.write_samples(samples)
            message = (f'calibration FAILED after {len(samples)} collected posture(s): {error}\n'
                       f'{len(samples)} posture(s) saved to {run.file(SAMPLES_FILE)}\n'
                       f'{calibration.RUN_DIRECTORY_LABEL}{run.path}')
            log.error(message)
            self._progress(len(samples), count, names.PHASE_FAILED, str(error))
            return False, message

        self._progress(count, count, names.PHASE_IDENTIFYING,
                       f'identifying {len(settings.free_parameters)} parameters from '
                       f'{len(samples)} postures')
        outcome = await self._await_thread(_run_in_thread(
            calibration.identify_from_samples, settings.nominal, samples, settings.sigmas,
            list(settings.free_parameters), settings.formulation))
        summary = calibration.outcome_summary(outcome, selected=count, skipped=skipped,
                                              run_directory=run.path)
        if outcome.result is not None:
            await self._write_report(run, settings, outcome)
        residuals = outcome.result.residual_rms if outcome.result is not None else None
        if not outcome.success:
            log.error(summary)
            self._progress(count, count, names.PHASE_FAILED, outcome.message, residuals)
            return False, summary

        geometry = outcome.geometry
        run.write_geometry(geometry, RESULT_FILE, comment=RESULT_COMMENT)
        yaml_text = geometry_to_yaml(geometry, comment=RESULT_COMMENT)
        self._result_pub.publish(String(data=yaml_text))
        success = True
        if settings.apply_result:
            applied, reason = await self._apply_to_platform(settings, geometry)
            summary += '\n' + reason
            success = applied
        summary += f'\ncalibration time: {time.monotonic() - started:.2f} s'
        (log.info if success else log.error)(summary)
        self._progress(count, count, names.PHASE_DONE if success else names.PHASE_FAILED,
                       summary.splitlines()[0], residuals, run_directory=run.path)
        return success, calibration.format_response(summary, geometry)

    async def _write_report(self, run, settings, outcome):
        """``result.json``, ``report.md`` and its PNGs, in a worker thread; errors are logged."""
        try:
            await self._await_thread(_run_in_thread(
                report.write_all, run.path, outcome.result,
                analysis=outcome.identifiability or None, nominal=settings.nominal,
                sigmas=outcome.sigmas,
                extra={'success': outcome.success, 'failure': outcome.message or None,
                       'options': recording.settings_options(settings)}))
        except Exception as error:  # the report must not fail the run
            self.get_logger().error(f'report not written: {error}\n{traceback.format_exc()}')

    async def _wait_for_system(self, settings):
        """Wait until platform_sim listens to commands and every sensor topic has spoken."""
        timeout = settings.topic_timeout
        outcome = await self._wait_for(
            lambda: self._command_pub.get_subscription_count() > 0, timeout)
        if outcome != WAIT_OK:
            raise RunFailed(f'no subscriber on {names.TOPIC_POSE_COMMAND} within {timeout:g} s '
                            '(is platform_sim running?)')
        outcome = await self._wait_for(
            lambda: self.count_publishers(names.TOPIC_PLATFORM_STATUS) > 0, timeout)
        if outcome != WAIT_OK:
            raise RunFailed(f'topic {names.TOPIC_PLATFORM_STATUS} is silent: no publisher within '
                            f'{timeout:g} s (is platform_sim running?)')
        for topic in SENSOR_TOPICS:
            outcome = await self._wait_for(lambda t=topic: t in self._last_heard, timeout)
            if outcome != WAIT_OK:
                raise RunFailed(f'topic {topic} is silent: no message within {timeout:g} s')

    async def _collect_posture(self, settings, k, count, pose, skipped):
        """Command posture k, wait until settled, collect and average; None if skipped."""
        log = self.get_logger()
        stamp = self.get_clock().now()
        command_id = conversions.command_id_from_stamp(stamp)
        if k == 1 or self._previous_readings is None:
            # What the device reports before the platform moves (stale readings would match).
            self._previous_readings = self._current_device_readings()
        with self._lock:
            self._awaited_command = command_id
            self._awaited_posture = k
            self._statuses.clear()
            self._collector.stop()
        self._command_pub.publish(conversions.pose_to_pose_stamped(pose, stamp.to_msg()))
        self._progress(k, count, names.PHASE_MOVING, f'posture {k} of {count}: moving')

        def state():
            status = self._statuses.get(command_id)
            return status.state if status is not None else None

        outcome = await self._wait_for(lambda: state() is not None, settings.topic_timeout)
        if outcome != WAIT_OK:
            raise RunFailed(f'topic {names.TOPIC_PLATFORM_STATUS} is silent: no status for '
                            f'posture {k} (command {command_id}) within '
                            f'{settings.topic_timeout:g} s')
        outcome = await self._wait_for(
            lambda: state() in (names.STATE_SETTLED, names.STATE_REJECTED),
            settings.settle_timeout)
        if state() == names.STATE_REJECTED:
            reason = self._statuses[command_id].reason or 'rejected'
            return self._skip(k, count, f'rejected by the platform: {reason}', skipped)
        if outcome != WAIT_OK:
            return self._skip(k, count, f'not settled within {settings.settle_timeout:g} s',
                              skipped)

        self._progress(k, count, names.PHASE_COLLECTING, f'posture {k} of {count}: collecting')
        collector = self._collector
        limit = MAX_PAIRS_PER_SAMPLE * settings.samples_per_posture

        def done():
            return collector.ready() or collector.pair_count() >= limit

        # The collection is bounded as a whole: pairs that keep coming without a consistent
        # window would otherwise restart the progress timeout for ever.
        collect_limit = settings.settle_timeout + settings.topic_timeout
        outcome = await self._wait_for(
            done, settings.topic_timeout, tuple(SENSOR_TOPICS), settings.topic_timeout,
            progress=collector.pair_count, deadline_s=collect_limit)
        with self._lock:
            if collector.ready():
                dropped_before = collector.inconsistent
                row = collector.take_posture()
                dropped = collector.inconsistent - dropped_before
            else:
                counts = collector.counts()
                row = None
                collector.stop()
        if row is None and counts['pairs'] >= limit:
            return self._skip(
                k, count, f'no {settings.samples_per_posture} consistent samples among '
                f'{counts["pairs"]} synchronised ones (too noisy, or the device readings did not '
                'change from the previous posture)', skipped)
        if row is None and outcome == WAIT_DEADLINE:
            return self._skip(
                k, count, f'no {settings.samples_per_posture} consistent synchronised samples '
                f'within {collect_limit:g} s (settle_timeout + topic_timeout) of settling: '
                f'{counts[LEG_LENGTHS]} leg-length and {counts["device"]} complete device '
                f'samples, {counts["pairs"]} within sync_tolerance {settings.sync_tolerance:g} s',
                skipped)
        if row is None:
            if outcome in SENSOR_TOPICS:
                raise RunFailed(f'topic {outcome} is silent: no message for '
                                f'{settings.topic_timeout:g} s while collecting posture {k}')
            raise RunFailed(
                f'no synchronised sample for {settings.topic_timeout:g} s at posture {k}: '
                f'{counts[LEG_LENGTHS]} leg-length and {counts["device"]} complete device '
                f'samples since settling, {counts["pairs"]} within sync_tolerance '
                f'{settings.sync_tolerance:g} s, consistent: {counts["consistent"]} '
                f'(non-finite readings dropped so far: {collector.non_finite})')
        if dropped:
            log.warning(f'posture {k}/{count}: dropped {dropped} synchronised sample(s) '
                        'inconsistent with the rest (glitch, or a stream still reporting the '
                        'previous posture)')
        residuals = calibration.posture_residuals(settings.nominal, pose, row.leg_lengths,
                                                  row.readings)
        self._progress(k, count, names.PHASE_COLLECTING,
                       f'posture {k} of {count}: {row.n_samples} samples averaged', residuals)
        log.info(f'posture {k}/{count}: {row.n_samples} samples averaged')
        return row

    def _skip(self, k, count, reason, skipped):
        skipped.append((k, reason))
        self.get_logger().warning(f'posture {k}/{count} skipped: {reason}')
        self._progress(k, count, names.PHASE_MOVING, f'posture {k} of {count} skipped: {reason}',
                       level=DiagnosticStatus.WARN, skipped=k)
        return None

    async def _apply_to_platform(self, settings, geometry):
        """Set the controller's ``geometry.*`` atomically; ``(applied, human message)``."""
        client, service = self._parameter_client(settings.platform_node_name)
        timeout = settings.topic_timeout
        if await self._wait_for(client.service_is_ready, timeout) != WAIT_OK:
            return False, (f'NOT applied: parameter service {service} unavailable within '
                           f'{timeout:g} s')
        request = SetParametersAtomically.Request()
        request.parameters = [
            Parameter(name, value=value).to_parameter_msg()
            for name, value in geometry_to_parameters(geometry).items()
        ]
        future = client.call_async(request)
        if await self._wait_for(future.done, timeout) != WAIT_OK:
            client.remove_pending_request(future)
            return False, f'NOT applied: no answer from {service} within {timeout:g} s'
        result = future.result().result
        if not result.successful:
            return False, f'NOT applied: {service} refused the geometry: {result.reason}'
        self.get_logger().info(f'calibrated geometry applied to /{settings.platform_node_name}')
        return True, f'applied to /{settings.platform_node_name} (geometry.* parameters)'


def main(args=None):
    """Console script ``calibrator``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(
        CalibratorNode, args,
        executor=lambda: MultiThreadedExecutor(num_threads=max(2, os.cpu_count() or 2)),
        logger_name=names.NODE_CALIBRATOR)


if __name__ == '__main__':
    raise SystemExit(main())
