"""The calibrator node with platform_sim and device_driver in one process (executors, no CLI).

The sensors run at 100 Hz here (three nodes share one Python process); waits are generous
because the machine may be loaded, and end as soon as their condition holds.
"""

import contextlib
import json
import sys
import threading

import numpy as np
import pytest
from calibrator_suite import (
    DEVICE_FREE,
    PERTURBED,
    RATE_HZ,
    Suite,
    calibrator_parameters,
    make_suite,
    perturbed_truth,
)
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from gsp_calibrator.collection import topics
from gsp_calibrator.files.run_directory import RunDirectory
from gsp_calibrator.node import calibrator_node
from gsp_calibrator.node.calibrator_node import GIL_SWITCH_INTERVAL_S, CalibratorNode
from gsp_calibrator.recording import rebuild
from gsp_calibrator.recording.mcap_io import RUN_METADATA_NAME, recording_info
from gsp_calibrator.recording.recorder import POSTURE_METADATA_NAME
from gsp_calibrator.report.write import PLOTS_SKIPPED_NOTE
from gsp_calibrator.run.response import parse_response
from gsp_kinematics.model.geometry import default_geometry, geometry_from_yaml, parameter_errors
from gsp_msgs_py import conversions, names, qos
from gsp_msgs_py.parameter_specs import ConfigurationError


