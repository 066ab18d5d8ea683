"""What a calibration run needs from the node that hosts it: :class:`RunHost` (pure, no rclpy).

The run (:class:`gsp_calibrator.run.flow.CalibrationRun`) is a coroutine. It never touches rclpy:
everything it needs from the graph, the executor and the threads goes through this protocol,
which the ``calibrator`` node implements (``CalibratorNode``) and a test can implement with
plain Python (``test_run_flow.py``). Awaitables may be rclpy futures (the node) or coroutines.
"""

import typing

#: Results of :meth:`RunHost.wait_for`.
WAIT_OK = 'ok'
WAIT_TIMEOUT = 'timeout'


class RunRecorder(typing.Protocol):
    """The run's recorder (``recording.recorder.RunRecorder`` in the node)."""

    def start(self, path, options=None): ...

    def stop(self, drain_s=0.0): ...


class FinalEvents(typing.Protocol):
    """The final event of each posture, in order (``node_threads.EventQueue`` in the node)."""

    def get(self) -> typing.Awaitable: ...


@typing.runtime_checkable
class RunHost(typing.Protocol):
    """The node side of a run. The node commands each posture itself, from the event that ends
    the previous one, and queues that event in :attr:`finals`; the run reports it afterwards."""

    recorder: RunRecorder
    finals: FinalEvents
    #: The event that ended the collection early (silent topic, second source...), else None.
    failure: object

    # --- the graph ------------------------------------------------------------------------------
    def get_logger(self): ...

    def shutting_down(self) -> bool:
        """Whether the process is going down (Ctrl-C, SIGTERM): a failure then is no crash."""

    def get_name(self) -> str: ...

    def get_namespace(self) -> str: ...

    def get_publishers_info_by_topic(self, topic) -> list: ...

    def count_publishers(self, topic) -> int: ...

    def command_subscriber_count(self) -> int:
        """Subscribers to the run's pose commands (is the platform listening?)."""

    # --- waiting and threads --------------------------------------------------------------------
    def wait_for(self, predicate, timeout_s) -> typing.Awaitable:
        """Awaitable of :data:`WAIT_OK` once ``predicate()`` holds, else :data:`WAIT_TIMEOUT`."""

    def await_thread(self, concurrent_future) -> typing.Awaitable: ...

    def in_thread(self, function, *args, **kwargs) -> typing.Awaitable:
        """Awaitable of ``function(*args, **kwargs)`` run in a worker thread."""

    def selection_future(self, settings):
        """``concurrent.futures.Future`` of the (cached) posture selection of ``settings``."""

    # --- the run --------------------------------------------------------------------------------
    def progress(self, index, phase, message='', residuals=None, warning=False, **extra):
        """Publish the run's progress at posture ``index`` (0 before the first)."""

    def start_collection(self, session, collection):
        """Feed messages to ``collection`` (a ``CollectionProtocol``) and rows to ``session``."""

    def stop_collection(self): ...

    def command_first(self):
        """Command the first posture left; each next one follows from the end of the previous."""

    def collection_done(self) -> bool:
        """Whether every posture was commanded, has ended and was queued in :attr:`finals`."""

    def deliver_result(self, settings, geometry, accepted) -> typing.Awaitable:
        """Publish the calibrated ``geometry`` and apply it as ``settings`` ask; awaitable of
        ``(success, note)`` (see ``gsp_calibrator.result_delivery``)."""

    def run_ended(self):
        """The run is over (its answer is being sent)."""


async def first_timeout(wait_for, timeout_s, checks):
    """Await each ``(predicate, message)`` of ``checks`` in turn through ``wait_for`` (see
    :meth:`RunHost.wait_for`); the message of the first that times out, else ''."""
    for predicate, message in checks:
        if await wait_for(predicate, timeout_s) != WAIT_OK:
            return message
    return ''
