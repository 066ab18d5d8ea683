"""Pytest helpers shared by the ROS packages' test suites.

Call :func:`use_loopback_domain` from a ``conftest.py`` before anything creates an rclpy
context, and re-export the :func:`ros_context` fixture. In-process node tests subclass
:class:`NodeHarness` and make their fixture with :func:`harness_fixture`. rclpy is imported
lazily, so importing this module does not load ROS.
"""

import itertools
import time

import pytest

from gsp_msgs_py.node_tools import shutdown_executor, spin_until  # noqa: F401 (re-exported)
from gsp_msgs_py.ros_environment import DomainInUseError, enter_private_domain


def wait_until(predicate, timeout):
    """Wait for an event another thread brings (``predicate()``), polling; False if ``timeout``
    (s) passes first. The timeout only bounds a failure."""
    import threading

    pause = threading.Event()
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        pause.wait(0.01)
    return True


def grid_offsets(stamps_ns, period_ns):
    """The distinct offsets (integer ns, 0 to ``period_ns - 1``) of ``stamps_ns`` from whole
    periods of ``period_ns``: a single one for stamps on one timer's grid of scheduled ticks
    (see :func:`gsp_msgs_py.node_tools.scheduled_tick_ns`), exactly, under a simulated clock."""
    return {int(stamp) % int(period_ns) for stamp in stamps_ns}


#: Step (ns) by which :func:`drive_sim_clock` advances ``/clock``: a whole number of ns, no divisor
#: of the tests' timer periods (10 to 100 ms), so the instants at which a timer's callback runs
#: fall off its grid, by a different offset each time (37.3 ms steps repeat a 50 ms phase only
#: after 500 steps).
SIM_CLOCK_STEP_NS = 37_300_000


def drive_sim_clock(node, step_ns=SIM_CLOCK_STEP_NS, every_s=0.01):
    """Publish ``/clock`` from ``node`` every ``every_s`` s of ``node``'s own clock, advancing by
    ``step_ns`` each time from ``step_ns``: the clock of a node with ``use_sim_time`` then reads
    only these instants, and does not move between two reads in one callback. Returns the
    timer (destroyed with ``node``)."""
    from rosgraph_msgs.msg import Clock

    publisher = node.create_publisher(Clock, '/clock', 10)
    steps = itertools.count(1)

    def tick():
        nanoseconds = next(steps) * int(step_ns)
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(nanoseconds, 1_000_000_000)
        publisher.publish(msg)

    return node.create_timer(every_s, tick)


#: Environment variable that marks the processes a test starts; their children inherit it,
#: whatever session or process group they start (see :func:`marked_processes`).
PROCESS_MARKER_VARIABLE = 'GSP_TEST_MARKER'


def marked_environment(env=None):
    """``(environment, marker)``: ``env`` (default ``os.environ``) plus a fresh
    :data:`PROCESS_MARKER_VARIABLE` for the processes a test starts."""
    import os
    import uuid

    marker = uuid.uuid4().hex
    return {**(os.environ if env is None else env), PROCESS_MARKER_VARIABLE: marker}, marker


def marked_processes(marker):
    """PIDs of the live processes (this one aside) whose environment holds ``marker`` (from
    :func:`marked_environment`): what a test started and has not ended, with every descendant.
    Linux (``/proc``); a zombie has no environment left, so it does not count."""
    import os
    from pathlib import Path

    needle = f'{PROCESS_MARKER_VARIABLE}={marker}'.encode()
    found = []
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if needle in (entry / 'environ').read_bytes().split(b'\0'):
                found.append(int(entry.name))
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return found


#: Bound on one ``gsp_demo`` run of a test (s): generous, the machine may be loaded (a demo
#: takes about a minute); it only bounds a failure.
DEMO_TIMEOUT_S = 400.0


def demo_command():
    """``gsp_demo`` from PATH (``make test``), else the module with this interpreter."""
    import shutil
    import sys

    executable = shutil.which('gsp_demo')
    return [executable] if executable else [sys.executable, '-m', 'gsp_calibrator.tools.demo']


def run_demo(arguments, env, timeout=DEMO_TIMEOUT_S):
    """Run ``gsp_demo arguments`` in ``env``; ``(completed process, stdout + stderr)``."""
    import subprocess

    completed = subprocess.run(
        demo_command() + list(arguments), env=env, capture_output=True, text=True, timeout=timeout
    )
    return completed, completed.stdout + completed.stderr


class SpinThread:
    """Spins ``executor`` in a daemon thread until :meth:`stop` (then shut it down yourself).

    Not ``executor.spin()`` in a thread: shutting an executor down while another thread builds
    its wait set can fail in that thread (rclpy 7.1: AttributeError on the destroyed guard
    condition). :meth:`stop` ends the loop first.
    """

    def __init__(self, executor, period_s=0.05):
        import threading

        self.executor = executor
        self._period_s = period_s
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=self._period_s)

    def stop(self, timeout=30.0):
        """End the loop and wait for it (``timeout`` s bounds a failure)."""
        self._stop.set()
        self.thread.join(timeout=timeout)


