"""Faults with real processes: the nodes run as separate processes, killed by pid at chosen
moments (a posture count in state.json), and the run is resumed (docs/faults.md).

Every wait is on an event (a file's content, a service response, a process exit), bounded by a
generous timeout that only limits a failure.
"""

import contextlib
import json
import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest
from gsp_testing import SpinThread
from scipy import stats
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from gsp_calibrator.collection import topics
from gsp_calibrator.files.run_directory import read_samples
from gsp_calibrator.recording import mcap_io, rebuild
from gsp_calibrator.recording.mcap_io import recording_info, recover_recording
from gsp_calibrator.recording.recorder import recording_parts
from gsp_calibrator.run.identify import identify_from_samples
from gsp_calibrator.run.record import (
    PHASE_COLLECTING,
    PHASE_DONE,
    PHASE_FAILED,
    PHASE_INTERRUPTED,
    STATE_FILE,
)
from gsp_calibrator.tools import demo, demo_commands
from gsp_calibrator.tools.processes import NodeProcesses
from gsp_calibrator.tools.reidentify import stored_weights
from gsp_kinematics.estimation.identification import ALL_PARAMETER_NAMES
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import default_geometry_path, load_geometry
from gsp_msgs_py import conversions, names, qos

#: Postures of the run resumed after a killed device driver, which is compared with an
#: uninterrupted run (a statistic of the two results: as many postures as the demo's).
COMPARED_POSTURES = 60
KILL_AT = 30  #: collected postures before that kill
#: Postures of the other kill tests: they are about the protocol (kill, state, resume), not
#: the accuracy, so a shorter run covers them (the latest kill is at 10 postures).
POSTURES = 16
DEVICE_TOPICS = [names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER, names.TOPIC_LVDT]
TIMEOUT_S = 240.0  #: bounds a failure only (selection + 60 postures on a loaded machine)
TOPIC_TIMEOUT_S = 5.0  #: the calibrator's (see node_suite)


def wait_until(predicate, timeout=TIMEOUT_S, what='event'):
    deadline = time.monotonic() + timeout
    event = threading.Event()
    while not predicate():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        event.wait(0.05)


def runs_under(root):
    return sorted(p for p in root.glob('*') if p.is_dir()) if root.is_dir() else []


def state_of(run):
    try:
        return json.loads((run / STATE_FILE).read_text())
    except (OSError, ValueError):
        return None


def done_count(root):
    runs = runs_under(root)
    state = state_of(runs[-1]) if runs else None
    return len(state['done']) if state else 0


class Client:
    """A client node for the calibrate and resume services, spun in a thread of its own."""

    def __init__(self, context):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node = rclpy.create_node('fault_test_client', context=context)
        self.clients = {
            service: self.node.create_client(Trigger, service)
            for service in (names.SERVICE_CALIBRATE, names.SERVICE_RESUME)
        }
        self.heard = {}  # topic -> messages received
        for topic in topics.SENSOR_TOPICS:
            self.node.create_subscription(
                JointState, topic, lambda _, t=topic: self._count(t), qos.TOPIC_QOS[topic]
            )
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.spinning = SpinThread(self.executor)

    def _count(self, topic):
        self.heard[topic] = self.heard.get(topic, 0) + 1

    def restart(self, processes, name, topics):
        """Start node ``name`` again and wait until ``topics`` speak again (its start-up)."""
        self.heard.clear()
        processes.start([name])
        wait_until(lambda: all(self.heard.get(t) for t in topics), what=f'{name} restarted')

    def calibrator_endpoints(self):
        """Gids of the calibrator's progress publisher and sensor subscriptions (a killed one
        lingers in the graph until its lease expires), by topic."""
        endpoints = {
            names.TOPIC_CALIBRATION_PROGRESS: self.node.get_publishers_info_by_topic(
                names.TOPIC_CALIBRATION_PROGRESS
            )
        }
        for topic in topics.SENSOR_TOPICS:
            endpoints[topic] = [
                info
                for info in self.node.get_subscriptions_info_by_topic(topic)
                if info.node_name.startswith(names.NODE_CALIBRATOR)
            ]
        return {topic: {bytes(i.endpoint_gid) for i in infos} for topic, infos in endpoints.items()}

    def wait_for_services(self):
        for client in self.clients.values():
            assert client.wait_for_service(timeout_sec=60.0), client.srv_name

    def call_async(self, service):
        return self.clients[service].call_async(Trigger.Request())

    def call(self, service):
        future = self.call_async(service)
        wait_until(future.done, what=f'{service} response')
        return future.result()

    def close(self):
        self.spinning.stop()
        self.executor.shutdown(timeout_sec=5.0)
        self.node.destroy_node()


