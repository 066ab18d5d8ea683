"""The run coroutine without rclpy: a plain Python RunHost drives CalibrationRun end to end."""

import asyncio
import concurrent.futures
import json
import logging
import threading

import numpy as np
import pytest

from gsp_calibrator.collection.events import PostureSkipped, RowReady, TopicSilent
from gsp_calibrator.collection.synchroniser import PostureRow
from gsp_calibrator.collection.topics import SENSOR_TOPICS
from gsp_calibrator.files import history
from gsp_calibrator.node.posture_link import PostureLink
from gsp_calibrator.run import postures
from gsp_calibrator.run.flow import CalibrationRun
from gsp_calibrator.run.host import WAIT_OK, WAIT_TIMEOUT, RunHost
from gsp_calibrator.run.record import PHASE_DONE, PHASE_FAILED, STATE_FILE
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.settings import CalibratorSettings
from gsp_kinematics.model.effects import approach_directions
from gsp_kinematics.model.geometry import default_geometry, parameter_errors
from gsp_kinematics.model.kinematics import home_pose, inverse_kinematics
from gsp_kinematics.model.motion import posture_leg_lengths
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.model.validation import sensor_measurements
from gsp_msgs_py import conversions, names

PAIRS_PER_POSTURE = 10


class FakeRecorder:
    def __init__(self):
        self.calls = []

    def start(self, path, options=None):
        self.calls.append(('start', path))

    def stop(self, drain_s=0.0):
        self.calls.append(('stop', drain_s))

    def note_posture_end(self, command_id, posture, outcome, reason=''):
        self.calls.append(('end', posture, outcome))


class FakePlatform:
    """A platform measured exactly by the true geometry plus the default noise: each posture's
    row is ready as soon as it is commanded. ``failure_after``: a silent topic ends the run
    instead at the posture after it."""

    def __init__(self, seed=0, failure_after=None, start_legs=None, silent=()):
        self.truth = default_geometry('true')
        self.silent = tuple(silent)  #: topics that never speak
        self.start_legs = start_legs  #: leg readings (6,) m before the run, else those at z 0.6 m
        self.rng = np.random.default_rng(seed)
        self.failure_after = failure_after
        self.link = None
        self.commands = 0
        self.commanded = []  #: the poses commanded, in order

    def hear_every_topic(self, collection, stamp_s=None):
        """Every sensor topic (but the ``silent``) speaks once, at its current reading (the
        system check awaits it), stamped ``stamp_s`` (s; None: zero)."""
        legs, readings = sensor_measurements(self.truth, np.array([[0.0, 0.0, 0.6, 0, 0, 0]]))
        if self.start_legs is not None:
            legs = np.asarray(self.start_legs, dtype=float)[None]
        messages = {
            names.TOPIC_LEG_LENGTHS: conversions.leg_lengths_to_msg(legs[0], stamp_s),
            names.TOPIC_INCLINOMETER: conversions.inclinometer_to_msg(*readings[0, :2], stamp_s),
            names.TOPIC_ENCODER: conversions.encoder_to_msg(readings[0, 2], stamp_s),
            names.TOPIC_LVDT: conversions.lvdt_to_msg(readings[0, 3], stamp_s),
        }
        for topic in SENSOR_TOPICS:
            if topic not in self.silent:
                collection.sensor(topic, messages[topic], 0)

    def commander(self, pose):
        self.commanded.append(np.array(pose, dtype=float))
        self.commands += 1
        k = self.commands
        return str(k), k * 1_000_000_000, lambda: self.link.feed(lambda _: self.end(k, pose))

    def end(self, k, pose):
        """The event that ends posture ``k`` (commanded ``pose``)."""
        if self.failure_after is not None and k > self.failure_after:
            return [
                TopicSilent(names.TOPIC_LVDT, 'collecting', f'topic {names.TOPIC_LVDT} is silent')
            ]
        sigma = DEFAULT_SENSOR_NOISE.averaged([PAIRS_PER_POSTURE])
        legs, readings = sensor_measurements(self.truth, pose[None])
        sample = PostureRow(
            legs[0] + self.rng.normal(0.0, sigma.leg_lengths, 6),
            readings[0] + self.rng.normal(0.0, 1.0, 4) * sigma.readings(),
            PAIRS_PER_POSTURE,
            k * 1_000_000_000,
            np.full(6, DEFAULT_SENSOR_NOISE.leg_lengths),
            DEFAULT_SENSOR_NOISE.readings(),
        )
        return [RowReady(k, pose, sample)]


