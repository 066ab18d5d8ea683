"""gsp_msgs_py.executors: the MultiThreadedExecutor tracks a coroutine task once however often it
is resumed (rclpy 7.1's list grows by one entry a wake-up, docs/architecture.md)."""

import threading

import rclpy
from gsp_testing import wait_until
from rclpy.task import Future

from gsp_msgs_py.executors import MultiThreadedExecutor

WAKE_UPS = 300  # timer callbacks while the coroutine waits: each wakes the executor


def test_a_waiting_coroutine_is_tracked_once_and_its_result_still_comes(ros_context):
    node = rclpy.create_node('executor_probe', context=ros_context)
    executor = MultiThreadedExecutor(num_threads=2, context=ros_context)
    executor.add_node(node)
    ticks = threading.Semaphore(0)
    node.create_timer(0.001, ticks.release)
    released = Future()

    async def wait_for_release():
        await released
        return 'finished'

    task = executor.create_task(wait_for_release)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        for _ in range(WAKE_UPS):
            assert ticks.acquire(timeout=30.0), 'the timer stopped ticking'
        # Every wake-up resumed the pending task; rclpy 7.1's own list would hold ~300 copies.
        assert sum(future is task for future in executor._futures) <= 1
        assert len(executor._futures) <= 3  # the task and at most the timer callbacks in flight
        released.set_result(None)
        assert wait_until(task.done, 30.0)
        assert task.result() == 'finished'
        assert wait_until(lambda: all(f is not task for f in executor._futures), 30.0)
    finally:
        executor.shutdown()
        spinner.join(30.0)
        node.destroy_node()