def test_calibration_in_process(ros_context, tmp_path):
    truth = perturbed_truth(tmp_path / 'true.yaml')
    suite, calibrator, platform, _ = make_suite(
        ros_context,
        tmp_path,
        tmp_path / 'true.yaml',
        {'apply_result': True},
    )
    nan_publisher = suite.client_node.create_publisher(
        JointState, names.TOPIC_LEG_LENGTHS, qos.TOPIC_QOS[names.TOPIC_LEG_LENGTHS]
    )
    status_publisher = suite.client_node.create_publisher(
        DiagnosticStatus, names.TOPIC_PLATFORM_STATUS, qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS]
    )
    settled_published = {}  # command id -> source timestamp (ns) of its settled status

    def on_status(msg, info):
        with contextlib.suppress(ValueError):  # the junk status below
            status = conversions.parse_status(msg)
            if status.settled:
                settled_published[status.command_id] = info['source_timestamp']

    suite.client_node.create_subscription(
        DiagnosticStatus,
        names.TOPIC_PLATFORM_STATUS,
        on_status,
        qos.TOPIC_QOS[names.TOPIC_PLATFORM_STATUS],
    )
    try:
        first = suite.call()
        # Once the run has started (its first progress), a second call is answered at once.
        assert suite.wait_until(lambda: suite.phase_seen(names.PHASE_SELECTING))
        response = suite.wait(suite.call(), timeout=10.0)
        assert not first.done()
        assert not response.success and response.message == 'calibration already running'
        # A non-finite reading is dropped and counted, a malformed message or status is
        # ignored; the run carries on. A timer publishes them until one is counted (discovery
        # of a new publisher takes time).
        bad = JointState(name=list(names.LEG_JOINT_NAMES), position=[float('nan')] * 6)

        counted = threading.Event()

        def publish_bad():  # (a timer cancelled from another thread can break the executor)
            if counted.is_set():
                return
            bad.header.stamp = calibrator.get_clock().now().to_msg()
            nan_publisher.publish(bad)
            nan_publisher.publish(JointState(name=['leg_1'], position=[0.5]))
            status_publisher.publish(DiagnosticStatus(name='junk'))

        suite.client_node.create_timer(0.05, publish_bad)
        assert suite.wait_until(
            lambda: first.done() or calibrator.postures.protocol.collector.non_finite['leg_lengths']
        )
        counted.set()
        response = suite.wait(first)
        assert response.success, response.message

        parsed = parse_response(response.message)
        run = RunDirectory(parsed.run_directory)
        assert run.path.parent == tmp_path / 'runs'
        samples = run.read_samples()
        assert 10 <= len(samples) <= 12 and set(samples.n_samples) == {5}
        calibrated = run.read_geometry()
        assert (
            geometry_from_yaml(parsed.geometry_yaml).to_vector().tolist()
            == calibrated.to_vector().tolist()
        )
        errors = parameter_errors(calibrated, truth)
        assert np.max(np.abs(errors[:43])) < 0.05 and abs(errors[43]) < 0.01  # mm, deg
        # The collection's figures are data in result.json (not log text).
        collection = json.loads((run.path / 'result.json').read_text())['collection']
        assert collection['non_finite_dropped']['leg_lengths'] >= 1
        assert set(collection['non_finite_dropped']) == {
            'leg_lengths',
            'inclinometer',
            'encoder',
            'lvdt',
        }
        assert isinstance(collection['inconsistent_dropped'], int)
        # Every sensor message's processing lag of the run, per topic (docs/data.md).
        lags = collection['processing_lag']
        assert set(lags) == set(topics.SENSOR_TOPICS)
        for topic, lag in lags.items():
            assert lag['count'] > 0, topic
            assert 0 <= lag['p50_s'] <= lag['p99_s'] <= lag['max_s'], topic
        skipped = [
            line for line in response.message.splitlines() if line.startswith('skipped posture')
        ]
        # A posture the platform rejects is replaced; only other skips leave a gap.
        replaced = {r['rejected'] for r in collection['replacements']}
        gaps = [s for s in collection['skipped'] if s['posture'] not in replaced]
        assert len(collection['skipped']) == len(skipped) and len(samples) == 12 - len(gaps)
        assert all(
            set(s) == {'posture', 'reason', 'rejected_by_platform'} for s in collection['skipped']
        )

        # The sensor subscriptions outlive the run (ros2/rclpy#1206); messages are dropped now.
        assert calibrator.recorder.forward and not calibrator.postures.active

        # Issue 4: the run directory holds the recording and the report, here without its plots
        # (write_report_plots false).
        for name in ('recording.mcap', 'result.json', 'report.md'):
            assert (run.path / name).is_file(), name
        report_text = (run.path / 'report.md').read_text(encoding='utf-8')
        assert PLOTS_SKIPPED_NOTE in report_text and '| Loff1 | mm |' in report_text
        assert not list(run.path.glob('*.png'))
        assert not list(run.path.glob('*.tmp'))
        info = recording_info(run.path / 'recording.mcap')
        for topic in (
            names.TOPIC_LEG_LENGTHS,
            names.TOPIC_ENCODER,
            names.TOPIC_PLATFORM_STATUS,
            names.TOPIC_POSE_COMMAND,
            names.TOPIC_CALIBRATION_PROGRESS,
        ):
            assert info['topics'][topic]['count'] > 0, topic
        assert len(info['metadata'][POSTURE_METADATA_NAME]) >= len(samples)
        # Each posture's samples count from the instant the platform published settled (not
        # from the status's receipt): the noted starts are the statuses' source timestamps.
        starts = rebuild.collection_notes(info)
        assert starts and {c: start for c, (_, start) in starts.items()} == {
            c: settled_published[c] for c in starts
        }
        assert info['metadata'][RUN_METADATA_NAME]
        assert json.loads((run.path / 'result.json').read_text())

        # Applied to the platform controller through its parameter service.
        applied = platform.get_parameter('geometry.leg_offsets').value
        np.testing.assert_allclose(applied, calibrated.leg_offsets, rtol=0, atol=1e-15)
        assert 'applied to /platform_sim' in response.message

        # Progress: posture k of M through the phases.
        phases = [p.phase for p in suite.progress]
        for phase in (
            names.PHASE_SELECTING,
            names.PHASE_MOVING,
            names.PHASE_COLLECTING,
            names.PHASE_IDENTIFYING,
            names.PHASE_DONE,
        ):
            assert phase in phases
        assert all(p.posture_count == 12 for p in suite.progress)
        assert suite.progress[-1].residuals and 'alpha' in suite.progress[-1].residuals

        # The result is latched: a subscriber that comes later still gets it.
        received = []
        suite.client_node.create_subscription(
            String,
            names.TOPIC_CALIBRATION_RESULT,
            lambda m: received.append(m.data),
            QoSProfile(
                depth=1,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
            ),
        )
        assert suite.wait_until(lambda: received, timeout=10.0)
        assert (
            geometry_from_yaml(received[0]).to_vector().tolist() == calibrated.to_vector().tolist()
        )
    finally:
        suite.close()