class FakeHost:
    """A plain Python :class:`RunHost` around a :class:`FakePlatform` (no rclpy)."""

    def __init__(self, streams_hz=None, status_after_s=0.0, **platform):
        """``streams_hz``: the streams also speak at this rate while the run waits (a round of
        messages per period, up to the wait's timeout); None: only once, before the run.
        ``status_after_s``: the platform's status publisher appears at this stream time (s)."""
        self.platform = FakePlatform(**platform)
        self.truth = self.platform.truth
        self.recorder = FakeRecorder()
        self.progress_log = []
        self.delivered = []
        self.postures = PostureLink(
            lambda: asyncio.get_running_loop().create_future(),
            self.platform.commander,
            self.recorder,
            lambda event: None,
        )
        self.platform.link = self.postures
        self.stamp_s = 0.0  # the streams' latest stamp (s)

        async def wait_for(predicate, timeout_s):
            rounds = int(timeout_s * streams_hz) if streams_hz else 0
            for _ in range(rounds):
                if predicate():
                    break
                self.stamp_s += 1.0 / streams_hz
                self.platform.hear_every_topic(self.run.collection, self.stamp_s)
            return WAIT_OK if predicate() else WAIT_TIMEOUT

        async def await_thread(concurrent_future):
            return concurrent_future.result()

        async def in_thread(function, *args, **kwargs):
            return function(*args, **kwargs)

        def selection(settings):
            future = concurrent.futures.Future()
            future.set_result(postures.choose_postures(*postures.selection_arguments(settings)))
            return future

        async def deliver_result(settings, geometry, accepted, rigid):
            self.delivered.append((geometry, accepted))
            return True, 'applied to the fake platform'

        self.host = RunHost(
            name=(names.NODE_CALIBRATOR, '/'),
            log=logging.getLogger('test_run_flow'),
            command_publishers=lambda: [],
            command_subscribers=lambda: 1,
            status_publishers=lambda: int(self.stamp_s >= status_after_s),
            recorder=self.recorder,
            postures=self.postures,
            wait_for=wait_for,
            in_thread=in_thread,
            await_thread=await_thread,
            selection=selection,
            progress=lambda index, phase, message='', *_, **__: self.progress_log.append(
                (index, phase, message)
            ),
            deliver_result=deliver_result,
            shutting_down=lambda: False,
        )

    def serve(self, settings):
        """One run: ``(success, message)``."""
        run = CalibrationRun(self.host, settings, False)
        self.platform.hear_every_topic(run.collection)
        self.run = run
        return asyncio.run(run.serve())

    @property
    def record(self):
        return self.run.record


def _settings(tmp_path, **values):
    return CalibratorSettings.from_values(
        {
            'output_root': str(tmp_path),
            'posture_count': 30,
            'pool_size': 120,
            'pairs_per_posture': PAIRS_PER_POSTURE,
            'write_report_plots': False,  # the tests are of the flow, not of the report
            **values,
        }
    )


def _state(run_directory):
    return json.loads((run_directory / STATE_FILE).read_text())


