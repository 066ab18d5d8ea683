"""The run coroutine without rclpy: a plain Python RunHost drives CalibrationRun end to end."""

import asyncio
import collections
import concurrent.futures
import json
import logging

import numpy as np

from gsp_calibrator.collection.events import RowReady, TopicSilent
from gsp_calibrator.collection.synchroniser import PostureSample
from gsp_calibrator.collection.topics import SENSOR_TOPICS
from gsp_calibrator.run import postures
from gsp_calibrator.run.flow import CalibrationRun
from gsp_calibrator.run.host import WAIT_OK, WAIT_TIMEOUT, RunHost
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.run.state import PHASE_DONE, PHASE_FAILED, STATE_FILE
from gsp_calibrator.settings import CalibratorSettings
from gsp_kinematics.geometry import default_geometry, parameter_errors
from gsp_kinematics.kinematics import home_pose
from gsp_kinematics.sensors.noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.travel.motion import posture_leg_lengths
from gsp_kinematics.validation import sensor_measurements
from gsp_msgs_py import conversions, names

SAMPLES_PER_POSTURE = 10


class FakeRecorder:
    def __init__(self):
        self.calls = []

    def start(self, path, options=None):
        self.calls.append(('start', path))

    def stop(self, drain_s=0.0):
        self.calls.append(('stop', drain_s))


class FinalEvents:
    def __init__(self):
        self.events = collections.deque()

    async def get(self):
        return self.events.popleft()


class FakeHost:
    """A platform measured exactly by the true geometry plus the default noise; each posture's
    row is ready as soon as it is commanded. ``failure``: an event ending the run instead."""

    def __init__(self, seed=0, failure_after=None, start_legs=None):
        self.truth = default_geometry('true')
        self.start_legs = start_legs  #: leg readings (6,) m before the run, else those at z 0.6 m
        self.rng = np.random.default_rng(seed)
        self.failure_after = failure_after
        self.recorder = FakeRecorder()
        self.finals = FinalEvents()
        self.failure = None
        self.progress_log = []
        self.delivered = []
        self.ended = False
        self.session = None

    def get_logger(self):
        return logging.getLogger('test_run_flow')

    def shutting_down(self):
        return False

    def get_name(self):
        return names.NODE_CALIBRATOR

    def get_namespace(self):
        return '/'

    def get_publishers_info_by_topic(self, topic):
        return []

    def count_publishers(self, topic):
        return 1

    def command_subscriber_count(self):
        return 1

    async def wait_for(self, predicate, timeout_s):
        return WAIT_OK if predicate() else WAIT_TIMEOUT

    async def await_thread(self, concurrent_future):
        return concurrent_future.result()

    async def in_thread(self, function, *args, **kwargs):
        return function(*args, **kwargs)

    def selection_future(self, settings):
        future = concurrent.futures.Future()
        future.set_result(postures.choose_postures(*postures.selection_arguments(settings)))
        return future

    def progress(self, index, phase, message='', residuals=None, warning=False, **extra):
        self.progress_log.append((index, phase, message))

    def start_collection(self, session, collection):
        """Every sensor topic speaks once, at its current reading (the system check awaits it)."""
        self.session = session
        legs, readings = sensor_measurements(self.truth, np.array([[0.0, 0.0, 0.6, 0, 0, 0]]))
        if self.start_legs is not None:
            legs = np.asarray(self.start_legs, dtype=float)[None]
        messages = {
            names.TOPIC_LEG_LENGTHS: conversions.leg_lengths_to_msg(legs[0]),
            names.TOPIC_INCLINOMETER: conversions.inclinometer_to_msg(*readings[0, :2]),
            names.TOPIC_ENCODER: conversions.encoder_to_msg(readings[0, 2]),
            names.TOPIC_LVDT: conversions.lvdt_to_msg(readings[0, 3]),
        }
        for topic in SENSOR_TOPICS:
            collection.sensor(topic, messages[topic], 0)

    def stop_collection(self):
        pass

    def command_first(self):
        sigma = DEFAULT_SENSOR_NOISE.averaged([SAMPLES_PER_POSTURE])
        while (posture := self.session.next_posture()) is not None:
            k, pose = posture
            if self.failure_after is not None and k > self.failure_after:
                self.failure = TopicSilent(
                    names.TOPIC_LVDT, 'collecting', f'topic {names.TOPIC_LVDT} is silent'
                )
                self.finals.events.append(self.failure)
                return
            legs, readings = sensor_measurements(self.truth, pose[None])
            sample = PostureSample(
                legs[0] + self.rng.normal(0.0, sigma.leg_lengths, 6),
                readings[0] + self.rng.normal(0.0, 1.0, 4) * sigma.readings(),
                SAMPLES_PER_POSTURE,
                k * 1_000_000_000,
                np.full(6, DEFAULT_SENSOR_NOISE.leg_lengths),
                DEFAULT_SENSOR_NOISE.readings(),
            )
            self.finals.events.append(self.session.end_posture(RowReady(k, pose, sample)))

    def collection_done(self):
        return self.session.commanded_all and not self.finals.events

    async def deliver_result(self, settings, geometry, fit_accepted):
        self.delivered.append((geometry, fit_accepted))
        return True, 'applied to the fake platform'

    def run_ended(self):
        self.ended = True