def test_rejected_postures_are_replaced_and_the_run_ends_with_the_planned_count(
    ros_context, tmp_path
):
    perturbed_truth(tmp_path / 'true.yaml')
    # The platform's controller allows less leg stroke than the nominal the postures come from.
    tight = [Parameter('geometry.limits.leg_stroke_max', value=1.0)]
    suite, *_ = make_suite(
        ros_context, tmp_path, tmp_path / 'true.yaml', {'free_parameters': PERTURBED}, tight
    )
    try:
        response = suite.wait(suite.call())
        assert response.success, response.message
        skipped = [
            line for line in response.message.splitlines() if line.startswith('skipped posture')
        ]
        assert skipped and all(
            'rejected by the platform' in line and 'stroke' in line for line in skipped
        )
        run = RunDirectory(parse_response(response.message).run_directory)
        samples = run.read_samples()
        assert len(samples) == 12  # the planned count, thanks to the replacements
        assert any('skipped' in p.extra for p in suite.progress)
        # result.json lists each rejected posture and the one that replaced it.
        replacements = json.loads((run.path / 'result.json').read_text())['collection'][
            'replacements'
        ]
        assert len(replacements) == len(skipped)
        state = json.loads((run.path / 'state.json').read_text())
        assert state['replacements'] == replacements
        rejected = {r['rejected'] for r in replacements}
        assert rejected == {int(line.split()[2].rstrip(':')) for line in skipped}, skipped
        # Every posture planned or added has a row, except the rejected ones.
        assert set(samples.posture) == set(range(1, len(state['poses']) + 1)) - rejected
        # A replacement is a pool posture not already in the run.
        poses = np.asarray(state['poses'])
        assert len({tuple(np.round(p, 12)) for p in poses}) == len(poses)
    finally:
        suite.close()


def test_a_silent_topic_ends_the_run_and_keeps_the_samples(ros_context, tmp_path):
    perturbed_truth(tmp_path / 'true.yaml')
    suite, _, _, device = make_suite(
        ros_context,
        tmp_path,
        tmp_path / 'true.yaml',
        # The silence is the device's, for good: the timeout needs no margin to it, only enough
        # not to take a loaded machine's pause of one in-process node for a silence.
        {'topic_timeout': 5.0, 'posture_count': 40, 'pool_size': 200},
    )
    try:
        future = suite.call()
        suite.wait_until(
            lambda: future.done() or sum('averaged' in p.message for p in list(suite.progress)) >= 3
        )
        suite.stop_spinning(device)  # the device driver stops: its topics fall silent
        response = suite.wait(future)
        assert not response.success
        assert 'is silent' in response.message and '/gsp/device/' in response.message
        run = RunDirectory(parse_response(response.message).run_directory)
        samples = run.read_samples()
        assert 3 <= len(samples) < 40
        assert f'{len(samples)} posture(s) saved to {run.path / "samples.csv"}' in response.message
        assert not (run.path / 'result.yaml').exists()
        assert suite.progress[-1].phase == names.PHASE_FAILED
    finally:
        suite.close()


