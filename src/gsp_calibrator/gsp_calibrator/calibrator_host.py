"""What a calibration run asks of the ``calibrator`` node (:class:`.run.host.RunHost`).

:class:`CalibratorRunHost` holds those members (futures and waits, progress, the collection
switches, the result's delivery) over the node's state; :class:`.calibrator_node.CalibratorNode`
inherits them beside its wiring and message callbacks, which set the state they use
(``_lock``, ``_running``, ``_run``, ``_protocol``, ``_session``, ``_sensors_active``, ``failure``,
``finals``, ``_ending``, ``_sources``, ``_waits``, ``_selections``, ``_results``,
``_progress_pub``, ``command_publisher``, ``_last_progress``) and ``_command_next()`` and
``_handle()``.
"""

from diagnostic_msgs.msg import DiagnosticStatus

from gsp_calibrator.node_threads import await_thread, new_future, run_in_thread
from gsp_calibrator.run import postures
from gsp_msgs_py import conversions


class CalibratorRunHost:
    """The :class:`~gsp_calibrator.run.host.RunHost` members of the calibrator node."""

    def _settings_count(self):
        run = self._run
        return run.settings.posture_count if run is not None else 0

    def _new_future(self):
        return new_future(self.executor)

    def wait_for(self, predicate, timeout_s):
        """Future of ``WAIT_OK`` once ``predicate()`` holds, else ``WAIT_TIMEOUT`` (s)."""
        return self._waits.add(predicate, timeout_s, self._new_future())

    def await_thread(self, concurrent_future):
        return await_thread(concurrent_future, self._new_future())

    def in_thread(self, function, *args, **kwargs):
        """Awaitable of ``function(*args, **kwargs)`` run in a worker thread."""
        return self.await_thread(run_in_thread(function, *args, **kwargs))

    def progress(self, index, phase, message='', residuals=None, warning=False, **extra):
        """Publish the run's progress at posture ``index`` (0 before the first)."""
        count = self._settings_count()
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

    def selection_future(self, settings):
        """The (possibly running, cached) posture selection of ``settings``."""
        args = postures.selection_arguments(settings)
        return self._selections.get(postures.selection_key(*args), postures.choose_postures, *args)

    def start_collection(self, session, collection):
        with self._lock:
            self._protocol, self._session, self.failure = collection, session, None
            self.finals.clear()
            self._ending.clear()
            self._sources.reset()
            self._sensors_active = True

    def stop_collection(self):
        with self._lock:
            self._sensors_active = False

    def command_first(self):
        with self._lock:
            events = self._command_next()
        self._handle(events)

    def collection_done(self):
        """Whether every posture was commanded, has ended and was reported."""
        with self._lock:
            idle = self._protocol.posture is None and not self.finals and not self._ending
            return idle and self._session.commanded_all

    def deliver_result(self, settings, geometry, accepted):
        return self._results.deliver(settings, geometry, accepted, self.wait_for)

    def shutting_down(self):
        return not self.context.ok()

    def command_subscriber_count(self):
        return self.command_publisher.get_subscription_count()

    def run_ended(self):
        self._waits.cancel()
        with self._lock:
            self._running, self._session = False, None