def node_suite(tmp_path, ros_context, postures):
    """The three nodes as processes, with a calibrator selecting ``postures``, and a client:
    yields ``(processes, client, runs root)``."""
    # 100 Hz (sync_tolerance 5 ms) and a 5 s topic_timeout: three processes at 200 Hz on a
    # loaded 2-core machine starved platform_sim to a few leg lengths in 2 s (none within 2.5 ms
    # of a device stamp), and a 2 s timeout then failed the resumed run ("no synchronised
    # sample"). The kill tests wait for the timeout once (a dead node has no other sign), so it
    # is no longer than that margin needs: the in-process node tests, whose three nodes share
    # one process and so pause together, run with 5 s too.
    args = demo.parse_arguments(
        ['--postures', str(postures), '--pool-size', str(4 * postures)]
        + ['--pairs-per-posture', '5']
        + ['--sensor-rate', '100']
    )
    commands = demo_commands.node_commands(args, tmp_path / 'runs')
    commands['calibrator'] += [
        '-p',
        'apply_result:=false',
        '-p',
        f'topic_timeout:={TOPIC_TIMEOUT_S}',
        '-p',
        'write_report_plots:=false',  # the tests are of the faults, not of the report's plots
    ]
    env = demo_commands.ros_environment(dict(os.environ))
    processes = NodeProcesses(commands, env, tmp_path)
    processes.start()
    client = Client(ros_context)
    try:
        client.wait_for_services()
        yield processes, client, tmp_path / 'runs'
    finally:
        client.close()
        processes.stop()


@pytest.fixture
def suite(tmp_path, ros_context):
    yield from node_suite(tmp_path, ros_context, POSTURES)


@pytest.fixture
def compared_suite(tmp_path, ros_context):
    yield from node_suite(tmp_path, ros_context, COMPARED_POSTURES)


def all_accounted_for(run, postures=POSTURES):
    """Every posture of the selection, and of what the route added for the effects (the default
    ``auto``'s reference revisit), has a row or was skipped (e.g. rejected by the platform)."""
    state = state_of(run)
    added = (state.get('route_additions') or {}).get('added_postures', 0)
    rows = sorted(read_samples(run / 'samples.csv').posture)
    skipped = {s['posture'] for s in state['skipped']}
    return len(set(rows)) == len(rows) and sorted(set(rows) | skipped) == list(
        range(1, postures + added + 1)
    )


def assert_recorded(parts, samples):
    """Every collected posture is in the recording (its collection start, noted by the calibrator
    itself), and rebuilding the recording gives (nearly) the same rows. Not exactly: a SIGKILL
    loses the recording's unwritten tail (recovery keeps what reached the file), so its last
    rows can be missing from the rebuild.
    """
    notes = {}
    for part in parts:
        notes.update(rebuild.collection_notes(recording_info(part), part))
    noted = {posture for posture, _ in notes.values()}
    assert set(int(k) for k in samples.posture) <= noted
    rebuilt = rebuild.samples_from_recording(parts)
    assert set(rebuilt.posture) <= set(samples.posture)
    assert len(rebuilt) >= 0.8 * len(samples)


def identification(run):
    """The run's identification, redone offline from its ``samples.csv`` and options (the
    calibrator's own code) for the covariance, which ``result.json`` does not hold; checked
    against the run's own estimates."""
    data = json.loads((run / 'result.json').read_text())
    options = data['options']
    samples = read_samples(run / 'samples.csv')
    sigmas, noise_source, _ = stored_weights(data, options, samples)
    result = identify_from_samples(
        load_geometry(options['nominal_geometry_file']),
        samples,
        sigmas,
        free=options['free_parameters'],
        formulation=options['formulation'],
        noise_source=noise_source,
    ).result
    online = dict(data['estimates']['si'])
    online.update({name: entry['estimate'] for name, entry in data['sensor_errors'].items()})
    for name, value, sd in zip(
        ALL_PARAMETER_NAMES, result.parameters, result.standard_deviations, strict=True
    ):
        assert np.isnan(sd) or abs(value - online[name]) <= 1e-3 * sd, name
    return result


def _kill(processes, name, sig=signal.SIGKILL):
    """Send ``sig`` to node ``name`` and wait for its exit; its exit code (None if alive)."""
    process = processes.processes[name]
    process.send_signal(sig)
    with contextlib.suppress(subprocess.TimeoutExpired):
        process.wait(timeout=20.0)
    return process.poll()


