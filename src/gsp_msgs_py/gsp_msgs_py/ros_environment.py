"""The network rule in one place: DDS on loopback, in a private ROS domain (no rclpy needed).

Every test, demo and benchmark process runs with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and
its own ``ROS_DOMAIN_ID``, so discovery never reaches another interface or another run.

A drawn domain is **claimed by a lock** (docs/faults.md, "ROS domains"): an exclusive
``flock`` on ``<tmp>/gsp-ros-domains/domain-<id>.lock``, held until the claiming process exits
(the kernel releases it even after a SIGKILL). Concurrent runs on one machine therefore never
draw the same domain: a locked domain is skipped for the next free one. A domain given in
``ROS_DOMAIN_ID`` is checked against the locks of other runs (:func:`hold_domain_id`), and
:func:`foreign_nodes` looks for nodes already present in a domain (rclpy, imported lazily).

Run as a script (system Python is enough) it claims a domain for a shell: ``python
ros_environment.py claim --owner <pid>`` prints a free domain id and leaves a small process
holding its lock until process ``<pid>`` exits (``scripts/env.sh`` uses it). ``probe <id>``
prints the nodes present in a domain (rclpy needed).
"""

import errno
import fcntl
import os
import random
import select
import sys
import tempfile
import threading
import time
from pathlib import Path

#: Domain ids claimed by :func:`claim_domain_id` (valid for any participant count on Linux).
DOMAIN_IDS = range(1, 102)
#: Environment variable naming the lock directory (default: ``<tmp>/gsp-ros-domains``).
LOCK_DIRECTORY_VARIABLE = 'GSP_ROS_DOMAIN_LOCK_DIR'
#: How long :func:`foreign_nodes` watches the graph for nodes (s): discovery on loopback takes
#: tens of ms; this only bounds the look when the domain is empty.
PROBE_WINDOW_S = 0.5
PROBE_NODE_NAME = 'gsp_domain_probe'


class DomainInUseError(RuntimeError):
    """The ROS domain is used by another run, or no domain is free; the message says which."""


def lock_directory():
    """The shared directory of the domain locks (``$GSP_ROS_DOMAIN_LOCK_DIR`` if set)."""
    given = os.environ.get(LOCK_DIRECTORY_VARIABLE, '').strip()
    return Path(given) if given else Path(tempfile.gettempdir()) / 'gsp-ros-domains'


def lock_path(domain_id, directory=None):
    return Path(directory or lock_directory()) / f'domain-{int(domain_id)}.lock'


class DomainLock:
    """An exclusive lock on one domain, held by this process until :meth:`release` or exit."""

    def __init__(self, domain_id, path, fd):
        self.domain_id = int(domain_id)
        self.path = Path(path)
        self._fd = fd

    @property
    def held(self):
        return self._fd is not None

    def fileno(self):
        return self._fd

    def release(self):
        """Give the domain back (closing the file releases the lock)."""
        if self._fd is not None:
            _HELD.pop(str(self.path), None)
            os.close(self._fd)
            self._fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()

    def __repr__(self):
        return f'DomainLock({self.domain_id}, {str(self.path)!r}, held={self.held})'


#: Locks this process holds, by lock file: kept referenced so they last as long as the process.
_HELD = {}
_HELD_LOCK = threading.Lock()


def _open_lock_file(path):
    directory = path.parent
    if not directory.is_dir():
        try:
            directory.mkdir(parents=True)
            os.chmod(directory, 0o1777)  # shared by every user of the machine, like /tmp
        except FileExistsError:
            pass
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        if os.fstat(fd).st_uid == os.getuid():
            os.fchmod(fd, 0o666)  # any user may lock it (never written by them otherwise)
    except OSError:
        pass
    return fd


def _try_lock(domain_id, directory=None, owner_pid=None):
    """A :class:`DomainLock` on ``domain_id`` if nobody holds it, else None. The file records
    ``owner_pid`` (default this process; the process whose descendants share the domain)."""
    path = lock_path(domain_id, directory)
    try:
        fd = _open_lock_file(path)
    except OSError:
        return None  # not ours to use (another user's file, a read-only directory)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as error:
        os.close(fd)
        if error.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return None
        raise
    owner = os.getpid() if owner_pid is None else int(owner_pid)
    record = f'{owner} {os.getpid()} {_command_line(owner)}\n'.encode()
    os.ftruncate(fd, 0)
    os.pwrite(fd, record, 0)
    lock = DomainLock(domain_id, path, fd)
    with _HELD_LOCK:
        _HELD[str(path)] = lock
    return lock


def _command_line(pid):
    try:
        raw = Path(f'/proc/{pid}/cmdline').read_bytes()
    except OSError:
        return '?'
    return ' '.join(part.decode(errors='replace') for part in raw.split(b'\0') if part)[:200]


