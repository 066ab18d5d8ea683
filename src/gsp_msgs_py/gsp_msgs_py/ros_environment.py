"""The network rule in one place: DDS on loopback, in a ROS domain of this run's own, claimed
through ``domain_coordinator`` (docs/faults.md, "ROS domains")."""

import contextlib
import itertools
import os
import random
import sys
import threading
import time

#: Domain ids drawn by :func:`claim_domain_id` (valid for any participant count on Linux).
DOMAIN_IDS = range(1, 102)
#: Set to the domain id in the environment of the process that claimed it (and so of its
#: children): a given ``ROS_DOMAIN_ID`` equal to it is held by this run, not another.
CLAIMED_VARIABLE = 'GSP_ROS_DOMAIN_CLAIMED'
#: How long :func:`foreign_nodes` watches the graph for nodes (s): discovery on loopback takes
#: tens of ms; this only bounds the look when the domain is empty.
PROBE_WINDOW_S = 0.5
PROBE_NODE_NAME = 'gsp_domain_probe'


class DomainInUseError(RuntimeError):
    """The ROS domain is used by another run, or no domain is free; the message says which."""


#: The claims of this process, held until it exits (never closed: closing frees the ports).
_HELD = contextlib.ExitStack()
_HELD_IDS = set()
_HELD_LOCK = threading.Lock()


def _claim(candidates):
    """Bind the port of the first free domain of ``candidates`` (ids, tried in order); its id,
    or None if every one is taken."""
    import domain_coordinator

    # domain_coordinator tries a selector at most 100 times: chunks of 100, padded with the last.
    for first in range(0, len(candidates), 100):
        chunk = candidates[first : first + 100]
        order = itertools.chain(chunk, itertools.repeat(chunk[-1]))
        with _HELD_LOCK:
            try:
                claim = domain_coordinator.domain_id(lambda order=order: next(order))
                domain_id = _HELD.enter_context(claim)
            except RuntimeError:  # "Failed to get a unique ROS domain ID": all taken
                continue
            _HELD_IDS.add(domain_id)
        return domain_id
    return None


def claim_domain_id(rng=None, exclude=()):
    """Claim a free domain for the life of this process; its id."""
    excluded = set(exclude)
    candidates = [d for d in DOMAIN_IDS if d not in excluded] or list(DOMAIN_IDS)
    start = (rng or random.SystemRandom()).randrange(len(candidates))
    domain_id = _claim(candidates[start:] + candidates[:start])
    if domain_id is None:
        raise DomainInUseError(
            f'no free ROS domain: all of {len(candidates)} candidate(s) are held by other runs; '
            'wait for one to finish'
        )
    return domain_id


def hold_domain_id(domain_id):
    """Claim a domain given in ``ROS_DOMAIN_ID`` for this process; True if newly claimed."""
    domain_id = int(domain_id)
    if domain_id in _HELD_IDS or os.environ.get(CLAIMED_VARIABLE) == str(domain_id):
        return False
    if _claim([domain_id]) is None:
        raise DomainInUseError(
            f'ROS_DOMAIN_ID={domain_id} is in use by another run (domain_coordinator port '
            'taken); unset ROS_DOMAIN_ID to get a free domain, or choose another'
        )
    return True


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
            PROBE_NODE_NAME, context=context, start_parameter_services=False, enable_rosout=False
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
    """A copy of ``environ`` (default ``os.environ``) with discovery kept on loopback."""
    env = dict(os.environ if environ is None else environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if not env.get('ROS_DOMAIN_ID', '').strip():
        env['ROS_DOMAIN_ID'] = env[CLAIMED_VARIABLE] = str(claim_domain_id(rng, exclude))
    return env


def enter_private_domain(probe=foreign_nodes, rng=None):
    """Put this process (``os.environ``) on loopback in a ROS domain of its own; its domain id."""
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
        os.environ[CLAIMED_VARIABLE] = str(domain_id)
        return domain_id
    occupied = []  # claimed but not empty: kept claimed, so no one else draws them either
    while True:
        domain_id = claim_domain_id(rng, exclude=occupied)
        if not (probe and probe(domain_id)):
            os.environ['ROS_DOMAIN_ID'] = os.environ[CLAIMED_VARIABLE] = str(domain_id)
            return domain_id
        occupied.append(domain_id)
        if len(occupied) >= len(DOMAIN_IDS):
            raise DomainInUseError('no free ROS domain: every domain has nodes of other runs')


USAGE = 'usage: python -m gsp_msgs_py.ros_environment probe DOMAIN_ID\n'


def main(argv=None):
    """``probe DOMAIN_ID``: print the nodes present in the domain (:func:`foreign_nodes`)."""
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) == 2 and argv[0] == 'probe' and argv[1].isdigit():
        try:
            for name in foreign_nodes(int(argv[1])):
                sys.stdout.write(f'{name}\n')
        except (OSError, ValueError) as error:
            sys.stderr.write(f'ros_environment: {error}\n')
            return 1
        return 0
    sys.stderr.write(USAGE)
    return 2


if __name__ == '__main__':
    raise SystemExit(main())
