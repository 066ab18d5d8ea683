"""rclpy's ``MultiThreadedExecutor`` without its growing list of futures: rclpy 7.1 (Jazzy)
re-appends a pending coroutine task at every wake-up, slowing the next (ros2/rclpy#1452)."""

from rclpy import executors as rclpy_executors


class MultiThreadedExecutor(rclpy_executors.MultiThreadedExecutor):
    """``rclpy.executors.MultiThreadedExecutor`` that tracks each callback task once."""

    # rclpy's spin_once and spin_once_until_future_complete call it.
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