def ancestors(pid=None):
    """This process (or ``pid``) and its ancestors, nearest first (Linux /proc; elsewhere only
    this process and its parent)."""
    pid = os.getpid() if pid is None else int(pid)
    chain = [pid]
    while pid > 1:
        try:
            stat = Path(f'/proc/{pid}/stat').read_text()
            pid = int(stat.rsplit(')', 1)[1].split()[1])  # field 4, after the command name
        except (OSError, IndexError, ValueError):
            if pid == os.getpid():
                chain.append(os.getppid())
            break
        chain.append(pid)
    return chain


def domain_holder(domain_id, directory=None):
    """Who holds the lock of ``domain_id``: None if nobody, else ``(owner pid, description)``
    as recorded by the holder (pid 0 if the record is not written yet)."""
    path = lock_path(domain_id, directory)
    if not path.exists():
        return None
    with _HELD_LOCK:
        if str(path) in _HELD:
            return os.getpid(), f'this process ({_command_line(os.getpid())})'
    probe = _try_lock(domain_id, directory)
    if probe is not None:
        probe.release()
        return None
    try:
        fields = path.read_text().split(' ', 2)
        return int(fields[0]), fields[2].strip() if len(fields) > 2 else '?'
    except (OSError, ValueError, IndexError):
        return 0, 'a process that is claiming it now'


def claim_domain_id(rng=None, exclude=(), directory=None, owner_pid=None):
    """Lock a free domain and return its :class:`DomainLock` (held until exit or release).

    Starts at a random candidate (``rng``: a ``random.Random``) and takes the next free one in
    :data:`DOMAIN_IDS` order (wrapping), skipping ``exclude`` unless that leaves none.
    :class:`DomainInUseError` if every candidate is locked by another run.
    """
    excluded = set(exclude)
    candidates = [d for d in DOMAIN_IDS if d not in excluded] or list(DOMAIN_IDS)
    start = (rng or random.SystemRandom()).randrange(len(candidates))
    for domain_id in candidates[start:] + candidates[:start]:
        lock = _try_lock(domain_id, directory, owner_pid)
        if lock is not None:
            return lock
    raise DomainInUseError(
        f'no free ROS domain: all of {len(candidates)} candidate(s) are locked by other runs '
        f'(lock files in {directory or lock_directory()}); wait for one to finish'
    )


def hold_domain_id(domain_id, directory=None):
    """Check a domain given in ``ROS_DOMAIN_ID`` and lock it for this process.

    Returns the new :class:`DomainLock`, or None if this process or one of its ancestors
    (the run that chose it, e.g. ``make`` or a shell that sourced ``scripts/env.sh``) already
    holds it. :class:`DomainInUseError` naming the holder if another run holds it.
    """
    domain_id = int(domain_id)
    with _HELD_LOCK:
        if str(lock_path(domain_id, directory)) in _HELD:
            return None
    lock = _try_lock(domain_id, directory)
    if lock is not None:
        return lock
    holder = domain_holder(domain_id, directory)
    if holder is None:  # released meanwhile
        return _try_lock(domain_id, directory)
    owner, description = holder
    if owner and owner in ancestors():
        return None
    raise DomainInUseError(
        f'ROS_DOMAIN_ID={domain_id} is in use by another run (pid {owner or "?"}: {description}); '
        'unset ROS_DOMAIN_ID to get a free domain, or choose another'
    )


def foreign_nodes(domain_id, window_s=PROBE_WINDOW_S):
    """Fully qualified names of the nodes already in ``domain_id``, seen by a short-lived probe
    node over ``window_s`` (ends as soon as one is seen). Needs rclpy and loopback discovery."""
    if os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') != 'LOCALHOST':
        raise ValueError('set ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST before probing a domain')
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(domain_id))
    found = set()
    try:
        node = rclpy.create_node(
            PROBE_NODE_NAME,
            context=context,
            start_parameter_services=False,
            enable_rosout=False,
        )
        pause = threading.Event()
        deadline = time.monotonic() + window_s
        while not found and time.monotonic() < deadline:
            for name, namespace in node.get_node_names_and_namespaces():
                if name != PROBE_NODE_NAME:
                    found.add(f'{namespace.rstrip("/")}/{name}')
            pause.wait(0.02)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return sorted(found)


def foreign_nodes_in_child(domain_id, window_s=PROBE_WINDOW_S):
    """:func:`foreign_nodes` run in a child process (``python -m gsp_msgs_py.ros_environment
    probe``), for a parent that must not start DDS threads yet (it forks its nodes later)."""
    import subprocess

    completed = subprocess.run(
        [sys.executable, '-m', 'gsp_msgs_py.ros_environment', 'probe', str(int(domain_id))],
        env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST'),
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=60.0 + window_s,
    )
    if completed.returncode != 0:
        raise DomainInUseError(
            f'cannot look for nodes in ROS domain {domain_id}: {completed.stderr.strip()}'
        )
    return completed.stdout.split()


