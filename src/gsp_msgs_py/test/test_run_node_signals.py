"""run_node stops a node whose executor nothing else wakes, whatever instant the signals arrive in.

rclpy 7.1's own signal handling wakes the executors first and shuts the context down after: an
executor woken in between finds the context still up and waits again, with nothing left to wake
it, so a node without a timer (``gsp_fake_device``) never stopped (docs/faults.md, Signals). The
window is a few microseconds, so each child process makes it certain: all its threads share one
CPU and the main thread runs at a real-time priority (``SCHED_FIFO``), so that a thread that
wakes the main thread is preempted by it at once and goes on only once the main thread waits
again (with rclpy's handling: shuts the context down only then, 8 hangs in 8 runs).
Real-time scheduling needs root (as CI has); without it the instants are not forced, and the
test still checks each stop without making the race certain.
"""

import signal
import subprocess
import sys

import pytest

#: A node like gsp_fake_device's (a subscription nobody publishes, no timer) sending itself the
#: given signals at one instant: ``start-up`` (in ``make_node``, before the spin), ``spin`` (in
#: a callback), ``cleanup`` (in ``destroy_node``, after a SIGINT at start-up).
STOP_CHILD = """
import os, signal, sys
from std_msgs.msg import String
from rclpy.node import Node
from gsp_msgs_py import node_tools

SIGNALS, AT = {signals!r}, {at!r}


def main_thread_first():
    cpu = min(os.sched_getaffinity(0))
    for thread_id in map(int, os.listdir('/proc/self/task')):
        os.sched_setaffinity(thread_id, {{cpu}})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))  # this (the main) thread only
    except PermissionError:  # not root: the instants are not forced, the stop is still checked
        pass


def send(names):
    for name in names:
        os.kill(os.getpid(), getattr(signal, name))


class Quiet(Node):
    def __init__(self):
        super().__init__('stop_child')
        self.create_subscription(String, 'stop_child_never_published', lambda msg: None, 1)
        main_thread_first()
        if AT == 'spin':
            self.create_guard_condition(lambda: send(SIGNALS)).trigger()
        else:
            send(SIGNALS if AT == 'start-up' else ('SIGINT',))

    def destroy_node(self):
        if AT == 'cleanup':
            send(SIGNALS)
        print('destroyed', flush=True)
        super().destroy_node()


sys.exit(node_tools.run_node(Quiet, logger_name='stop_child'))
"""


@pytest.mark.parametrize('at', ['start-up', 'spin', 'cleanup'])
@pytest.mark.parametrize(
    'signals',
    [('SIGINT',), ('SIGTERM',), ('SIGINT', 'SIGINT'), ('SIGTERM', 'SIGINT')],
    ids='+'.join,
)
def test_a_node_nothing_else_wakes_stops_at_any_instant_of_the_signals(at, signals):
    process = subprocess.Popen(
        [sys.executable, '-c', STOP_CHILD.format(signals=signals, at=at)],
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a terminal does
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        output, _ = process.communicate(timeout=60)  # bounds a failure only (a hung spin)
    except subprocess.TimeoutExpired:
        process.kill()
        output, _ = process.communicate()
        pytest.fail(f'still spinning 60 s after {"+".join(signals)} at {at}:\n{output}')
    assert process.returncode == 0, output
    assert output.count('destroyed') == 1, output
    for word in ('Traceback', 'Exception ignored', 'terminate called', 'KeyboardInterrupt'):
        assert word not in output, output