def test_non_identifiable_parameters_fail_and_nothing_is_applied(ros_context, tmp_path):
    perturbed_truth(tmp_path / 'true.yaml')
    # 4 postures give 16 independent equations (10 readings, 6 pose unknowns each): not
    # enough for 20 free parameters.
    free = [
        'A1x',
        'A1y',
        'A1z',
        'B1x',
        'B1y',
        'B1z',
        'Loff1',
        'A2x',
        'A2y',
        'A2z',
        'B2x',
        'B2y',
        'B2z',
        'Loff2',
        'A3x',
        'A3y',
        'A3z',
        'B3x',
        'D0',
        'gamma',
    ]
    suite, _, platform, _ = make_suite(
        ros_context,
        tmp_path,
        tmp_path / 'true.yaml',
        {'posture_count': 4, 'pool_size': 40, 'apply_result': True, 'free_parameters': free},
    )
    before = platform.get_parameter('geometry.leg_offsets').value
    try:
        response = suite.wait(suite.call())
        assert not response.success
        assert 'non-identifiable parameters' in response.message
        assert 'nothing applied' in response.message
        assert 'applied to' not in response.message
        assert platform.get_parameter('geometry.leg_offsets').value == before
        run = RunDirectory(parse_response(response.message).run_directory)
        assert len(run.read_samples()) == 4 and not (run.path / 'result.yaml').exists()
    finally:
        suite.close()


def test_a_device_that_does_not_follow_the_platform_is_detected(ros_context, tmp_path):
    """A stuck device (its readings never change) gives no usable posture: each is skipped."""
    import rclpy

    from gsp_platform_sim.platform_sim_node import PlatformSimNode

    frozen = rclpy.create_node('frozen_device', context=ros_context)
    publishers = {
        topic: frozen.create_publisher(JointState, topic, qos.TOPIC_QOS[topic])
        for topic in (names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER, names.TOPIC_LVDT)
    }
    rng = np.random.default_rng(0)

    def publish():
        stamp = frozen.get_clock().now().to_msg()
        noise = rng.normal(0.0, 1e-6, 4)
        publishers[names.TOPIC_INCLINOMETER].publish(
            conversions.inclinometer_to_msg(0.01 + noise[0], -0.02 + noise[1], stamp)
        )
        publishers[names.TOPIC_ENCODER].publish(conversions.encoder_to_msg(0.1 + noise[2], stamp))
        publishers[names.TOPIC_LVDT].publish(conversions.lvdt_to_msg(0.15 + noise[3], stamp))

    frozen.create_timer(1.0 / RATE_HZ, publish)
    platform = PlatformSimNode(
        context=ros_context,
        parameter_overrides=[
            Parameter('publish_rate', value=RATE_HZ),
            Parameter('publish_markers', value=False),
        ],
    )
    calibrator = CalibratorNode(
        context=ros_context,
        parameter_overrides=calibrator_parameters(tmp_path / 'runs', posture_count=2, pool_size=20),
    )
    suite = Suite(ros_context, [calibrator, platform, frozen])
    try:
        response = suite.wait(suite.call())
        assert not response.success and 'no posture was collected' in response.message
        skipped = [
            line for line in response.message.splitlines() if line.startswith('skipped posture')
        ]
        assert len(skipped) == 2
        assert all('did not change from the previous posture' in line for line in skipped)
    finally:
        suite.close()


def applying_to_nobody(ros_context, tmp_path, **overrides):
    """A 4-posture run fitting only D0 and gamma (the leg offsets stay at their wrong nominal
    values: a wrong datum, so the accuracy the device measures misses the requirement) that
    applies its result to a node that does not exist."""
    perturbed_truth(tmp_path / 'true.yaml')
    parameters = {
        'posture_count': 4,
        'pool_size': 40,
        'free_parameters': ['D0', 'gamma'],
        'apply_result': True,
        'platform_node_name': 'nobody',
        # Also bounds the wait for the absent parameter service: short, but long enough that a
        # loaded machine's pause of one in-process node is not taken for a silent topic.
        'topic_timeout': 5.0,
        **overrides,
    }
    return make_suite(ros_context, tmp_path, tmp_path / 'true.yaml', parameters)[0]


def test_a_failed_apply_is_reported(ros_context, tmp_path):
    # Every wrong parameter free: the result is accepted, so the apply is tried.
    suite = applying_to_nobody(
        ros_context, tmp_path, free_parameters=DEVICE_FREE, posture_count=8, pool_size=80
    )
    try:
        response = suite.wait(suite.call())
        assert not response.success
        assert (
            'NOT applied: parameter service /nobody/list_parameters unavailable' in response.message
        )
        parsed = parse_response(response.message)
        assert parsed.geometry_yaml  # the calibration itself succeeded and is kept
        assert (RunDirectory(parsed.run_directory).path / 'result.yaml').is_file()
    finally:
        suite.close()


