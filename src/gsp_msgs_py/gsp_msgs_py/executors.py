"""rclpy's ``MultiThreadedExecutor`` without its growing list of futures (rclpy 7.1, Jazzy).

rclpy 7.1's executor resumes an ``async`` callback by polling: every time it wakes up (any timer,
message or guard condition), it yields each pending coroutine task again, and its
``MultiThreadedExecutor`` appends the task to its list of futures once more. The list keeps every
copy until the task finishes, and the whole list is scanned on every wake-up. A coroutine that
awaits for the length of a run (the calibrator's ``calibrate`` service) while the executor wakes
hundreds of times a second therefore makes each wake-up cost more than the last: the spin thread
ends up scanning tens of thousands of entries a wake-up, holding the GIL from the callbacks
(ros2/rclpy#1452; later rclpy versions resume a task only once what it awaits is done).

:class:`MultiThreadedExecutor` keeps one entry a task; everything else is rclpy's.
"""

from rclpy import executors as rclpy_executors


class MultiThreadedExecutor(rclpy_executors.MultiThreadedExecutor):
    """``rclpy.executors.MultiThreadedExecutor`` that tracks each callback task once."""

    def _spin_once_impl(self, timeout_sec=None, wait_condition=lambda: False):
        try:
            handler, _, _ = self.wait_for_ready_callbacks(timeout_sec, None, wait_condition)
        except (
            rclpy_executors.ExternalShutdownException,
            rclpy_executors.ShutdownException,
            rclpy_executors.TimeoutException,
            rclpy_executors.ConditionReachedException,
        ):
            return
        self._executor.submit(handler)
        # A resumed coroutine task is the same object each time: track it once (identity, not
        # equality; the list holds only the tasks not yet done, a handful).
        if not any(future is handler for future in self._futures):
            self._futures.append(handler)
        for future in [future for future in self._futures if future.done()]:
            self._futures.remove(future)
            future.result()  # raise any exceptions, as rclpy does