def test_a_plain_python_host_drives_a_whole_run(tmp_path):
    host = FakeHost()
    success, message = host.serve(_settings(tmp_path))

    assert success, message
    parsed = parse_response(message)
    assert 'applied to the fake platform' in parsed.summary
    ((geometry, accepted),) = host.delivered
    assert accepted.compensating.accepted  # the verdicts: the delivery applies the matching one
    # 30 postures of 10 samples at Table 3's first noise level: every parameter within 0.05 mm
    # (0.05 deg for gamma) of the truth; the nominal is off by millimetres.
    assert np.max(np.abs(parameter_errors(geometry, host.truth))) < 0.05
    assert np.max(np.abs(parameter_errors(default_geometry('nominal'), host.truth))) > 0.5
    run_directory = tmp_path / parsed.run_directory.rstrip('/').rsplit('/', 1)[-1]
    assert _state(run_directory)['phase'] == PHASE_DONE
    # The 30 selected postures and the default route's addition (auto: the reference revisit).
    commanded = 30 + _state(run_directory)['route_additions']['added_postures']
    assert commanded == 31
    assert len((run_directory / 'samples.csv').read_text().splitlines()) == 1 + commanded
    assert host.progress_log[-1][1] == names.PHASE_DONE
    calls = host.recorder.calls
    assert calls[0][0] == 'start' and calls[-1][0] == 'stop'
    assert calls[1:-1] == [('end', k, 'kept') for k in range(1, commanded + 1)]
    # The run ends recorded in the platform's history (a step of the run, not of the node).
    (indexed,) = history.runs(history.database_path(tmp_path))
    assert indexed['run_dir'] == str(run_directory) and indexed['kind'] == 'calibration'


def test_each_row_records_its_approach_directions_and_auto_keeps_the_plain_model(tmp_path):
    """The rows carry each leg's approach direction over the sequence the run commanded (from
    the legs heard before it); ``auto`` on a platform the plain model describes keeps it."""
    host = FakeHost()
    settings = _settings(tmp_path, free_parameters=['auto'], payload_mass=40.0)
    success, message = host.serve(settings)
    assert success, message
    assert 'model (auto): groups none' in message
    samples = host.record.directory.read_samples()
    commanded = np.asarray(host.record.state.poses)
    heard, _ = sensor_measurements(host.truth, np.array([[0.0, 0.0, 0.6, 0, 0, 0]]))
    legs = inverse_kinematics(settings.nominal, commanded)
    expected = approach_directions(legs, heard[0])
    np.testing.assert_array_equal(samples.directions, expected[samples.posture - 1])
    assert (samples.directions < 0).any() and (samples.directions > 0).any()
    result = json.loads(host.record.directory.file('result.json').read_text())
    assert result['effects']['model_choice']['groups'] == []
    ((geometry, _),) = host.delivered
    assert geometry.effects.none


def test_the_route_starts_from_the_platforms_current_posture(tmp_path):
    """The first planned move is from where the leg lengths say the platform is, not home (the
    plain model's route: no revisit after it)."""
    settings = _settings(tmp_path, free_parameters=['extended'])
    selection = postures.choose_postures(*postures.selection_arguments(settings))
    # A selected posture far from home: the route from it differs from the route from home.
    start = selection.poses[np.argmax(np.abs(selection.poses[:, 0]))]
    # The legs where a controller with the nominal geometry put them (platform_sim's).
    heard_legs = posture_leg_lengths(settings.nominal, start[None])[0]
    host = FakeHost(start_legs=heard_legs)
    success, message = host.serve(settings)
    assert success, message

    current, reason = postures.route_start(settings.nominal, heard_legs)
    assert reason == ''
    np.testing.assert_allclose(current, start, atol=1e-9)  # m, rad
    expected = postures.posture_route(settings, selection.poses, current)
    from_home = postures.posture_route(settings, selection.poses, home_pose())
    assert not np.array_equal(expected.order, from_home.order)
    commanded = np.asarray(host.record.state.poses)
    # The platform stands at a selected posture: commanded first, the device would not change
    # and the posture would be skipped, so it comes last.
    np.testing.assert_allclose(commanded[-1], start, atol=1e-12)
    np.testing.assert_allclose(commanded, selection.poses[expected.order], atol=1e-12)  # m, rad