def test_a_wrong_datum_is_written_but_not_applied(ros_context, tmp_path):
    """Garbage through the nodes: leg offsets held at wrong values. The device measures the
    held-out postures millimetres from where the model puts them: the result is written, not
    applied, and the response says which condition failed and by how much; the goodness of fit
    stays a diagnostic beside it."""
    suite = applying_to_nobody(ros_context, tmp_path)
    try:
        response = suite.wait(suite.call())
        assert not response.success
        assert response.message.startswith('calibration NOT ACCEPTED')
        assert 'exceeds the required 0.1 mm' in response.message
        assert 'does NOT explain the data' in response.message  # the diagnostic
        assert 'parameter service' not in response.message  # no apply was attempted
        parsed = parse_response(response.message)
        result_yaml = RunDirectory(parsed.run_directory).path / 'result.yaml'
        assert 'NOT ACCEPTED' in result_yaml.read_text()
        data = json.loads((result_yaml.parent / 'result.json').read_text())
        assert data['accepted'] is False and data['fit_accepted'] is False
        assert data['accuracy']['calibrated']['position_mm']['mean'] > 0.1
        assert any('exceeds the required' in f for f in data['acceptance']['failures'])
        assert set(data['noise_estimates']) == {'leg_lengths', 'inclinometer', 'encoder', 'lvdt'}
    finally:
        suite.close()


@pytest.mark.parametrize(
    'name, value, match',
    [
        ('posture_count', 0, 'posture_count'),
        ('free_parameters', ['A1x', 'bogus'], 'unknown parameter name'),
        ('nominal_geometry_file', '/nonexistent.yaml', 'cannot read geometry file'),
        ('sigma_lvdt', -1.0, 'sigma_lvdt'),
    ],
)
def test_bad_parameters_stop_the_node_at_start_up(ros_context, name, value, match):
    with pytest.raises(ConfigurationError, match=match):
        CalibratorNode(context=ros_context, parameter_overrides=[Parameter(name, value=value)])


def test_bad_parameters_are_rejected_at_run_time(ros_context, tmp_path):
    node = CalibratorNode(
        context=ros_context,
        parameter_overrides=[
            Parameter('posture_count', value=5),
            Parameter('pool_size', value=10),
            Parameter('output_root', value=str(tmp_path)),
        ],
    )
    try:
        for name, value, match in [
            ('pool_size', 4, 'must not exceed pool_size'),
            ('formulation', 'magic', 'must be one of'),
            ('sync_tolerance', -0.5, 'sync_tolerance'),
            ('platform_node_name', 'bad name', 'not a valid node name'),
        ]:
            result = node.set_parameters([Parameter(name, value=value)])[0]
            assert not result.successful and match in result.reason, (name, result.reason)
        result = node.set_parameters([Parameter('formulation', value='fk')])[0]
        assert result.successful and node._settings.formulation == 'fk'
        # Every parameter has a descriptor with a description.
        for spec_name in ('posture_count', 'sync_tolerance', 'free_parameters', 'apply_result'):
            assert node.describe_parameter(spec_name).description
    finally:
        node.destroy_node()


def test_the_calibrator_process_hands_the_gil_over_promptly(monkeypatch):
    # main() sets the switch interval before the node spins (checked inside run_node, which is
    # replaced here: the real one would take over this process's signals and rclpy's default
    # context).
    seen = {}

    def run_node(make_node, args=None, executor=None, *, logger_name):
        seen.update(interval=sys.getswitchinterval(), make_node=make_node, args=args)
        return 0

    monkeypatch.setattr(calibrator_node.node_tools, 'run_node', run_node)
    previous = sys.getswitchinterval()
    sys.setswitchinterval(0.005)  # Python's default
    try:
        assert calibrator_node.main(['--ros-args']) == 0
    finally:
        sys.setswitchinterval(previous)
    assert seen['make_node'] is CalibratorNode and seen['args'] == ['--ros-args']
    assert seen['interval'] == pytest.approx(GIL_SWITCH_INTERVAL_S)
    assert GIL_SWITCH_INTERVAL_S < 0.005


