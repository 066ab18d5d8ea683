"""Waiting without blocking, for the calibrator node: predicate waits, worker threads and the
sensor listener thread (docs/architecture.md)."""

import concurrent.futures
import dataclasses
import threading

from rclpy.executors import ExternalShutdownException, ShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future

from gsp_calibrator.run.host import WAIT_OK, WAIT_TIMEOUT


def new_future(executor):
    """An rclpy Future whose completion wakes ``executor`` (and the coroutine awaiting it)."""
    future = Future(executor=executor)
    # A done callback makes the executor wake up (and resume the awaiting coroutine) at once.
    future.add_done_callback(lambda _: None)
    return future


def run_in_thread(function, *args, **kwargs):
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


def await_thread(concurrent_future, future):
    """Complete the rclpy ``future`` with the result (or exception) of ``concurrent_future``."""

    def done(source):
        if future.done():
            return
        error = source.exception()
        try:
            if error is not None:
                future.set_exception(error)
            else:
                future.set_result(source.result())
        except AttributeError:
            # The executor was shut down meanwhile (the node is going down): nobody awaits.
            pass

    concurrent_future.add_done_callback(done)
    return future


class ThreadResults:
    """Results of :func:`run_in_thread` calls by key, the ``size`` latest kept (thread-safe)."""

    def __init__(self, size):
        self.size = int(size)
        self._futures = {}
        self._lock = threading.Lock()

    def get(self, key, function, *args):
        """The (maybe running) Future of ``function(*args)`` under ``key`` (again if it failed)."""
        with self._lock:
            future = self._futures.get(key)
            if future is None or (future.done() and future.exception() is not None):
                future = self._futures[key] = run_in_thread(function, *args)
                while len(self._futures) > self.size:
                    self._futures.pop(next(iter(self._futures)))
        return future


@dataclasses.dataclass
class _Wait:
    predicate: object  # () -> bool
    timeout: float  # s from the start before WAIT_TIMEOUT
    started: float  # s, the clock of poll()
    future: Future


class Waits:
    """Predicate waits completed by :meth:`poll` (thread-safe)."""

    def __init__(self, clock):
        self._clock = clock
        self._lock = threading.Lock()
        self._waits = []

    def add(self, predicate, timeout_s, future):
        """``future`` completes with :data:`WAIT_OK` once ``predicate()`` holds, or
        :data:`WAIT_TIMEOUT` after ``timeout_s``; returns it."""
        with self._lock:
            self._waits.append(_Wait(predicate, float(timeout_s), self._clock(), future))
        self.poll()
        return future

    def poll(self):
        """Complete the waits whose condition or timeout has come."""
        finished = []
        with self._lock:
            now = self._clock()
            for wait in list(self._waits):
                try:
                    outcome = WAIT_OK if wait.predicate() else None
                except Exception as error:  # a broken predicate must not kill the callbacks
                    outcome = f'error: {error}'
                if outcome is None and now - wait.started >= wait.timeout:
                    outcome = WAIT_TIMEOUT
                if outcome is not None:
                    self._waits.remove(wait)
                    finished.append((wait.future, outcome))
        for future, outcome in finished:
            if not future.done():
                future.set_result(outcome)

    def cancel(self):
        """Cancel every pending wait."""
        with self._lock:
            waits, self._waits = self._waits, []
        for wait in waits:
            if not wait.future.done():
                wait.future.cancel()

    def __len__(self):
        return len(self._waits)


class SensorListener:
    """A node ``<node name>_<suffix>`` in ``node``'s namespace and context, spun in a thread of its
    own; ``setup(listener node)`` gives :attr:`extra` (the recorder, which subscribes to the
    sensor topics); ``on_error(error)``: a callback failed (None: raised)."""

    def __init__(self, node, suffix, setup, on_error=None):
        name = f'{node.get_name()}_{suffix}'
        self.on_error = on_error
        self.node = Node(
            name,
            namespace=node.get_namespace(),
            context=node.context,
            use_global_arguments=False,
            start_parameter_services=False,
        )
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(self.node)
        self.extra = setup(self.node)
        self._thread = threading.Thread(target=self._spin, name=f'{name}-executor', daemon=True)
        self._thread.start()

    def _spin(self):
        while True:
            try:
                self.executor.spin()
                return
            except (ExternalShutdownException, ShutdownException):
                return
            except Exception as error:
                # A signal shuts the context down from another thread; this thread's wait can
                # then fail (RCLError from rcl_wait) instead of raising ExternalShutdownException.
                if not self.node.context.ok():
                    return
                if self.on_error is None:
                    raise
                self.on_error(error)  # a callback failed: report it and keep listening

    def close(self):
        self.executor.shutdown(timeout_sec=2.0)
        self._thread.join(timeout=2.0)
        self.node.destroy_node()