def _settings(tmp_path, **values):
    return CalibratorSettings.from_values(
        {
            'output_root': str(tmp_path),
            'posture_count': 30,
            'pool_size': 120,
            'samples_per_posture': SAMPLES_PER_POSTURE,
            'write_report_plots': False,  # the tests are of the flow, not of the report
            **values,
        }
    )


def _state(run_directory):
    return json.loads((run_directory / STATE_FILE).read_text())


def test_a_plain_python_host_drives_a_whole_run(tmp_path):
    host = FakeHost()
    assert isinstance(host, RunHost)  # every member the run may use
    success, message = asyncio.run(CalibrationRun(host, _settings(tmp_path), False).serve())

    assert success, message
    parsed = parse_response(message)
    assert 'applied to the fake platform' in parsed.summary
    ((geometry, fit_accepted),) = host.delivered
    # 30 postures of 10 samples at Table 3's first noise level: every parameter within 0.05 mm
    # (0.05 deg for gamma) of the truth; the nominal is off by millimetres.
    assert np.max(np.abs(parameter_errors(geometry, host.truth))) < 0.05
    assert np.max(np.abs(parameter_errors(default_geometry('nominal'), host.truth))) > 0.5
    run_directory = tmp_path / parsed.run_directory.rstrip('/').rsplit('/', 1)[-1]
    assert _state(run_directory)['phase'] == PHASE_DONE
    assert len((run_directory / 'samples.csv').read_text().splitlines()) == 1 + 30
    assert host.progress_log[-1][1] == names.PHASE_DONE
    assert [call[0] for call in host.recorder.calls] == ['start', 'stop'] and host.ended


def test_the_route_starts_from_the_platforms_current_posture(tmp_path):
    """The first planned move is from where the leg lengths say the platform is, not home."""
    settings = _settings(tmp_path)
    selection = postures.choose_postures(*postures.selection_arguments(settings))
    # A selected posture far from home: the route from it differs from the route from home.
    start = selection.poses[np.argmax(np.abs(selection.poses[:, 0]))]
    # The legs where a controller with the nominal geometry put them (platform_sim's).
    heard_legs = posture_leg_lengths(settings.nominal, start[None])[0]
    host = FakeHost(start_legs=heard_legs)
    success, message = asyncio.run(CalibrationRun(host, settings, False).serve())
    assert success, message

    current, reason = postures.route_start(settings.nominal, heard_legs)
    assert reason == ''
    np.testing.assert_allclose(current, start, atol=1e-9)  # m, rad
    expected = postures.posture_route(settings, selection.poses, current)
    from_home = postures.posture_route(settings, selection.poses, home_pose())
    assert not np.array_equal(expected.order, from_home.order)
    commanded = np.asarray(host.session.state.poses)
    # The platform stands at a selected posture: commanded first, the device would not change
    # and the posture would be skipped, so it comes last.
    np.testing.assert_allclose(commanded[-1], start, atol=1e-12)
    np.testing.assert_allclose(commanded, selection.poses[expected.order], atol=1e-12)  # m, rad


def test_the_route_start_is_the_home_pose_without_leg_lengths():
    nominal = default_geometry('nominal')
    pose, reason = postures.route_start(nominal, None)
    np.testing.assert_array_equal(pose, home_pose())
    assert reason == 'no leg lengths received'
    pose, reason = postures.route_start(nominal, np.full(6, 5.0))
    np.testing.assert_array_equal(pose, home_pose())
    assert reason.startswith('no forward kinematics of the latest leg lengths')


def test_a_failure_event_ends_the_run_without_delivering(tmp_path):
    host = FakeHost(failure_after=5)
    success, message = asyncio.run(CalibrationRun(host, _settings(tmp_path), False).serve())

    assert not success
    assert names.TOPIC_LVDT in message
    assert host.delivered == []
    (run_directory,) = [path for path in tmp_path.iterdir() if path.is_dir()]
    state = _state(run_directory)
    assert state['phase'] == PHASE_FAILED and names.TOPIC_LVDT in state['stop_reason']
    assert host.progress_log[-1][1] == names.PHASE_FAILED
    assert host.ended
