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
    command_publishers: Callable[[], list]  #: ``TopicEndpointInfo`` of each pose commander
    command_subscribers: Callable[[], int]  #: subscribers to the pose commands, bar its recorder
    status_publishers: Callable[[], int]  #: publishers of the platform's status
    recorder: typing.Any  #: ``start(path, options)``, ``stop(drain_s)``, ``note_posture_end``
    #: ``start(record, protocol)``, ``command(k, pose)`` (awaitable of the posture's end),
    #: ``stop()``, ``failure`` (:class:`gsp_calibrator.node.posture_link.PostureLink`)
    postures: typing.Any
    #: ``wait_for(predicate, timeout_s)``: awaitable of :data:`WAIT_OK` once ``predicate()``
    #: holds, else :data:`WAIT_TIMEOUT`
    wait_for: Callable[[Callable[[], bool], float], Awaitable]
    in_thread: Callable[..., Awaitable]  #: ``in_thread(function, *args)`` in a worker thread
    await_thread: Callable[..., Awaitable]  #: ``await_thread(concurrent.futures.Future)``
    selection: Callable[..., typing.Any]  #: ``selection(settings)``: Future of the selection
    #: ``progress(index, phase, message='', residuals=None, warning=False, **extra)``: publish
    #: the run's progress at posture ``index`` (0 before the first)
    progress: Callable[..., None]
    #: ``deliver_result(settings, geometry, run.rigid.Verdicts, rigid geometry or None)``:
    #: awaitable of ``(success, note)`` (``gsp_calibrator.node.result_delivery``)
    deliver_result: Callable[..., Awaitable]
    shutting_down: Callable[[], bool]  #: the process is going down (a failure is no crash)
    #: the processing lags of the sensor messages (the run's: reset at its start, in result.json)
    processing_lags: ProcessingLags = dataclasses.field(default_factory=lambda: ProcessingLags(()))


async def first_timeout(wait_for, timeout_s, checks):
    """Await each ``(predicate, message)`` of ``checks`` in turn through ``wait_for`` (see
    :attr:`RunHost.wait_for`); the message of the first that times out, else ''."""
    for predicate, message in checks:
        if await wait_for(predicate, timeout_s) != WAIT_OK:
            return message
    return ''
