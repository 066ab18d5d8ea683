"""node_tools: parameter specs, checks, declare/watch on a node, and the docs table."""

import math

import pytest
import rclpy
import rclpy.executors
from gsp_testing import SIM_CLOCK_STEP_NS, drive_sim_clock, grid_offsets
from rclpy.parameter import Parameter

from gsp_msgs_py.node_tools import scheduled_tick_ns, spin_until, timer_tick_time
from gsp_msgs_py.parameter_specs import (
    ConfigurationError,
    ParameterSpec,
    at_least,
    declare_parameters,
    greater_than,
    is_finite_number,
    not_blank,
    one_of,
    resolve_seed,
    seed_spec,
    validate_values,
    watch_parameters,
)

SPECS = (
    ParameterSpec(
        'rate',
        200.0,
        'Rate of the readings',
        unit='Hz',
        read_only=True,
        constraints='> 0',
        check=greater_than(0.0, 'Hz'),
    ),
    ParameterSpec(
        'noise', 1e-6, 'Noise std', unit='m', float_range=(0.0, 1.0), check=at_least(0.0, 'm')
    ),
    ParameterSpec(
        'seed',
        0,
        'Seed; -1 = random',
        integer_range=(-1, 10),
        check=at_least(-1, reason='must be >= 0, or -1 for a random seed'),
    ),
    ParameterSpec('mode', 'a', 'Mode', check=one_of('ab')),
    ParameterSpec('names', ['x', 'y'], 'Names | with a pipe'),
    ParameterSpec('frame', 'base', 'Frame', check=not_blank(reason='must not be empty')),
)


def test_is_finite_number():
    assert is_finite_number(1) and is_finite_number(-2.5)
    assert not any(is_finite_number(v) for v in (True, math.nan, math.inf, '1', None))


def test_checks_give_the_reason_with_name_and_value():
    assert validate_values(SPECS, {'rate': 10.0, 'seed': -1, 'unknown': 'ignored'}) == ''
    assert validate_values(SPECS, {'rate': 0.0}) == 'rate: 0.0 rejected, must be > 0 Hz'
    assert validate_values(SPECS, {'noise': math.nan}) == 'noise: nan rejected, must be >= 0 m'
    assert 'or -1 for a random seed' in validate_values(SPECS, {'seed': -2})
    assert validate_values(SPECS, {'mode': 'c'}) == "mode: 'c' rejected, must be one of ['a', 'b']"
    assert validate_values(SPECS, {'frame': ' '}) == "frame: ' ' rejected, must not be empty"
    assert not_blank('a file')('') == 'must name a file'


def test_descriptor_and_type():
    descriptor = SPECS[0].descriptor()
    assert descriptor.description == 'Rate of the readings (Hz)' and descriptor.read_only
    assert descriptor.additional_constraints == '> 0'
    assert SPECS[1].descriptor().floating_point_range[0].to_value == 1.0
    assert SPECS[2].descriptor().integer_range[0].from_value == -1
    assert [s.type_name for s in SPECS] == [
        'double',
        'double',
        'integer',
        'string',
        'string_array',
        'string',
    ]


def test_declare_and_watch_parameters(ros_context):
    node = rclpy.create_node(
        'node_tools_test', context=ros_context, parameter_overrides=[Parameter('noise', value=0.5)]
    )
    try:
        values = declare_parameters(node, SPECS, validate=lambda v: '')
        assert values['noise'] == 0.5 and values['rate'] == 200.0
        applied = []
        watch_parameters(
            node,
            SPECS,
            apply=applied.append,
            validate=lambda changes, current: (
                'too noisy' if changes.get('noise', current['noise']) > 0.9 else ''
            ),
        )
        result = node.set_parameters([Parameter('mode', value='c')])[0]
        assert not result.successful and result.reason.startswith("mode: 'c' rejected")
        assert node.set_parameters([Parameter('noise', value=0.95)])[0].reason == 'too noisy'
        assert node.set_parameters([Parameter('noise', value=0.25)])[0].successful
        assert applied == [{'noise': 0.25}]
    finally:
        node.destroy_node()