def test_waits_end_when_their_predicate_holds_or_at_their_timeout():
    from rclpy.task import Future

    from gsp_calibrator.node.threads import Waits
    from gsp_calibrator.run.host import WAIT_OK, WAIT_TIMEOUT

    now = [100.0]
    flag = []
    waits = Waits(lambda: now[0])
    condition = waits.add(lambda: bool(flag), 5.0, Future())
    timeout = waits.add(lambda: False, 2.0, Future())
    broken = waits.add(lambda: 1 / 0, 2.0, Future())
    assert broken.result().startswith('error') and not condition.done() and len(waits) == 2
    now[0] += 2.0
    waits.poll()
    assert timeout.result() == WAIT_TIMEOUT and not condition.done()
    flag.append(True)
    waits.poll()
    assert condition.result() == WAIT_OK and len(waits) == 0


#: Leg limits scaled up from the realistic ones (50 mm/s, 200 mm/s^2) so that a run takes seconds:
#: a move of 0.4 m takes 0.2 s.
FAST_MOTION = {'max_leg_speed': 4.0, 'max_leg_acceleration': 40.0}
MOVING_POSTURES = 8


def _moving_run(suite, calibrator, order, truth):
    """One run of ``calibrator`` in ``suite`` with the postures in ``order``: its commanded poses,
    samples and parameter errors against ``truth``."""
    assert calibrator.set_parameters([Parameter('posture_order', value=order)])[0].successful
    response = suite.wait(suite.call())
    assert response.success, response.message
    run = RunDirectory(parse_response(response.message).run_directory)
    state = json.loads((run.path / 'state.json').read_text())
    errors = parameter_errors(run.read_geometry(), truth)
    return np.asarray(state['poses']), run.read_samples(), errors


def test_a_route_ordered_run_with_motion_calibrates_as_well_as_selection_order(
    ros_context, tmp_path
):
    from gsp_kinematics.model.kinematics import home_pose
    from gsp_kinematics.model.motion import MotionLimits
    from gsp_kinematics.planning.route import plan_route

    truth = perturbed_truth(tmp_path / 'true.yaml')
    platform = [Parameter(name, value=value) for name, value in FAST_MOTION.items()]
    overrides = {
        'free_parameters': PERTURBED,
        'posture_count': MOVING_POSTURES,
        'pool_size': 60,
        **FAST_MOTION,
    }
    suite, calibrator, *_ = make_suite(
        ros_context, tmp_path, tmp_path / 'true.yaml', overrides, platform
    )
    try:
        # The route run first: it starts from home, where the platform starts. The selection
        # order does not depend on where the platform is (the same seed: the same postures).
        route_poses, route_samples, route_errors = _moving_run(suite, calibrator, 'route', truth)
        chosen_poses, chosen_samples, chosen_errors = _moving_run(
            suite, calibrator, 'selection', truth
        )
    finally:
        suite.close()
    # The same postures, in another order: the route's, whose travel is shorter.
    assert sorted(map(tuple, route_poses)) == sorted(map(tuple, chosen_poses))
    assert not np.array_equal(route_poses, chosen_poses)
    limits = MotionLimits(FAST_MOTION['max_leg_speed'], FAST_MOTION['max_leg_acceleration'])
    route = plan_route(default_geometry('nominal'), home_pose(), chosen_poses, limits)
    np.testing.assert_array_equal(route_poses, chosen_poses[route.order])
    assert route.travel_s < route.selection_order_s
    # Both collect every posture and calibrate to the same accuracy (mm, deg).
    assert len(route_samples) == len(chosen_samples) == MOVING_POSTURES
    for errors in (route_errors, chosen_errors):
        assert np.max(np.abs(errors[:43])) < 0.05 and abs(errors[43]) < 0.01


