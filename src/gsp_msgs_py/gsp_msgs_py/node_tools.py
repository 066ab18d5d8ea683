"""The node skeleton shared by every node: publishers, timer ticks, throttled publishing and
:func:`run_node` with its signal handling (docs/architecture.md)."""

import signal
import threading

from . import names
from .parameter_specs import ConfigurationError

# rclpy is imported only where a node is needed: pure modules import this one without it.

#: The measuring device's topics, in the order of its readings ``[alpha, beta, phi, d_m]``.
DEVICE_TOPICS = (names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER, names.TOPIC_LVDT)


def create_publishers(node, topics):
    """``{topic: publisher}`` of ``topics``, each with its interface type and QoS profile."""
    from . import qos

    return {
        topic: node.create_publisher(
            names.interface_type(names.TOPIC_TYPES[topic]), topic, qos.TOPIC_QOS[topic]
        )
        for topic in topics
    }


def device_messages(readings, stamp, frame_id):
    """``{topic: JointState}`` of one device instant ``[alpha, beta, phi, d_m]`` (rad, rad, rad,
    m) stamped ``stamp``; ValueError naming a value that is not finite."""
    from . import conversions

    alpha, beta, phi, d_m = readings
    return {
        names.TOPIC_INCLINOMETER: conversions.inclinometer_to_msg(alpha, beta, stamp, frame_id),
        names.TOPIC_ENCODER: conversions.encoder_to_msg(phi, stamp, frame_id),
        names.TOPIC_LVDT: conversions.lvdt_to_msg(d_m, stamp, frame_id),
    }


def scheduled_tick_ns(period_ns, until_next_ns, now_ns):
    """The scheduled instant (ns) of the tick a periodic timer's callback runs for, never after
    ``now_ns`` (``now_ns`` when ``until_next_ns`` is None or the clock jumped back).

    rcl advances the next call by whole periods before the callback, so the tick is ``next -
    period``: samples are stamped on the timer's grid, free of the scheduling delay.
    """
    if until_next_ns is None or period_ns <= 0:
        return int(now_ns)
    tick_ns = int(now_ns) + int(until_next_ns) - int(period_ns)
    return tick_ns if tick_ns <= int(now_ns) else int(now_ns)


def timer_tick_time(node, timer):
    """``rclpy.time.Time`` (``node``'s clock) of :func:`scheduled_tick_ns` for ``timer``, called
    from the timer's own callback."""
    from rclpy.time import Time

    now = node.get_clock().now()
    tick_ns = scheduled_tick_ns(
        timer.timer_period_ns, timer.time_until_next_call(), now.nanoseconds
    )
    return Time(nanoseconds=tick_ns, clock_type=now.clock_type)


#: Least interval (s) between two warnings about dropped messages of one kind.
DROP_WARNING_THROTTLE_S = 1.0


def publish_messages(node, publishers, what, build, *args):
    """Publish the ``{topic: message}`` of ``build(*args)``; whether it did. A ValueError drops
    them all with a throttled warning: a node never dies on one bad sample."""
    try:
        messages = build(*args)
    except ValueError as error:
        node.get_logger().warning(
            f'dropping {what}: {error}', throttle_duration_sec=DROP_WARNING_THROTTLE_S
        )
        return False
    for topic, msg in messages.items():
        publishers[topic].publish(msg)
    return True


def close_opened(node, *attributes):
    """Close each of ``node``'s ``attributes`` that is set (from ``destroy_node``: a constructor
    that failed part-way leaves the later ones unset)."""
    for attribute in attributes:
        resource = getattr(node, attribute, None)
        if resource is not None:
            resource.close()


def spin_until(executor, predicate, timeout):
    """Spin ``executor`` until ``predicate()`` holds; False if ``timeout`` (s) passes first."""
    import time

    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.01)
    return True


def shutdown_executor(executor, timeout_sec=5.0):
    """Shut ``executor`` down once its thread pool's callbacks have run (after the spin).

    rclpy 7.1's ``Executor.shutdown`` does not wait for them: a queued callback then fails with
    ``InvalidHandle``, and a node destroyed under a running one can crash the process.
    """
    pool = getattr(executor, '_executor', None)  # the MultiThreadedExecutor's ThreadPoolExecutor
    if pool is not None:
        pool.shutdown(wait=True)
    return executor.shutdown(timeout_sec=timeout_sec)


#: Longest wait (s) of one turn of :func:`run_node`'s spin: how late a stop signal may be seen.
STOP_POLL_S = 0.1


def run_node(make_node, args=None, executor=None, *, logger_name):
    """Initialise rclpy, build ``make_node()`` and spin it until shutdown; the exit code.

    ``executor``: an instance or a factory (default ``SingleThreadedExecutor``). Exit code 1 on
    :class:`ConfigurationError` (logged fatal under ``logger_name``), else 0, whatever signals.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    # Before rclpy.init: a signal from now on is recorded (see StopSignals).
    stop_signals = StopSignals().install()
    options = SignalHandlerOptions.NO if stop_signals.installed else None
    rclpy.init(args=args, signal_handler_options=options)
    node = None
    active_executor = None
    exit_code = 0
    try:
        executor = executor or SingleThreadedExecutor
        active_executor = executor() if callable(executor) else executor
        if not stop_signals.received and rclpy.ok():
            node = make_node()
            active_executor.add_node(node)
            # Short turns so the main thread sees a recorded signal; rclpy's own handling could
            # leave a node without a timer waiting for ever (docs/faults.md).
            while not stop_signals.received and rclpy.ok():
                active_executor.spin_once(timeout_sec=STOP_POLL_S)
    except ConfigurationError as error:
        rclpy.logging.get_logger(logger_name).fatal(f'cannot start: {error}')
        exit_code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # An external shutdown from another thread can make a spin fail to build its wait set
        # (RCLError) instead of raising ExternalShutdownException.
        if rclpy.ok():
            raise
    finally:
        if active_executor is not None:
            # The context first, so a callback waiting on it ends before the pool is joined.
            shut_down_context(active_executor.context)
            shutdown_executor(active_executor, timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        # Nothing is left to clean up: a later signal must not kill the process now.
        stop_signals.ignore()
    return exit_code


def shut_down_context(context):
    """Shut ``context`` down with ``rcl_shutdown`` alone, as rclpy's signal handler does:
    ``Context.try_shutdown`` would also finalise the logging under the node's cleanup."""
    from rclpy.impl.implementation_singleton import rclpy_implementation

    handle = context.handle
    with handle:
        if handle.ok():
            try:
                handle.shutdown()
            except rclpy_implementation.RCLError:  # shut down meanwhile (an external shutdown)
                pass


class StopSignals:
    """SIGINT and SIGTERM handlers that record the signal and never raise, so a second signal
    cannot land inside the cleanup (as ``KeyboardInterrupt`` would)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.received = []  #: signal numbers, in order of arrival
        self.installed = False  #: whether the handlers are in place (main thread only)

    def __call__(self, signal_number, frame):
        self.received.append(signal_number)

    def install(self):
        """Install for :attr:`SIGNALS` (main thread only; elsewhere a no-op, and rclpy's own
        handlers stay in charge); returns self."""
        self.installed = threading.current_thread() is threading.main_thread()
        return self._set(self)

    def ignore(self):
        """After the cleanup: ignore :attr:`SIGNALS` until exit (at interpreter shutdown Python
        restores the default action of handled signals, which would kill a clean stop)."""
        return self._set(signal.SIG_IGN)

    def _set(self, handler):
        if threading.current_thread() is threading.main_thread():
            for number in self.SIGNALS:
                signal.signal(number, handler)
        return self