@pytest.mark.parametrize(
    'overrides, words',
    [
        ([Parameter('rate', value=0.0)], 'rate: 0.0 rejected'),
        ([Parameter('rate', value='fast')], 'rate'),  # wrong type
        ([Parameter('noise', value=2.0)], 'noise'),  # out of range
    ],
)
def test_declare_parameters_raises_one_configuration_error(ros_context, overrides, words):
    node = rclpy.create_node('node_tools_test', context=ros_context, parameter_overrides=overrides)
    try:
        with pytest.raises(ConfigurationError, match=words):
            declare_parameters(node, SPECS)
    finally:
        node.destroy_node()


def test_declare_parameters_runs_the_whole_set_check(ros_context):
    node = rclpy.create_node('node_tools_test', context=ros_context)
    try:
        with pytest.raises(ConfigurationError, match='inconsistent'):
            declare_parameters(node, SPECS, validate=lambda values: 'inconsistent')
    finally:
        node.destroy_node()


def test_a_noise_seed_is_fresh_at_each_start_unless_fixed():
    # Fresh by default: a simulated sensor restarted mid-run must not replay its noise.
    assert seed_spec().default == -1
    fresh = {resolve_seed(-1) for _ in range(5)}
    assert len(fresh) == 5 and all(0 <= seed < 2**31 for seed in fresh)  # a valid `seed`
    assert resolve_seed(7) == 7 and resolve_seed(0) == 0


def test_scheduled_tick_is_the_timer_grid_instant_before_its_next_call():
    period = 5_000_000
    # rcl has advanced the next call to 1_010 ms when the callback runs at 1_007.3 ms: the tick
    # it runs for is 1_005 ms; a callback late by more than a period keeps the grid too.
    assert scheduled_tick_ns(period, 2_700_000, 1_007_300_000) == 1_005_000_000
    assert scheduled_tick_ns(period, 1_000_000, 1_019_000_000) == 1_015_000_000
    assert scheduled_tick_ns(period, -1_000_000, 1_021_000_000) == 1_015_000_000  # due again
    # Nothing usable: the current time.
    assert scheduled_tick_ns(period, None, 1_007_300_000) == 1_007_300_000
    assert scheduled_tick_ns(0, 2_700_000, 1_007_300_000) == 1_007_300_000
    assert scheduled_tick_ns(period, 9_000_000, 1_007_300_000) == 1_007_300_000  # ahead of now
    # The tests' measure of it: the offsets from whole periods, exact integer ns.
    assert grid_offsets([0, period, 3 * period, 4 * period], period) == {0}
    assert grid_offsets([7, period + 7, 3 * period + 7], period) == {7}
    assert grid_offsets([0, period, 2 * period + 1], period) == {0, 1}


def test_timer_tick_time_stamps_a_timer_callback_exactly_on_its_grid(ros_context):
    # Under a simulated clock that jumps by steps off the timer's grid, the callbacks run at
    # instants off the grid (by a different offset each time) and the clock does not move
    # between the reads in one callback: the ticks are exactly on the grid, to the ns, whatever
    # the machine's load. The callback's own clock reading would not be.
    node = rclpy.create_node(
        'node_tools_tick_test',
        context=ros_context,
        parameter_overrides=[Parameter('use_sim_time', value=True)],
    )
    clock_node = rclpy.create_node('node_tools_tick_clock', context=ros_context)
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(clock_node)
    ticks = []
    try:
        timer = node.create_timer(
            0.1, lambda: ticks.append((timer_tick_time(node, timer), node.get_clock().now()))
        )
        drive_sim_clock(clock_node)
        assert spin_until(executor, lambda: len(ticks) >= 6, timeout=30.0)
        period = timer.timer_period_ns
        nows = [now.nanoseconds for _, now in ticks]
        stamps = [tick.nanoseconds for tick, _ in ticks]
        # The callbacks ran at the simulated instants, off the grid.
        assert all(now % SIM_CLOCK_STEP_NS == 0 for now in nows), nows
        assert len(grid_offsets(nows, period)) > 1, nows
        for tick, now in ticks:
            assert tick.clock_type == now.clock_type
            assert now.nanoseconds - period < tick.nanoseconds <= now.nanoseconds
        assert len(set(stamps)) == len(stamps) and len(grid_offsets(stamps, period)) == 1, stamps
    finally:
        executor.shutdown()
        clock_node.destroy_node()
        node.destroy_node()


