"""What a calibration run uses of the node that hosts it (pure, no rclpy)."""

import dataclasses
import typing
from collections.abc import Awaitable, Callable

from gsp_calibrator.collection.events import PostureSkipped, RowReady
from gsp_calibrator.run.health import ProcessingLags

#: Results of :attr:`RunHost.wait_for`.
WAIT_OK = 'ok'
WAIT_TIMEOUT = 'timeout'

#: The ends of a posture after which the run goes on; any other ends the run (its ``message``).
POSTURE_ENDS = (RowReady, PostureSkipped)


@dataclasses.dataclass
class RunHost:
    """The node side of a run: every member the run uses, given by the node or a test."""

    name: tuple  #: ``(name, namespace)`` of the calibrator node
    log: typing.Any  #: logger (``info``, ``warning``, ``error``)
    #: ``TopicEndpointInfo`` of every publisher of pose commands (another calibrator?)
    command_publishers: Callable[[], list]
    #: subscribers to the pose commands (is the platform listening?)
    command_subscribers: Callable[[], int]
    #: publishers of the platform's status
    status_publishers: Callable[[], int]
    recorder: typing.Any  #: ``start(path, options)``, ``stop(drain_s)``, ``note_posture_end``
    #: ``start(record, protocol)``, ``command(k, pose)`` (awaitable of the posture's end),
    #: ``stop()``, ``failure`` (:class:`gsp_calibrator.node.posture_link.PostureLink`)
    postures: typing.Any
    #: ``wait_for(predicate, timeout_s)``: awaitable of :data:`WAIT_OK` once ``predicate()``
    #: holds, else :data:`WAIT_TIMEOUT`
    wait_for: Callable[[Callable[[], bool], float], Awaitable]
    #: ``in_thread(function, *args)``: awaitable of ``function(*args)`` run in a worker thread
    in_thread: Callable[..., Awaitable]
    #: ``await_thread(concurrent_future)``: awaitable of a ``concurrent.futures.Future``
    await_thread: Callable[..., Awaitable]
    #: ``selection(settings)``: ``concurrent.futures.Future`` of the (cached) posture selection
    selection: Callable[..., typing.Any]
    #: ``progress(index, phase, message='', residuals=None, warning=False, **extra)``: publish
    #: the run's progress at posture ``index`` (0 before the first)
    progress: Callable[..., None]
    #: ``deliver_result(settings, geometry, run.rigid.Verdicts, rigid geometry or None)``:
    #: awaitable of ``(success, note)`` (``gsp_calibrator.node.result_delivery``)
    deliver_result: Callable[..., Awaitable]
    #: whether the process is going down (Ctrl-C, SIGTERM): a failure then is no crash
    shutting_down: Callable[[], bool]
    #: the processing lags of the sensor messages (the run's: reset at its start, in result.json)
    processing_lags: ProcessingLags = dataclasses.field(default_factory=lambda: ProcessingLags(()))


async def first_timeout(wait_for, timeout_s, checks):
    """Await each ``(predicate, message)`` of ``checks`` in turn through ``wait_for`` (see
    :attr:`RunHost.wait_for`); the message of the first that times out, else ''."""
    for predicate, message in checks:
        if await wait_for(predicate, timeout_s) != WAIT_OK:
            return message
    return ''
