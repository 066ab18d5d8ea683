"""The suite's nodes as child processes of a job (``gsp_demo``): start, watch, stop."""

import contextlib
import ctypes
import signal
import subprocess
import sys
import time
from pathlib import Path

SHUTDOWN_GRACE_S = 5.0  #: wait after SIGINT before SIGTERM, and after SIGTERM before SIGKILL


# Loaded in the parent: the child must not dlopen between fork and exec.
_LIBC = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith('linux') else None
_PR_SET_PDEATHSIG = 1


def _die_with_parent():
    """In the child before exec: get SIGTERM if the demo dies, even by SIGKILL (Linux)."""
    _LIBC.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)


class DemoError(RuntimeError):
    """The demo cannot go on; the message says why."""


class NodeExited(DemoError):
    """A node process has exited; the message names it and ends with its log."""


class NodeProcesses:
    """The nodes as child processes; :meth:`stop` ends all of them (idempotent)."""

    def __init__(self, commands, env, log_directory):
        self.commands = commands
        self.env = env
        self.log_directory = Path(log_directory)
        self.processes = {}
        self._logs = {}

    def start(self, names=None):
        """Start ``names`` (default: every command); a restarted node appends to its log."""
        for name in self.commands if names is None else names:
            argv = self.commands[name]
            if name in self._logs:
                self._logs[name].close()
            log = open(self.log_directory / f'{name}.log', 'ab')  # closed in stop()
            self._logs[name] = log
            self.processes[name] = subprocess.Popen(
                argv,
                env=self.env,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=_die_with_parent if _LIBC is not None else None,
            )

    def exited(self):
        """``(name, exit code)`` of a process that has exited, or None while all run."""
        for name, process in self.processes.items():
            code = process.poll()
            if code is not None:
                return name, code
        return None

    def log_tail(self, name, lines=15):
        path = self.log_directory / f'{name}.log'
        try:
            text = path.read_text(errors='replace')
        except OSError:
            return ''
        return '\n'.join(f'  | {line}' for line in text.splitlines()[-lines:])

    def _signal_all(self, sig):
        for process in self.processes.values():
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    process.send_signal(sig)

    def _wait_all(self, timeout):
        deadline = time.monotonic() + timeout
        for process in self.processes.values():
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=max(0.0, deadline - time.monotonic()))
        return all(p.poll() is not None for p in self.processes.values())

    def stop(self, grace=SHUTDOWN_GRACE_S):
        """SIGINT, wait; SIGTERM, wait; SIGKILL. Returns ``{name: exit code}``."""
        if not self._wait_all(0.0):
            self._signal_all(signal.SIGINT)
            if not self._wait_all(grace):
                self._signal_all(signal.SIGTERM)
                if not self._wait_all(grace):
                    self._signal_all(signal.SIGKILL)
                    self._wait_all(grace)
        for log in self._logs.values():
            log.close()
        return {name: p.returncode for name, p in self.processes.items()}