def test_diagnostics_report_topic_silence_and_a_failed_run(ros_context, tmp_path):
    from gsp_calibrator.run.health import LAG_WARN_S, topic_age_key, topic_lag_key
    from gsp_msgs_py.diagnostics import DiagnosticsListener
    from gsp_msgs_py.health import ERROR, OK, WARN

    calibrator = CalibratorNode(
        context=ros_context,
        parameter_overrides=calibrator_parameters(
            tmp_path / 'runs',
            posture_count=4,
            pool_size=20,
            topic_timeout=0.5,
            diagnostics_period=0.05,
        ),
    )
    suite = Suite(ros_context, [calibrator])
    listener = DiagnosticsListener(suite.client_node)
    name = 'calibrator: calibration'

    def health(predicate):
        assert suite.wait_until(
            lambda: name in listener.reports and predicate(listener.reports[name]), 30.0
        ), listener.reports
        return listener.reports[name]

    publishers = {
        topic: suite.client_node.create_publisher(JointState, topic, qos.TOPIC_QOS[topic])
        for topic in topics.SENSOR_TOPICS
    }
    streaming = threading.Event()

    def publish():
        if streaming.is_set():
            for publisher in publishers.values():
                publisher.publish(JointState())

    suite.client_node.create_timer(0.02, publish)
    try:
        # Nothing heard yet: a run could not start.
        report = health(lambda h: True)
        assert report.level == WARN and 'silent for more than 0.5 s' in report.message
        assert report.values['state'] == 'idle' and report.values['posture'] == '0 of 0'
        assert all(report.values[topic_age_key(t)] == 'never' for t in topics.SENSOR_TOPICS)
        assert listener.hardware_ids[name] == names.PROGRESS_NAME

        streaming.set()
        report = health(lambda h: h.level == OK)
        ages = [float(report.values[topic_age_key(t)]) for t in topics.SENSOR_TOPICS]
        assert max(ages) <= 0.5
        # The processing lag of each topic, from the middleware's receive time on.
        report = health(
            lambda h: (
                h.level == OK
                and all(
                    h.values.get(topic_lag_key(t), 'none') != 'none' for t in topics.SENSOR_TOPICS
                )
            )
        )
        lags = [float(report.values[topic_lag_key(t)]) for t in topics.SENSOR_TOPICS]
        assert 0.0 <= min(lags) and max(lags) <= LAG_WARN_S

        # Every sensor falls silent. Each topic's silence counts from its own last receipt, so
        # the first warning can name one topic before the others cross the bound: the status
        # awaited is the one that names them all.
        streaming.clear()
        report = health(
            lambda h: h.level == WARN and all(t in h.message for t in topics.SENSOR_TOPICS)
        )
        assert 'silent for more than 0.5 s' in report.message

        # A run with no platform: it fails, and the status says so until the next run.
        response = suite.wait(suite.call())
        assert not response.success
        report = health(lambda h: h.level == ERROR)
        assert report.message.startswith('the last run failed: ') and report.values['run']
        assert report.values['phase'] == names.PHASE_FAILED
        assert report.values['state'] == 'idle'
    finally:
        suite.close()


def test_the_platform_check_counts_subscribers_other_than_the_calibrator_s_recorder(
    ros_context, tmp_path
):
    """The calibrator records its own pose commands: the run's first check (a subscriber to the
    commands: is platform_sim running?) counts only the others, or the first command of a
    (re)started calibrator goes out before the platform hears it."""
    import rclpy
    from geometry_msgs.msg import PoseStamped

    node = CalibratorNode(
        context=ros_context, parameter_overrides=[Parameter('output_root', value=str(tmp_path))]
    )
    platform = rclpy.create_node('platform_sim', context=ros_context)
    try:
        host = node._run_host()
        assert node.command_publisher.get_subscription_count() == 1  # the recorder's
        assert host.command_subscribers() == 0
        platform.create_subscription(
            PoseStamped, names.TOPIC_POSE_COMMAND, lambda _: None, qos.COMMAND_QOS
        )
        assert host.command_subscribers() == 1
    finally:
        platform.destroy_node()
        node.destroy_node()