def test_killed_device_driver_then_resume_matches_an_uninterrupted_run(compared_suite):
    processes, client, root = compared_suite
    pending = client.call_async(names.SERVICE_CALIBRATE)
    wait_until(lambda: done_count(root) >= KILL_AT, what=f'{KILL_AT} postures')
    assert _kill(processes, 'device_driver') == -signal.SIGKILL
    wait_until(pending.done, what='the failed run')
    response = pending.result()
    assert not response.success
    assert '/gsp/device/' in response.message, response.message
    run = runs_under(root)[-1]
    state = state_of(run)
    assert state['phase'] == PHASE_FAILED
    assert '/gsp/device/' in state['stop_reason']
    kept = read_samples(run / 'samples.csv')
    assert len(kept) == len(state['done']) >= KILL_AT
    assert sorted(kept.posture) == sorted(state['done'])

    client.restart(processes, 'device_driver', DEVICE_TOPICS)
    resumed = client.call(names.SERVICE_RESUME)
    assert resumed.success, resumed.message
    state = state_of(run)
    assert state['phase'] == PHASE_DONE and state['sessions'] == 2
    samples = read_samples(run / 'samples.csv')
    assert all_accounted_for(run, COMPARED_POSTURES)
    # The first rows are untouched; the recording has a second part, and offline rebuild reads
    # both parts into the same postures.
    assert (samples.leg_lengths[: len(kept)] == kept.leg_lengths).all()
    parts = recording_parts(run)
    assert [os.path.basename(p) for p in parts] == ['recording.mcap', 'recording-2.mcap']
    assert state['recordings'] == ['recording.mcap', 'recording-2.mcap']
    assert_recorded(parts, samples)

    # The restarted device_driver draws fresh noise: with a fixed seed it replayed the draws of
    # its first life, so the resumed run averaged the same noise twice (docs/faults.md).
    first, second = (inclinometer_noise_draws(part) for part in parts)
    assert len(first) > 50 and len(second) > 50 and not first & second

    # An uninterrupted run on the same postures (same selection options): within noise.
    full = client.call(names.SERVICE_CALIBRATE)
    assert full.success, full.message
    other = runs_under(root)[-1]
    assert other != run
    difference = parameter_difference(run, other)
    # The difference of two independent estimates, against its covariance (the sum of theirs):
    # its squared Mahalanobis length is chi2 with one degree per free parameter. 0.1 % of
    # correct resumes fail this (and any one of them is a 3.3-sigma event); a lost, shifted or
    # doubled row, or draws shared between the runs, is far outside. The issue's "3 standard
    # deviations on every parameter" is reported, not asserted: with 51 correlated parameters,
    # 9 % of pairs of correct runs have one beyond 3 (docs/faults.md, "Resume against an
    # uninterrupted run").
    assert difference['parameters'] > 30
    assert difference['mahalanobis2'] <= difference['chi2_999'], difference
    assert difference['max_sigmas'] <= 4.5, difference


def inclinometer_noise_draws(path):
    """The alpha noise draws (rad, rounded to 1e-15) of the inclinometer readings recorded in
    ``path``: reading minus the exact reading of the recorded true pose of the simulated truth."""
    truth = load_geometry(default_geometry_path('true'))
    pose, draws = None, set()
    for message in mcap_io.read_recording(
        path, topics=[names.TOPIC_TRUE_POSE, names.TOPIC_INCLINOMETER]
    ):
        if message.topic == names.TOPIC_TRUE_POSE:
            pose = conversions.pose_stamped_to_pose(message.message)[None]
        elif pose is not None:
            exact = truth.sensors.device_readings(device_readings(truth, pose))[0]
            draws.add(round(message.message.position[0] - exact[0], 15))
    return draws


def parameter_difference(run, other):
    """The free parameters' difference between two runs' results, in their standard deviations
    (each parameter, largest) and jointly (squared Mahalanobis length and its 0.999 quantile)."""
    a, b = identification(run), identification(other)
    assert (a.free == b.free).all()
    difference = (a.parameters - b.parameters)[a.free]
    sigmas = difference / np.hypot(a.standard_deviations, b.standard_deviations)[a.free]
    names_ = [name for name, free in zip(ALL_PARAMETER_NAMES, a.free, strict=True) if free]
    return {
        'parameters': len(difference),
        'max_sigmas': float(np.abs(sigmas).max()),
        'beyond_3_sigmas': [name for name, z in zip(names_, sigmas, strict=True) if abs(z) > 3],
        'mahalanobis2': float(
            difference @ np.linalg.solve(a.covariance + b.covariance, difference)
        ),
        'chi2_999': float(stats.chi2.ppf(0.999, len(difference))),
    }


