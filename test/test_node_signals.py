"""Every node, as a real process, survives two stop signals sent back to back (docs/faults.md).

Under ``ros2 launch`` each node gets SIGINT twice (the terminal's process group, then launch);
a user may send SIGTERM and then SIGINT. Each node must finish its cleanup and exit 0 (or the
conventional 130/143) with no traceback, whatever the pair. Each node is started with
``python -m`` and default SIGINT handling (a process started from a non-interactive shell has
SIGINT ignored), signalled once its start-up log line is out, and waited for.

The three pairs of one node run as three processes at once (each with files of its own): the
start-up (imports, rclpy) is most of the time, and the processes only share the domain, where
nothing commands them.
"""

import os
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest

from gsp_calibrator.files.run_directory import Rows, write_samples

TIMEOUT_S = 60.0  #: bounds a failure only (start-up on a loaded machine)
PAIRS = {
    'SIGINT+SIGINT': (signal.SIGINT, signal.SIGINT),
    'SIGTERM+SIGINT': (signal.SIGTERM, signal.SIGINT),
    'SIGINT+SIGTERM': (signal.SIGINT, signal.SIGTERM),
}
CLEAN_EXIT_CODES = (0, 128 + signal.SIGINT, 128 + signal.SIGTERM)
#: What an unclean exit prints (a Python traceback, an exception in a finaliser, std::terminate).
UNCLEAN = ('Traceback', 'Exception ignored', 'terminate called', 'KeyboardInterrupt')


def replayable_run(directory):
    """A run directory with a one-posture samples.csv (what the replay node needs)."""
    samples = Rows.empty()
    samples.append(1, [0.0, 0.0, 1.0, 0.0, 0.0, 0.0], np.full(6, 1.2), np.zeros(4), 5, 0.0)
    directory.mkdir()
    write_samples(directory / 'samples.csv', samples)
    return directory


def node_commands(tmp_path):
    """``{name: argv}`` of every node of the suite, each with what it needs to start."""
    python = [sys.executable, '-m']
    return {
        'platform_sim': python + ['gsp_platform_sim.platform_sim_node'],
        'controller_sim': python + ['gsp_platform_sim.controller_sim_node'],
        'device_driver': python + ['gsp_device_driver.device_driver_node'],
        'gsp_fake_device': python
        + ['gsp_device_driver.fake_device_node', '--port', str(tmp_path / 'device')],
        'platform_bridge': python + ['gsp_platform_bridge.platform_bridge_node'],
        'calibrator': python
        + [
            'gsp_calibrator.node.calibrator_node',
            '--ros-args',
            '-p',
            f'output_root:={tmp_path / "runs"}',
        ],
        'replay': python
        + [
            'gsp_calibrator.replay.replay_node',
            '--ros-args',
            '-p',
            f'run:={replayable_run(tmp_path / "recorded")}',
        ],
    }


#: Popen options: no stdin, stdout and stderr merged into one text pipe.
MERGED_TEXT = dict(
    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
)


def _default_sigint():
    """In the child before exec: SIGINT as an interactive shell leaves it (not ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class NodeProcess:
    """A node process whose merged output is read by a thread; :attr:`started` is set at its
    first log line (the node logs once it is built)."""

    def __init__(self, argv):
        env = dict(os.environ, RCUTILS_LOGGING_BUFFERED_STREAM='0', PYTHONUNBUFFERED='1')
        self.process = subprocess.Popen(argv, env=env, preexec_fn=_default_sigint, **MERGED_TEXT)
        self.lines = []
        self.started = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line)
            if '[INFO]' in line:
                self.started.set()
        self.started.set()  # end of output: the process is gone (the test says why)

    def output(self):
        self._reader.join(timeout=TIMEOUT_S)
        return ''.join(self.lines)

    def kill(self):
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


@pytest.mark.parametrize(
    'name',
    [
        'platform_sim',
        'controller_sim',
        'device_driver',
        'gsp_fake_device',
        'platform_bridge',
        'calibrator',
        'replay',
    ],
)
def test_a_node_survives_two_signals_back_to_back(tmp_path, name):
    nodes = {}
    codes = {}
    try:
        for pair in PAIRS:
            directory = tmp_path / pair
            directory.mkdir()
            nodes[pair] = NodeProcess(node_commands(directory)[name])
        for pair, node in nodes.items():
            assert node.started.wait(TIMEOUT_S), f'{name} did not start ({pair})'
            assert node.process.poll() is None, f'{name} exited at start ({pair}):\n{node.output()}'
        for pair, node in nodes.items():
            for number in PAIRS[pair]:
                node.process.send_signal(number)
        for pair, node in nodes.items():
            codes[pair] = node.process.wait(timeout=TIMEOUT_S)
    finally:
        for node in nodes.values():
            node.kill()
    for pair, node in nodes.items():
        output = node.output()
        assert codes[pair] in CLEAN_EXIT_CODES, (
            f'{name} exited {codes[pair]} after {pair}:\n{output}'
        )
        for word in UNCLEAN:
            assert word not in output, f'{name} printed {word!r} after {pair}:\n{output}'