def test_a_run_in_selection_order_commands_a_held_posture_last(tmp_path):
    """An ``auto`` run ends with a revisit of its first posture: a run of the same selection in
    selection order after it starts where the platform stands. Commanded first, that posture
    would leave the device readings unchanged and be skipped: it comes last, and the reference
    revisits are of the new first posture."""
    settings = _settings(tmp_path, free_parameters=['auto'], posture_order='selection')
    selection = postures.choose_postures(*postures.selection_arguments(settings))
    held = selection.poses[0]
    host = FakeHost(start_legs=posture_leg_lengths(settings.nominal, held[None])[0])
    success, message = host.serve(settings)
    assert success, message

    commanded = np.asarray(host.record.state.poses)
    legs = posture_leg_lengths(settings.nominal, np.vstack([held[None], commanded[:1]]))
    assert np.max(np.abs(legs[1] - legs[0])) > postures.HELD_TOLERANCE  # m: the readings change
    order = np.r_[np.arange(1, len(selection.poses)), 0]
    route = postures.effect_route(settings, selection.poses[order], held)
    np.testing.assert_allclose(commanded, route.poses, atol=1e-12)  # m, rad
    assert route.kind[-1] == 'reference'
    np.testing.assert_allclose(commanded[-1], selection.poses[1], atol=1e-12)


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
    success, message = host.serve(_settings(tmp_path))

    assert not success
    assert names.TOPIC_LVDT in message
    assert host.delivered == []
    (run_directory,) = [path for path in tmp_path.iterdir() if path.is_dir()]
    state = _state(run_directory)
    assert state['phase'] == PHASE_FAILED and names.TOPIC_LVDT in state['stop_reason']
    assert host.progress_log[-1][1] == names.PHASE_FAILED
    # The posture the failure ended gave no row: in progress, as the recording says.
    assert ('end', 6, 'in_progress') in host.recorder.calls


def test_a_posture_s_end_is_kept_before_the_run_sees_it():
    """The end comes in a message thread: the row (or skip) is kept, and its outcome noted,
    before the future the run awaits completes; a failure between two postures ends the next."""

    class Session:
        def __init__(self):
            self.ended = []

        def end_posture(self, event):
            self.ended.append(event)
            return event

    class Protocol:
        def command(self, posture, pose, command_id, now_ns):
            return []

    session, recorder = Session(), FakeRecorder()
    link = PostureLink(
        concurrent.futures.Future, lambda pose: ('7', 0, lambda: None), recorder, print
    )
    link.start(session, Protocol())
    pose = np.zeros(6)
    ended = link.command(1, pose)
    seen = []
    ended.add_done_callback(lambda _: seen.append((list(session.ended), list(recorder.calls))))
    skip = PostureSkipped(1, 'not settled within 10 s')
    thread = threading.Thread(target=link.feed, args=(lambda _: [skip],))
    thread.start()
    thread.join()
    assert ended.result() is skip
    assert seen == [([skip], [('end', 1, 'skipped')])]
    failure = TopicSilent(names.TOPIC_LVDT, 'waiting', 'silent')
    link.fail(failure)  # between two postures (a second source, a failed write)
    assert link.command(2, pose).result() is failure


def test_the_posture_link_sends_a_command_again_while_it_has_no_status():
    """The protocol's CommandAgain publishes the current command again (the same message, its
    id unchanged); once the platform answers, it is not sent again."""
    from gsp_calibrator.collection.protocol import CollectionProtocol

    class Session:
        def end_posture(self, event):
            return event

    sent = []
    link = PostureLink(
        concurrent.futures.Future,
        lambda pose: ('7', 0, lambda: sent.append('7')),
        FakeRecorder(),
        print,
    )
    link.start(Session(), CollectionProtocol(0.0025, 3, topic_timeout=2.0, settle_timeout=2.0))
    link.command(1, np.zeros(6))
    link.feed(lambda protocol: protocol.poll(400_000_000))
    assert sent == ['7']
    link.feed(lambda protocol: protocol.poll(500_000_000))
    link.feed(lambda protocol: protocol.poll(1_000_000_000))
    assert sent == ['7'] * 3
    moving = conversions.parse_status(conversions.make_status('7', names.STATE_MOVING))
    link.feed(lambda protocol: protocol.status(moving, 1_100_000_000))
    link.feed(lambda protocol: protocol.poll(2_000_000_000))
    assert sent == ['7'] * 3


