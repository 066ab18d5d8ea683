"""Domain ids claimed through domain_coordinator, checked when given, and probed for foreign
nodes (gsp_msgs_py.ros_environment; docs/faults.md "ROS domains").

The claims are machine-wide (a bound port per domain), so the tests draw from all domains and
assert only what holds beside concurrent runs; waits are on events (a child's output or exit).
"""

import os
import random
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import domain_coordinator.impl
import pytest

from gsp_msgs_py import ros_environment
from gsp_msgs_py.ros_environment import (
    CLAIMED_VARIABLE,
    DOMAIN_IDS,
    DomainInUseError,
    claim_domain_id,
    enter_private_domain,
    foreign_nodes,
    hold_domain_id,
    loopback_environment,
)

TIMEOUT_S = 30.0  #: bounds a failure only
WS = Path(__file__).resolve().parents[3]
SOURCE = str(Path(ros_environment.__file__).resolve().parents[1])  #: for the children's sys.path
#: A child that claims a domain (same rng seed as the others: the same first candidate), prints
#: it and holds it until its stdin closes.
CLAIMER = (
    'import random, sys\n'
    f'sys.path.insert(0, {SOURCE!r})\n'
    'from gsp_msgs_py import ros_environment as r\n'
    'print(r.claim_domain_id(random.Random(0)), flush=True)\n'
    'sys.stdin.read()\n'
)


def is_claimed(domain_id):
    """Whether some process holds ``domain_id``'s domain_coordinator port."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        probe.bind(('', domain_coordinator.impl.PORT_BASE + domain_id))
    except OSError:
        return True
    finally:
        probe.close()
    return False


def start_claimer():
    child = subprocess.Popen(
        [sys.executable, '-c', CLAIMER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    return child, int(child.stdout.readline())


def wait_until(predicate, what):
    pause, deadline = threading.Event(), time.monotonic() + TIMEOUT_S
    while not predicate():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        pause.wait(0.02)


def test_concurrent_claims_get_distinct_domains_and_release_on_exit():
    # Two processes with the same first candidate: the second skips the held one.
    first, first_domain = start_claimer()
    second, second_domain = start_claimer()
    try:
        assert first_domain != second_domain
        assert is_claimed(first_domain) and is_claimed(second_domain)
    finally:
        for child in (first, second):
            child.stdin.close()
            child.wait(timeout=TIMEOUT_S)
    # The kernel freed the ports with the processes, even after a SIGKILL.
    killed, killed_domain = start_claimer()
    killed.kill()
    killed.wait(timeout=TIMEOUT_S)
    for domain_id in (first_domain, second_domain, killed_domain):
        hold_domain_id(domain_id)  # DomainInUseError if still held (or taken by another run)


def test_concurrent_claims_in_threads_get_distinct_domains():
    barrier = threading.Barrier(8)
    claimed = []

    def claim():
        barrier.wait()
        claimed.append(claim_domain_id(random.Random(0)))

    threads = [threading.Thread(target=claim) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=TIMEOUT_S)
    assert len(set(claimed)) == 8 and all(is_claimed(d) for d in claimed)


def test_a_held_domain_is_skipped_and_exclusions_respected():
    held = claim_domain_id(random.Random(3))
    assert claim_domain_id(random.Random(3)) != held
    others = claim_domain_id(exclude=[d for d in DOMAIN_IDS if d < 51])
    assert others >= 51
    with pytest.raises(DomainInUseError, match='no free ROS domain'):
        claim_domain_id(exclude=[d for d in DOMAIN_IDS if d != others])  # only ours is left


def test_a_given_domain_is_checked_against_other_runs(monkeypatch):
    monkeypatch.delenv(CLAIMED_VARIABLE, raising=False)
    other, domain_id = start_claimer()
    try:
        with pytest.raises(DomainInUseError, match=rf'ROS_DOMAIN_ID={domain_id} is in use'):
            hold_domain_id(domain_id)
        # The run that claimed it says so to its children: they share the domain.
        monkeypatch.setenv(CLAIMED_VARIABLE, str(domain_id))
        assert hold_domain_id(domain_id) is False
        monkeypatch.delenv(CLAIMED_VARIABLE)
    finally:
        other.stdin.close()
        other.wait(timeout=TIMEOUT_S)
    assert hold_domain_id(domain_id) is True  # free now: held by this process
    assert hold_domain_id(domain_id) is False


def test_claim_for_a_shell_holds_until_the_owner_exits():
    script = str(WS / 'scripts' / 'claim-ros-domain')
    owner = subprocess.Popen(
        [sys.executable, '-c', 'import sys; sys.stdin.read()'], stdin=subprocess.PIPE
    )
    try:
        claimed = subprocess.run(
            [sys.executable, script, '--owner', str(owner.pid)],
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
        )
        assert claimed.returncode == 0, claimed.stderr
        domain_id = int(claimed.stdout)
        assert is_claimed(domain_id)  # the claiming process has exited; its holder keeps it
    finally:
        owner.stdin.close()
        owner.wait(timeout=TIMEOUT_S)
    wait_until(lambda: not is_claimed(domain_id), 'the holder to let go')
    usage = subprocess.run([sys.executable, script, 'claim'], capture_output=True, text=True)
    assert usage.returncode == 2 and 'usage' in usage.stderr


def test_enter_private_domain_leaves_domains_with_nodes(monkeypatch):
    monkeypatch.delenv('ROS_DOMAIN_ID', raising=False)
    monkeypatch.delenv(CLAIMED_VARIABLE, raising=False)
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET')
    probed = []

    def probe(domain_id):  # the first domain looked at is busy
        probed.append(domain_id)
        return ['/somebody_else'] if len(probed) == 1 else []

    domain_id = enter_private_domain(probe=probe, rng=random.Random(5))
    assert probed[-1] == domain_id != probed[0]
    assert os.environ['ROS_DOMAIN_ID'] == os.environ[CLAIMED_VARIABLE] == str(domain_id)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert is_claimed(probed[0])  # kept, so nobody else draws it

    # A given domain with nodes in it is refused, naming them; an empty one is kept.
    given = claim_domain_id()  # free for the test; held by this process
    monkeypatch.setenv('ROS_DOMAIN_ID', str(given))
    with pytest.raises(DomainInUseError, match='/somebody_else'):
        enter_private_domain(probe=lambda d: ['/somebody_else'])
    assert enter_private_domain(probe=lambda d: []) == given
    monkeypatch.setenv('ROS_DOMAIN_ID', 'x')
    with pytest.raises(DomainInUseError, match='not a domain id'):
        enter_private_domain(probe=None)


def test_loopback_environment_claims_a_domain_unless_given():
    env = loopback_environment({'PATH': '/bin'}, rng=random.Random(1))
    domain_id = int(env['ROS_DOMAIN_ID'])
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST' and domain_id in DOMAIN_IDS
    assert env[CLAIMED_VARIABLE] == str(domain_id) and is_claimed(domain_id)
    assert loopback_environment({'ROS_DOMAIN_ID': '9'})['ROS_DOMAIN_ID'] == '9'


def test_foreign_nodes_sees_a_node_of_the_domain(ros_context):
    import rclpy

    domain_id = int(os.environ['ROS_DOMAIN_ID'])  # this session's own
    node = rclpy.create_node('someone_else', namespace='/lab', context=ros_context)
    try:
        found = []
        wait_until(lambda: found.extend(foreign_nodes(domain_id)) or found, 'the node')
        assert found == ['/lab/someone_else']
    finally:
        node.destroy_node()