def test_killed_platform_sim_names_the_status_and_resume_completes(suite):
    processes, client, root = suite
    pending = client.call_async(names.SERVICE_CALIBRATE)
    wait_until(lambda: done_count(root) >= 5, what='5 postures')
    _kill(processes, 'platform_sim')
    wait_until(pending.done, what='the failed run')
    response = pending.result()
    assert not response.success
    assert names.TOPIC_PLATFORM_STATUS in response.message or (
        names.TOPIC_LEG_LENGTHS in response.message
    ), response.message
    run = runs_under(root)[-1]
    assert state_of(run)['phase'] == PHASE_FAILED
    client.restart(processes, 'platform_sim', [names.TOPIC_LEG_LENGTHS])
    resumed = client.call(names.SERVICE_RESUME)
    assert resumed.success, resumed.message
    assert all_accounted_for(run)


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGKILL], ids=['SIGTERM+SIGINT', 'SIGKILL'])
def test_killed_calibrator_loses_nothing_and_resumes(suite, sig):
    processes, client, root = suite
    client.call_async(names.SERVICE_CALIBRATE)
    wait_until(lambda: done_count(root) >= 10, what='10 postures')
    if sig == signal.SIGTERM:  # and a SIGINT right behind it: still a clean stop
        processes.processes['calibrator'].send_signal(signal.SIGTERM)
        code = _kill(processes, 'calibrator', signal.SIGINT)
    else:
        code = _kill(processes, 'calibrator', sig)
    run = runs_under(root)[-1]
    state = state_of(run)
    kept = read_samples(run / 'samples.csv')
    # state.json never lists a posture without its row. After a SIGKILL it can lag samples.csv
    # by the rows appended since its last write (docs/faults.md); destroy_node writes it whole.
    done = state['done']
    assert len(done) >= 10 and list(kept.posture[: len(done)]) == done
    if sig == signal.SIGTERM:
        assert len(kept) == len(done)
        assert code == 0, processes.log_tail('calibrator')
        assert 'Traceback' not in (processes.log_directory / 'calibrator.log').read_text()
        assert state['phase'] == PHASE_INTERRUPTED
        assert (run / 'recording.mcap').is_file() and not (run / 'recording.mcap.tmp').exists()
        parts = [run / 'recording.mcap']
    else:
        assert state['phase'] == PHASE_COLLECTING  # as the kill left it
        recovered = recover_recording(run / 'recording.mcap.tmp')
        parts = [recovered['path']]
    assert_recorded(parts, kept)

    before = client.calibrator_endpoints()
    processes.start(['calibrator'])
    # The new calibrator is discovered (a SIGKILLed one still answers wait_for_service).
    wait_until(
        lambda: all(now - before[t] for t, now in client.calibrator_endpoints().items()),
        what='the new calibrator and its sensor subscriptions',
    )
    client.wait_for_services()
    # Just after a restart a request (or its response) can be lost to discovery: the resume
    # is judged by state.json, and sent again only if no session started on it.
    # A request sent again while the first one's session is starting (slowly, on a loaded
    # machine) is answered 'calibration already running': harmless, and accepted below.
    # Asked again every 10 s until a session starts (bounded by TIMEOUT_S only): beside busy
    # loops, discovery of the new calibrator's service took longer than three tries of 10 s.
    sessions = state_of(run)['sessions']
    pendings = []
    asked_until = time.monotonic() + TIMEOUT_S
    started = threading.Event()
    while not started.is_set():
        assert time.monotonic() < asked_until, 'no resumed session started'
        pendings.append(client.call_async(names.SERVICE_RESUME))
        for _ in range(200):  # up to 10 s for the session to start, then ask again
            if any(p.done() for p in pendings) or state_of(run)['sessions'] > sessions:
                started.set()
                break
            started.wait(0.05)
    wait_until(
        lambda: (
            state_of(run)['phase'] in (PHASE_DONE, PHASE_FAILED)
            and state_of(run)['sessions'] > sessions
        ),
        what='the resumed run',
    )
    for pending in pendings:
        if pending.done():
            message = pending.result().message
            assert pending.result().success or message == 'calibration already running', message
    assert state_of(run)['phase'] == PHASE_DONE, state_of(run)['stop_reason']
    assert all_accounted_for(run)
    # Each kept row once, first; its posture counted done even if state.json had not listed it.
    samples = read_samples(run / 'samples.csv')
    assert (samples.leg_lengths[: len(kept)] == kept.leg_lengths).all()
    assert sorted(state_of(run)['done']) == sorted(samples.posture)