@pytest.mark.filterwarnings('ignore:MultiThreadedExecutor is used with a single thread')
def test_shutdown_executor_runs_the_queued_callbacks_before_the_guard_goes(ros_context):
    """A callback queued in a MultiThreadedExecutor's pool when the test shuts it down still runs;
    rclpy's own shutdown destroys the guard condition under it (InvalidHandle, never retrieved)."""
    import threading

    from gsp_testing import shutdown_executor, wait_until
    from rclpy.callback_groups import ReentrantCallbackGroup

    node = rclpy.create_node('shutdown_executor_test', context=ros_context)
    executor = rclpy.executors.MultiThreadedExecutor(num_threads=1, context=ros_context)
    executor.add_node(node)
    group, release, ran = ReentrantCallbackGroup(), threading.Event(), []
    first = node.create_guard_condition(
        lambda: (ran.append('first'), release.wait(30.0)), callback_group=group
    )
    second = node.create_guard_condition(lambda: ran.append('second'), callback_group=group)
    first.trigger()
    assert spin_until(executor, lambda: ran == ['first'], 30.0)  # holds the pool's one thread
    second.trigger()
    executor.spin_once(timeout_sec=30.0)  # hands the second callback to the pool: queued
    pool = executor._executor
    closing = threading.Thread(target=shutdown_executor, args=(executor,))
    closing.start()
    # Release the first callback once the shutdown is under way (rclpy's alone: already done).
    assert wait_until(lambda: pool._shutdown or not closing.is_alive(), 30.0)
    release.set()
    closing.join(30.0)
    try:
        assert ran == ['first', 'second']
    finally:
        node.destroy_node()


#: A node process stopped by a signal of its own, then signalled again during interpreter
#: shutdown (a module global's finaliser), after run_node has finished its cleanup.
LATE_SIGNAL_CHILD = """
import os, signal, sys
from rclpy.node import Node
from gsp_msgs_py import node_tools

class LateSignal:
    def __del__(self):
        os.kill(os.getpid(), signal.{late})

def make_node():
    node = Node('late_signal_child')
    node.create_timer(0.01, lambda: os.kill(os.getpid(), signal.SIGINT))
    return node

late = LateSignal()
sys.exit(node_tools.run_node(make_node, logger_name='late_signal_child'))
"""


@pytest.mark.parametrize('late', ['SIGINT', 'SIGTERM'])
def test_a_signal_after_the_cleanup_is_ignored_and_the_exit_code_stays_0(late):
    # Python restores the default handlers while the interpreter shuts down: a second SIGINT
    # arriving then (two Ctrl-C, ros2 launch) once killed the process (exit code -2).
    import signal
    import subprocess
    import sys

    process = subprocess.run(
        [sys.executable, '-c', LATE_SIGNAL_CHILD.format(late=late)],
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a terminal does
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert process.returncode == 0, process.stderr


#: A node process whose pool callback is still running when a SIGTERM ends the spin: the
#: callback signals its own process, then takes a while; destroy_node says whether it ran first.
SIGNAL_IN_CALLBACK_CHILD = """
import os, signal, sys, threading
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from gsp_msgs_py import node_tools

class Busy(Node):
    def __init__(self):
        super().__init__('signal_in_callback_child')
        self.in_callback = False
        self.timer = self.create_timer(0.01, self.work)

    def work(self):
        self.timer.cancel()
        self.in_callback = True
        os.kill(os.getpid(), signal.SIGTERM)
        threading.Event().wait(0.5)  # the rest of a callback's work after the signal
        self.in_callback = False

    def destroy_node(self):
        print('destroyed during a callback' if self.in_callback else 'destroyed after it')
        super().destroy_node()

sys.exit(node_tools.run_node(Busy, executor=lambda: MultiThreadedExecutor(num_threads=2),
                             logger_name='signal_in_callback_child'))
"""


def test_the_node_is_destroyed_only_after_the_callbacks_running_in_the_pool():
    # rclpy 7.1's executor.shutdown() returns with pool callbacks still running: run_node once
    # destroyed the node under them (a calibrator stopped by SIGTERM then died of SIGSEGV).
    import subprocess
    import sys

    process = subprocess.run(
        [sys.executable, '-c', SIGNAL_IN_CALLBACK_CHILD],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert process.returncode == 0, process.stderr
    assert 'destroyed after it' in process.stdout, process.stdout + process.stderr