def loopback_environment(environ=None, rng=None, exclude=()):
    """A copy of ``environ`` (default ``os.environ``) with discovery kept on loopback.

    An existing non-empty ``ROS_DOMAIN_ID`` is kept (not checked: see :func:`enter_private_domain`);
    otherwise a free one is claimed (:func:`claim_domain_id`, locked for this process's life, so
    that its children share it and no concurrent run draws it).
    """
    env = dict(os.environ if environ is None else environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if not env.get('ROS_DOMAIN_ID', '').strip():
        env['ROS_DOMAIN_ID'] = str(claim_domain_id(rng, exclude).domain_id)
    return env


def enter_private_domain(probe=foreign_nodes, rng=None):
    """Put this process (``os.environ``) on loopback in a ROS domain of its own; its domain id.

    Without ``ROS_DOMAIN_ID`` a free domain is claimed; one where ``probe(domain_id)`` (default
    :func:`foreign_nodes`; None: no look) sees nodes already (a run that does not take the
    locks) is left for the next. A given ``ROS_DOMAIN_ID`` is kept, locked by
    :func:`hold_domain_id` (:class:`DomainInUseError` if another run holds it) and must have no
    nodes yet.
    """
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    given = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if given:
        try:
            domain_id = int(given)
        except ValueError:
            raise DomainInUseError(f'ROS_DOMAIN_ID={given!r} is not a domain id') from None
        hold_domain_id(domain_id)
        present = probe(domain_id) if probe else []
        if present:
            raise DomainInUseError(
                f'ROS_DOMAIN_ID={domain_id} already has nodes of another run: '
                f'{", ".join(present)}; stop them, unset ROS_DOMAIN_ID to get a free domain, '
                'or choose another'
            )
        return domain_id
    occupied = []  # claimed but not empty: kept locked, so no one else draws them either
    while True:
        lock = claim_domain_id(rng, exclude=[d.domain_id for d in occupied])
        if not (probe and probe(lock.domain_id)):
            os.environ['ROS_DOMAIN_ID'] = str(lock.domain_id)
            return lock.domain_id
        occupied.append(lock)
        if len(occupied) >= len(DOMAIN_IDS):
            raise DomainInUseError('no free ROS domain: every domain has nodes of other runs')


# --- a domain for a shell ----------------------------------------------------------------------


def _wait_for_exit(pid):
    """Return once process ``pid`` has exited (pidfd on Linux >= 5.3, else polled)."""
    try:
        pidfd = os.pidfd_open(pid)
    except (AttributeError, OSError) as error:
        if isinstance(error, OSError) and error.errno == errno.ESRCH:
            return
        pause = threading.Event()
        while True:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return
            except PermissionError:
                pass
            pause.wait(1.0)
    poller = select.poll()
    poller.register(pidfd, select.POLLIN)
    while not poller.poll():
        pass
    os.close(pidfd)


def _claim_for(owner_pid):
    """Claim a domain, print it, and leave a detached child holding the lock until ``owner_pid``
    exits (the child shares the lock's open file, so the lock outlives this process)."""
    lock = claim_domain_id(owner_pid=owner_pid)
    sys.stdout.write(f'{lock.domain_id}\n')
    sys.stdout.flush()
    if os.fork() == 0:
        try:
            os.setsid()  # a Ctrl-C in the shell's terminal does not reach the holder
            os.chdir('/')
            devnull = os.open(os.devnull, os.O_RDWR)
            for fd in (0, 1, 2):  # the shell's $(...) ends once stdout is closed
                os.dup2(devnull, fd)
            # Nothing else the shell had open (pipes others wait on) stays open here.
            os.closerange(3, lock.fileno())
            os.closerange(lock.fileno() + 1, os.sysconf('SC_OPEN_MAX'))
            _wait_for_exit(owner_pid)
        finally:
            os._exit(0)
    return 0


USAGE = 'usage: ros_environment.py claim --owner PID | probe DOMAIN_ID\n'


def main(argv=None):
    """``claim --owner PID``: print a free domain id, locked until process PID exits.
    ``probe DOMAIN_ID``: print the nodes present in the domain (:func:`foreign_nodes`)."""
    argv = sys.argv[1:] if argv is None else argv
    try:
        if len(argv) == 3 and argv[:2] == ['claim', '--owner'] and argv[2].isdigit():
            return _claim_for(int(argv[2]))
        if len(argv) == 2 and argv[0] == 'probe' and argv[1].isdigit():
            for name in foreign_nodes(int(argv[1])):
                sys.stdout.write(f'{name}\n')
            return 0
    except (DomainInUseError, OSError, ValueError) as error:
        sys.stderr.write(f'ros_environment: {error}\n')
        return 1
    sys.stderr.write(USAGE)
    return 2


if __name__ == '__main__':
    raise SystemExit(main())