class SpinningNodes:
    """In-process nodes spun as they run in use: ``together`` (e.g. a calibrator and the test's
    client) share one :class:`gsp_msgs_py.executors.MultiThreadedExecutor` (:attr:`executor`),
    and every node of ``apart`` (a simulated platform, a device driver: a process each in use)
    gets a ``SingleThreadedExecutor`` and a :class:`SpinThread` of its own.

    Why apart: an rclpy executor rebuilds the wait set of all its nodes' entities at every
    wake-up, so one executor for every node woken by each of their hundreds of messages a second
    kept a test process busy on the executor itself (four times the CPU of a whole test).
    """

    def __init__(self, context, together, apart=(), num_threads=4):
        from rclpy.executors import SingleThreadedExecutor

        from gsp_msgs_py.executors import MultiThreadedExecutor

        self.executor = MultiThreadedExecutor(num_threads=num_threads, context=context)
        for node in together:
            self.executor.add_node(node)
        self._apart = {}
        for node in apart:
            self._apart[node] = SingleThreadedExecutor(context=context)
            self._apart[node].add_node(node)
        self._spinning = [SpinThread(self.executor)] + [
            SpinThread(executor) for executor in self._apart.values()
        ]

    def remove(self, node):
        """The node's callbacks stop (its timers no longer publish); destroy it yourself."""
        (self._apart.get(node) or self.executor).remove_node(node)

    def close(self):
        """Stop spinning, remove the nodes and shut the executors down (the nodes remain)."""
        for spinning in self._spinning:
            spinning.stop()
        # Remove the nodes first: the executors then have no new work when they shut down.
        for executor in [self.executor, *self._apart.values()]:
            for node in executor.get_nodes():
                executor.remove_node(node)
            shutdown_executor(executor)  # after the callbacks in progress


def use_loopback_domain():
    """Keep DDS on loopback, in a ROS domain of this test session's own: a free one claimed
    (through domain_coordinator) unless ``ROS_DOMAIN_ID`` is set (then checked: no other run
    holds it, no nodes in it yet); see :func:`~gsp_msgs_py.ros_environment.enter_private_domain`.
    A collision fails the session at once with the reason, rather than letting two runs hear
    each other."""
    try:
        return enter_private_domain()
    except DomainInUseError as error:
        pytest.exit(f'ROS domain: {error}', returncode=3)


@pytest.fixture
def ros_context():
    """A fresh, initialised ``rclpy.Context``, shut down after the test."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


class NodeHarness:
    """A node under test and a test node (:attr:`node`), spun together by one executor.

    ``timeout`` (s) bounds every :meth:`spin_until`; generous, since the machine may be loaded,
    and waits end as soon as their predicate holds. A node under test with ``use_sim_time``
    gets its ``/clock`` from the test node (:func:`drive_sim_clock`).
    """

    def __init__(self, context, node_under_test, test_node_name, timeout=10.0):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.timeout = timeout
        self.node = rclpy.create_node(test_node_name, context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self._under_test = node_under_test
        self.executor.add_node(node_under_test)
        self.executor.add_node(self.node)
        if node_under_test.get_parameter('use_sim_time').value:
            drive_sim_clock(self.node)
        from gsp_msgs_py.diagnostics import DiagnosticsListener

        self.diagnostics = DiagnosticsListener(self.node)  #: what /diagnostics said

    def subscribe(self, topic, callback):
        """Subscribe the test node to ``topic`` with its interface type and QoS."""
        from gsp_msgs_py import names, qos

        return self.node.create_subscription(
            names.interface_type(names.TOPIC_TYPES[topic]), topic, callback, qos.TOPIC_QOS[topic]
        )

    def publisher(self, topic):
        """A publisher of the test node on ``topic`` with its interface type and QoS."""
        from gsp_msgs_py import names, qos

        return self.node.create_publisher(
            names.interface_type(names.TOPIC_TYPES[topic]), topic, qos.TOPIC_QOS[topic]
        )

    def spin_until(self, predicate, timeout=None):
        """Spin until ``predicate()`` holds; False if the timeout passes first."""
        return spin_until(self.executor, predicate, self.timeout if timeout is None else timeout)

    def wait_health(self, name, predicate=lambda health: True):
        """The latest ``Health`` of the status ``name`` on ``/diagnostics`` once
        ``predicate(health)`` holds; AssertionError with what was heard if it does not in time."""
        reports = self.diagnostics.reports

        def holds():
            return name in reports and predicate(reports[name])

        assert self.spin_until(holds), f'/diagnostics: {name!r} not as expected; heard {reports}'
        return reports[name]

    def spin_for(self, duration):
        """Spin for ``duration`` seconds (to let messages that must be ignored arrive)."""
        deadline = time.monotonic() + duration
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self._under_test.destroy_node()


def harness_fixture(make_harness):
    """A pytest fixture yielding ``make_harness(ros_context, overrides)``, closed afterwards.

    ``overrides`` is the test's indirect parameter (``@pytest.mark.parametrize('harness',
    [[Parameter(...)]], indirect=True)``), else ``()``. Assign it to the fixture's name.
    """

    @pytest.fixture
    def fixture(ros_context, request):
        harness = make_harness(ros_context, getattr(request, 'param', ()))
        try:
            yield harness
        finally:
            harness.close()

    return fixture
