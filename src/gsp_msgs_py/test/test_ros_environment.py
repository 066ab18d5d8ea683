"""Domain ids claimed by lock, checked when given, and probed for foreign nodes
(gsp_msgs_py.ros_environment; docs/faults.md "ROS domains").

Every test uses a private lock directory (``GSP_ROS_DOMAIN_LOCK_DIR``), so it neither sees nor
disturbs the locks of concurrent runs; waits are on events (a child's output or exit).
"""

import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from gsp_msgs_py import ros_environment
from gsp_msgs_py.ros_environment import (
    DOMAIN_IDS,
    LOCK_DIRECTORY_VARIABLE,
    DomainInUseError,
    claim_domain_id,
    domain_holder,
    enter_private_domain,
    foreign_nodes,
    hold_domain_id,
    loopback_environment,
)

TIMEOUT_S = 30.0  #: bounds a failure only
SOURCE = str(Path(ros_environment.__file__).resolve().parents[1])  #: for the children's sys.path
#: A child that claims a domain (same rng seed as the others: the same first candidate), prints
#: it and holds it until its stdin closes.
CLAIMER = (
    'import random, sys\n'
    f'sys.path.insert(0, {SOURCE!r})\n'
    'from gsp_msgs_py import ros_environment as r\n'
    'print(r.claim_domain_id(random.Random(0)).domain_id, flush=True)\n'
    'sys.stdin.read()\n'
)


@pytest.fixture
def lock_dir(tmp_path, monkeypatch):
    directory = tmp_path / 'locks'
    monkeypatch.setenv(LOCK_DIRECTORY_VARIABLE, str(directory))
    return directory


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


def test_concurrent_claims_get_distinct_domains_and_release_on_exit(lock_dir):
    # Two processes with the same first candidate: the second skips the held one for the next.
    first, first_domain = start_claimer()
    second, second_domain = start_claimer()
    try:
        assert first_domain != second_domain
        assert second_domain == first_domain % max(DOMAIN_IDS) + 1
        assert domain_holder(first_domain)[0] == first.pid
        assert domain_holder(second_domain)[0] == second.pid
    finally:
        for child in (first, second):
            child.stdin.close()
            child.wait(timeout=TIMEOUT_S)
    # The kernel released the locks with the processes: the domains are free again.
    assert domain_holder(first_domain) is None
    assert domain_holder(second_domain) is None
    killed, killed_domain = start_claimer()
    killed.kill()
    killed.wait(timeout=TIMEOUT_S)
    assert domain_holder(killed_domain) is None  # even after a SIGKILL


def test_concurrent_claims_in_threads_get_distinct_domains(lock_dir):
    barrier = threading.Barrier(8)
    locks = []

    def claim():
        barrier.wait()
        locks.append(claim_domain_id(random.Random(0)))

    threads = [threading.Thread(target=claim) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=TIMEOUT_S)
    try:
        assert len({lock.domain_id for lock in locks}) == 8
    finally:
        for lock in locks:
            lock.release()


def test_a_held_domain_is_skipped_and_exclusions_respected(lock_dir):
    with claim_domain_id(random.Random(3)) as held:
        with claim_domain_id(random.Random(3)) as next_one:
            assert next_one.domain_id != held.domain_id
        only = claim_domain_id(exclude=[d for d in DOMAIN_IDS if d != 50])
        assert only.domain_id == 50
        with pytest.raises(DomainInUseError, match='no free ROS domain'):
            claim_domain_id(exclude=[d for d in DOMAIN_IDS if d != 50])
        only.release()
    assert domain_holder(held.domain_id) is None and not held.held


def test_a_given_domain_is_checked_against_other_runs(lock_dir):
    other, domain_id = start_claimer()
    try:
        with pytest.raises(DomainInUseError, match=rf'ROS_DOMAIN_ID={domain_id} .*pid'):
            hold_domain_id(domain_id)
    finally:
        other.stdin.close()
        other.wait(timeout=TIMEOUT_S)
    lock = hold_domain_id(domain_id)  # free now: held by this process
    try:
        assert lock.domain_id == domain_id and hold_domain_id(domain_id) is None
        # A child of the holder shares the domain (it is the same run).
        code = (
            f'import sys; sys.path.insert(0, {SOURCE!r})\n'
            'from gsp_msgs_py import ros_environment as r\n'
            f'print(r.hold_domain_id({domain_id}))'
        )
        child = subprocess.run(
            [sys.executable, '-c', code], capture_output=True, text=True, timeout=TIMEOUT_S
        )
        assert child.stdout.strip() == 'None', child.stderr
    finally:
        lock.release()


def test_claim_for_a_shell_holds_until_the_owner_exits(lock_dir):
    owner = subprocess.Popen(
        [sys.executable, '-c', 'import sys; sys.stdin.read()'], stdin=subprocess.PIPE
    )
    try:
        claimed = subprocess.run(
            [sys.executable, ros_environment.__file__, 'claim', '--owner', str(owner.pid)],
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
        )
        assert claimed.returncode == 0, claimed.stderr
        domain_id = int(claimed.stdout)
        # The claiming process has exited; its holder keeps the lock for the owner.
        assert domain_holder(domain_id)[0] == owner.pid
    finally:
        owner.stdin.close()
        owner.wait(timeout=TIMEOUT_S)
    wait_until(lambda: domain_holder(domain_id) is None, 'the holder to let go')
    usage = subprocess.run(
        [sys.executable, ros_environment.__file__, 'claim'], capture_output=True, text=True
    )
    assert usage.returncode == 2 and 'usage' in usage.stderr


def test_enter_private_domain_leaves_domains_with_nodes(lock_dir, monkeypatch):
    monkeypatch.delenv('ROS_DOMAIN_ID', raising=False)
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET')
    probed = []

    def probe(domain_id):  # the first domain looked at is busy
        probed.append(domain_id)
        return ['/somebody_else'] if len(probed) == 1 else []

    domain_id = enter_private_domain(probe=probe, rng=random.Random(5))
    assert probed[-1] == domain_id != probed[0]
    assert os.environ['ROS_DOMAIN_ID'] == str(domain_id)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert domain_holder(probed[0])[0] == os.getpid()  # kept, so nobody else draws it

    # A given domain with nodes in it is refused, naming them; an empty one is kept.
    monkeypatch.setenv('ROS_DOMAIN_ID', '77')
    with pytest.raises(DomainInUseError, match='/somebody_else'):
        enter_private_domain(probe=lambda d: ['/somebody_else'])
    assert enter_private_domain(probe=lambda d: []) == 77
    monkeypatch.setenv('ROS_DOMAIN_ID', 'x')
    with pytest.raises(DomainInUseError, match='not a domain id'):
        enter_private_domain(probe=None)


def test_loopback_environment_claims_a_domain_unless_given(lock_dir):
    env = loopback_environment({'PATH': '/bin'}, rng=random.Random(1))
    domain_id = int(env['ROS_DOMAIN_ID'])
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST' and domain_id in DOMAIN_IDS
    assert domain_holder(domain_id)[0] == os.getpid()
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