def test_the_route_has_what_the_effect_groups_to_identify_need():
    """Reference revisits for thermal (and auto, which may choose it), none for the groups a
    route does not serve; each revisit is at the reference's pose."""
    settings = CalibratorSettings.from_values({'posture_count': 30, 'pool_size': 120})
    poses = postures.choose_postures(*postures.selection_arguments(settings)).poses
    for free in (['extended'], ['extended', 'joint_offsets']):
        settings = CalibratorSettings.from_values({'free_parameters': free})
        assert postures.effect_route(settings, poses, home_pose()) is None
    settings = CalibratorSettings.from_values({'free_parameters': ['auto'], 'payload_mass': 40.0})
    assert postures.route_effect_groups(settings.free_parameters) == ['backlash', 'thermal']
    route = postures.effect_route(settings, poses, home_pose())
    revisits = [m for m, kind in enumerate(route.kind) if kind == 'reference']
    # 30 postures: the reference first, revisited at the end (periodic revisits do not pay).
    assert revisits == [len(route.kind) - 1] and route.added_postures >= 1
    np.testing.assert_array_equal(route.poses[revisits], poses[:1])
    # What the default (auto) adds costs at most a tenth of the plain route's platform time
    # (here 1.06x; a revisit every 10 postures made it 1.2x, docs/platform_effects.md).
    assert route.total_s <= 1.1 * route.plain_s, (route.total_s, route.plain_s)
    assert not route.one_way_legs and route.added_s > 0.0
    additions = postures.route_additions(route, ['backlash', 'thermal'])
    assert additions['added_postures'] == route.added_postures
    assert '1 reference revisits' in postures.route_additions_line(additions)
    assert additions['sample_rate_hz'] == postures.PLAN_SENSOR_RATE_HZ  # none heard: gsp_plan's
    # Timed at the rate the run heard its streams at: each added posture samples longer at 50 Hz.
    heard = postures.effect_route(settings, poses, home_pose(), 50.0)
    np.testing.assert_array_equal(heard.poses, route.poses)
    longer = route.added_postures * settings.pairs_per_posture * (1 / 50.0 - 1 / 200.0)
    assert heard.added_s - route.added_s == pytest.approx(longer, rel=1e-9)
    additions = postures.route_additions(heard, ['backlash', 'thermal'], 50.0)
    assert 'samples at 50 Hz' in postures.route_additions_line(additions)


def test_an_auto_run_commands_the_reference_revisits_each_as_its_own_posture(tmp_path):
    """With ``auto`` the run commands the route with the effects' additions: each revisit of
    the reference is a posture of its own (state.json, samples.csv), and the progress, the
    response and result.json say what the additions cost."""
    host = FakeHost()
    settings = _settings(tmp_path, free_parameters=['auto'], payload_mass=40.0)
    success, message = host.serve(settings)
    assert success, message
    selection = postures.choose_postures(*postures.selection_arguments(settings))
    heard, _ = sensor_measurements(host.truth, np.array([[0.0, 0.0, 0.6, 0, 0, 0]]))
    start, _ = postures.route_start(settings.nominal, heard[0])
    ordered = selection.poses[postures.posture_route(settings, selection.poses, start).order]
    route = postures.effect_route(settings, ordered, start)
    commanded = np.asarray(host.record.state.poses)
    np.testing.assert_allclose(commanded, route.poses, atol=1e-12)  # m, rad
    samples = host.record.directory.read_samples()
    assert len(samples) == len(route.poses) == 30 + route.added_postures
    revisits = [m + 1 for m, kind in enumerate(route.kind) if kind == 'reference']
    assert len(revisits) == 1 and set(revisits) <= set(samples.posture.tolist())
    np.testing.assert_allclose(commanded[np.array(revisits) - 1], commanded[[0]], atol=0)
    result = json.loads(host.record.directory.file('result.json').read_text())
    additions = result['collection']['route_additions']
    assert additions['reference_revisits'] == 1
    assert additions['added_postures'] == route.added_postures
    line = postures.route_additions_line(additions)
    assert any(line == text for _, _, text in host.progress_log)
    assert line in message
    # The additions count among the postures commanded.
    total = len(route.poses)
    assert any(text.startswith(f'posture {total} of {total}') for _, _, text in host.progress_log)
    assert f'{total} posture(s) of {total} commanded' in message


def test_the_route_is_timed_at_the_rate_the_streams_are_heard_at(tmp_path):
    """The run hears its streams (their rate measured) before it plans the route: streams at
    50 Hz that have spoken once when the run starts time the route's additions at 50 Hz, not
    gsp_plan's 200 Hz."""
    host = FakeHost(streams_hz=50.0)
    settings = _settings(tmp_path, free_parameters=['auto'], payload_mass=40.0)
    success, message = host.serve(settings)
    assert success, message
    result = json.loads(host.record.directory.file('result.json').read_text())
    additions = result['collection']['route_additions']
    assert additions['sample_rate_hz'] == pytest.approx(50.0, rel=1e-6)
    assert 'samples at 50 Hz' in message
    assert _state(host.record.directory.path)['route_additions'] == additions


def test_a_platform_still_starting_is_waited_for_up_to_the_startup_timeout(tmp_path):
    """platform_sim started with the calibrator publishes its status 5 s (stream time) after
    the run starts, past topic_timeout (2 s) but within startup_timeout (10 s): the run goes on;
    one that takes 12 s fails naming the topic and the timeout."""
    settings = _settings(tmp_path, topic_timeout=2.0, startup_timeout=10.0)
    host = FakeHost(streams_hz=50.0, status_after_s=5.0)
    success, message = host.serve(settings)
    assert success, message
    late = FakeHost(streams_hz=50.0, status_after_s=12.0)
    success, message = late.serve(_settings(tmp_path / 'late', startup_timeout=10.0))
    assert not success
    assert f'topic {names.TOPIC_PLATFORM_STATUS} is silent: no publisher within 10 s' in message
    assert late.platform.commands == 0


def test_a_topic_never_heard_fails_the_run_naming_it_with_the_route_kept(tmp_path):
    """A sensor topic that never speaks: the run fails naming it once ``topic_timeout`` is
    over, nothing commanded; state.json keeps the planned route (failed, the reason) for a
    resume."""
    host = FakeHost(silent=[names.TOPIC_LVDT])
    settings = _settings(tmp_path, free_parameters=['auto'], payload_mass=40.0)
    success, message = host.serve(settings)
    assert not success
    assert f'topic {names.TOPIC_LVDT} is silent: no message within' in message
    assert host.platform.commands == 0
    state = _state(host.record.directory.path)
    assert state['phase'] == PHASE_FAILED and names.TOPIC_LVDT in state['stop_reason']
    assert len(state['poses']) == 30 + state['route_additions']['added_postures']
    assert host.progress_log[-1][1] == names.PHASE_FAILED


def test_a_resumed_auto_run_keeps_its_route_with_the_revisits(tmp_path):
    """A run that failed after 12 postures, resumed: it commands the rest of the augmented
    route it started (the revisits among them), not a new one, and keeps its record."""
    settings = _settings(tmp_path, free_parameters=['auto'], payload_mass=40.0)
    failed = FakeHost(failure_after=12)
    success, _ = failed.serve(settings)
    assert not success
    started = _state(failed.record.directory.path)
    assert started['route_additions']['reference_revisits'] == 1
    host = FakeHost(seed=1)
    run = CalibrationRun(host.host, settings, True)
    host.platform.hear_every_topic(run.collection)
    host.run = run
    success, message = asyncio.run(run.serve())
    assert success, message
    state = _state(host.record.directory.path)
    assert state['poses'] == started['poses'] and len(state['poses']) == 31
    assert state['route_additions'] == started['route_additions']
    # Rows 1-12 were kept; the resumed run commands postures 13-31 of the augmented route.
    np.testing.assert_allclose(host.platform.commanded, started['poses'][12:], atol=1e-12)
