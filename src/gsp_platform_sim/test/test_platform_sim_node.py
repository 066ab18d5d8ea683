"""In-process tests of the platform_sim node: a test node commands poses and listens."""

import dataclasses
import math

import gsp_testing
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from rclpy.parameter import Parameter

from gsp_kinematics.model.effect_groups import commanded_leg_readings
from gsp_kinematics.model.effects import IdentifiedEffects, PlatformEffects
from gsp_kinematics.model.geometry import (
    Limits,
    SensorErrors,
    default_geometry,
    geometry_to_parameters,
)
from gsp_kinematics.model.kinematics import forward_kinematics, home_pose, inverse_kinematics
from gsp_kinematics.model.real_pose import real_poses
from gsp_msgs_py import conversions, names
from gsp_msgs_py.health import OK, WARN
from gsp_msgs_py.parameter_specs import ConfigurationError
from gsp_platform_sim.platform_sim_node import PlatformSimNode

TRUE = default_geometry('true')
NOMINAL = default_geometry('nominal')
POSE = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])
TIMEOUT_S = 10.0  # generous: the machine may be loaded; tests finish as soon as they can


class Harness(gsp_testing.NodeHarness):
    """platform_sim plus a test node that commands poses and records what comes back."""

    def __init__(self, context, overrides=()):
        self.sim = PlatformSimNode(context=context, parameter_overrides=list(overrides))
        super().__init__(context, self.sim, 'platform_sim_test', TIMEOUT_S)
        self.statuses, self.leg_lengths, self.true_poses, self.markers = [], [], [], []
        self.subscribe(
            names.TOPIC_PLATFORM_STATUS, lambda m: self.statuses.append(conversions.parse_status(m))
        )
        self.subscribe(names.TOPIC_LEG_LENGTHS, self.leg_lengths.append)
        self.subscribe(names.TOPIC_TRUE_POSE, self.true_poses.append)
        self.subscribe(names.TOPIC_MARKERS, self.markers.append)
        self.command_pub = self.publisher(names.TOPIC_POSE_COMMAND)
        assert self.spin_until(
            lambda: (
                self.command_pub.get_subscription_count() > 0
                and self.leg_lengths
                and self.true_poses
            )
        ), 'no discovery'

    def command(self, pose=None, msg=None):
        """Publish a command (a pose, or a prepared message); returns its command id."""
        stamp = self.node.get_clock().now().to_msg()
        if msg is None:
            msg = conversions.pose_to_pose_stamped(pose, stamp, names.FRAME_BASE)
        msg.header.stamp = stamp
        self.command_pub.publish(msg)
        return conversions.command_id_from_stamp(stamp)

    def states(self, command_id):
        return [s for s in self.statuses if s.command_id == command_id]

    def wait_final(self, command_id):
        """The states of a command once it is settled or rejected."""
        assert self.spin_until(
            lambda: any(s.settled or s.rejected for s in self.states(command_id))
        ), self.statuses
        return self.states(command_id)

    def leg_lengths_after(self, count=5):
        """Leg lengths (m) of ``count`` messages stamped from now on (so published after
        everything observed so far, whatever is still in flight)."""
        now_ns = self.node.get_clock().now().nanoseconds

        def fresh():
            return [
                m
                for m in self.leg_lengths
                if conversions.stamp_to_nanoseconds(m.header.stamp) > now_ns
            ]

        assert self.spin_until(lambda: len(fresh()) >= count)
        return np.array([conversions.msg_to_leg_lengths(m) for m in fresh()[:count]])

    def call(self, client, request):
        assert self.spin_until(client.service_is_ready), 'parameter service not available'
        future = client.call_async(request)
        assert self.spin_until(future.done)
        return future.result()


harness = gsp_testing.harness_fixture(Harness)


def test_command_moves_then_settles_and_streams_the_new_posture(harness):
    command_id = harness.command(POSE)
    assert [s.state for s in harness.wait_final(command_id)] == ['moving', 'settled']
    moving, settled = harness.states(command_id)
    assert moving.level == 1 and settled.level == 0

    q = inverse_kinematics(NOMINAL, POSE[None])[0]
    measured = harness.leg_lengths_after(5)
    assert list(harness.leg_lengths[-1].name) == [f'leg_{i}' for i in range(1, 7)]
    assert harness.leg_lengths[-1].header.frame_id == names.FRAME_BASE
    np.testing.assert_allclose(measured, np.broadcast_to(q, measured.shape), atol=1e-5)
    assert np.std(measured - q) > 0  # noisy (default 1e-6 m)

    true_pose = conversions.pose_stamped_to_pose(harness.true_poses[-1])
    np.testing.assert_allclose(
        true_pose,
        forward_kinematics(TRUE, TRUE.sensors.true_leg_lengths(q)[None], POSE[None])[0],
        atol=1e-9,
    )

    # leg_lengths and true_pose come from one timer with one stamp (best effort: some may be
    # dropped, so wait for a few stamps received on both; separate clocks would share none).
    def common_stamps():
        legs = {conversions.stamp_to_nanoseconds(m.header.stamp) for m in harness.leg_lengths}
        poses = {conversions.stamp_to_nanoseconds(m.header.stamp) for m in harness.true_poses}
        return legs & poses

    assert harness.spin_until(lambda: len(common_stamps()) >= 5)


@pytest.mark.parametrize(
    'harness',
    [[Parameter('publish_rate', value=20.0), Parameter('use_sim_time', value=True)]],
    indirect=True,
)
def test_leg_lengths_are_stamped_exactly_at_the_timer_ticks(harness):
    # As a sensor sampling on its own clock: the stamps are the publish timer's scheduled ticks,
    # not the callback's clock readings. Under the simulated clock (steps off the 50 ms grid,
    # still between the reads of one callback), the ticks are on one grid to the ns, and the
    # instants the callbacks ran at are not.
    harness.leg_lengths.clear()
    assert harness.spin_until(lambda: len(harness.leg_lengths) >= 6)
    stamps = [conversions.stamp_to_nanoseconds(m.header.stamp) for m in harness.leg_lengths]
    assert len(set(stamps)) == len(stamps), stamps
    assert len(gsp_testing.grid_offsets(stamps, 50_000_000)) == 1, stamps


@pytest.mark.parametrize('harness', [[Parameter('settle_time', value=0.0)]], indirect=True)
def test_zero_settle_time_settles_at_once(harness):
    command_id = harness.command(POSE)
    assert [s.state for s in harness.wait_final(command_id)] == ['moving', 'settled']


FAST_DIAGNOSTICS = [Parameter('diagnostics_period', value=0.05)]


@pytest.mark.parametrize('harness', [FAST_DIAGNOSTICS], indirect=True)
def test_diagnostics_count_the_commands_their_rejections_and_settle_times(harness):
    name = 'platform_sim: commands'
    health = harness.wait_health(name)
    assert health.level == OK and health.values['commands'] == '0'
    assert harness.diagnostics.hardware_ids[name] == names.STATUS_HARDWARE_ID

    harness.wait_final(harness.command(POSE))
    health = harness.wait_health(name, lambda h: h.values['settled'] == '1')
    assert health.level == OK and health.values['accepted'] == '1'
    # From the acceptance to the settled status: settle_time (0.05 s) and a timer's delay.
    assert 0.05 <= float(health.values['settle_time_last_s']) < 5.0

    far = POSE + np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    rejected = harness.command(far)
    assert harness.wait_final(rejected)[-1].rejected
    health = harness.wait_health(name, lambda h: h.values['refused'] == '1')
    assert health.level == WARN and rejected in health.message
    assert health.values['rejected'] == '1' and health.values['commands'] == '2'
    assert health.values['last_rejection'].startswith(f'{rejected}: ')


def _bad_messages():
    nan_pose = conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE)
    nan_pose.pose.position.y = math.nan
    wrong_frame = conversions.pose_to_pose_stamped(POSE, None, 'world')
    not_unit = conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE)
    not_unit.pose.orientation.w = 3.0
    nan_quaternion = conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE)
    nan_quaternion.pose.orientation.x = math.nan
    return [
        (nan_pose, 'non-finite'),
        (wrong_frame, 'frame_id'),
        (not_unit, 'unit length'),
        (nan_quaternion, 'not finite'),
    ]


def test_bad_commands_are_rejected_with_a_reason_and_the_node_survives(harness):
    first = harness.command(POSE)
    harness.wait_final(first)
    legs_before = harness.leg_lengths_after(1)[0]

    unreachable = harness.command([0.0, 0.0, 2.5, 0.0, 0.0, 0.0])
    states = harness.wait_final(unreachable)
    assert [s.state for s in states] == ['rejected']
    assert 'stroke' in states[0].reason and states[0].level == 2
    for msg, words in _bad_messages():
        command_id = harness.command(msg=msg)
        states = harness.wait_final(command_id)
        assert [s.state for s in states] == ['rejected'], words
        assert words in states[0].reason

    # Nothing moved, and the node still obeys.
    np.testing.assert_allclose(harness.leg_lengths_after(1)[0], legs_before, atol=1e-5)
    pose = POSE + [0.02, 0.0, 0.0, 0.0, 0.0, 0.0]
    command_id = harness.command(pose)
    assert harness.wait_final(command_id)[-1].settled


@pytest.mark.parametrize('harness', [[Parameter('settle_time', value=60.0)]], indirect=True)
def test_a_new_command_supersedes_one_still_moving(harness):
    # The first command cannot settle before the second arrives, however slow the machine; the
    # settle time applies from the next command, so the second settles at once.
    first = harness.command(POSE)
    assert harness.spin_until(lambda: harness.states(first))
    assert harness.sim.set_parameters([Parameter('settle_time', value=0.0)])[0].successful
    second = harness.command(POSE + [0.01, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert [s.state for s in harness.wait_final(second)] == ['moving', 'settled']
    assert harness.spin_until(lambda: len(harness.states(first)) == 2)
    first_states = harness.states(first)
    assert [s.state for s in first_states] == ['moving', 'rejected']
    assert first_states[1].reason == f'superseded by command {second} before settling'


def test_bad_parameter_values_are_rejected_with_a_reason(harness):
    sim = harness.sim
    for name, value in [
        ('leg_lengths_noise_std', -1e-6),
        ('settle_time', -0.1),
        ('geometry.leg_offsets', [0.6] * 5),
        ('geometry.device_length', -0.85),
        ('geometry.limits.leg_stroke_min', 5.0),
        ('publish_rate', 100.0),
    ]:
        result = sim.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful, name
        assert result.reason, name
    assert (
        'geometry.leg_offsets'
        in sim.set_parameters([Parameter('geometry.leg_offsets', value=[0.6] * 5)])[0].reason
    )
    assert 'read-only' in sim.set_parameters([Parameter('publish_rate', value=100.0)])[0].reason
    assert sim.get_parameter('leg_lengths_noise_std').value == 1e-6
    assert sim.set_parameters([Parameter('leg_lengths_noise_std', value=0.0)])[0].successful
    measured = harness.leg_lengths_after(3)
    np.testing.assert_array_equal(measured, np.broadcast_to(measured[0], measured.shape))


def _calibrated_geometry():
    """A geometry off nominal in every group of the geometry.* parameters."""
    return NOMINAL.replace(
        base_joints=NOMINAL.base_joints + np.linspace(-1e-3, 1e-3, 18).reshape(6, 3),
        platform_joints=NOMINAL.platform_joints + np.linspace(1e-3, -1e-3, 18).reshape(6, 3),
        leg_offsets=NOMINAL.leg_offsets + [0.002, -0.001, 0.0005, 0.001, -0.0015, 0.003],
        device_length=NOMINAL.device_length + 0.002,
        inclinometer_axes_angle=NOMINAL.inclinometer_axes_angle + 0.01,
        limits=Limits(
            leg_stroke_min=0.01,
            leg_stroke_max=1.1,
            base_joint_max_angle=math.radians(64.0),
            platform_joint_max_angle=math.radians(74.0),
        ),
        sensors=SensorErrors(
            leg_gain_errors=[1e-3, -2e-3, 1.5e-3, -1e-3, 2e-3, -1.5e-3],
            inclinometer_offsets=[1e-3, -1e-3],
            encoder_offset=2e-3,
            lvdt_gain_error=-1e-3,
        ),
        # Identified effects (docs/platform_effects.md): micrometres at the legs.
        effects=IdentifiedEffects(
            np.concatenate(
                [np.full(6, 3e-8), np.full(6, 4e-6), np.full(6, 1e-8), np.full(6, 2e-5)]
            ),
            40.0,
            (0.0, 0.01, 0.05),
            100.0,
            (11.8,) * 6,  # heavy legs
        ),
    )


def _legs(geometry, pose):
    """Leg sensor readings (6,) the controller drives to for ``pose`` (m), its identified
    effects compensated (as arrived extending: the direction moves them by the backlash)."""
    return commanded_leg_readings(geometry, pose[None])[0]


@pytest.mark.parametrize('service', ['set_parameters', 'set_parameters_atomically'])
def test_controller_geometry_applied_through_the_parameter_service(harness, service):
    command_id = harness.command(POSE)
    harness.wait_final(command_id)
    calibrated = _calibrated_geometry()
    sent = geometry_to_parameters(calibrated)
    nominal = geometry_to_parameters(NOMINAL, all_effects=True)
    assert all(not np.array_equal(sent[name], nominal[name]) for name in sent), 'a group nominal'
    q_new = _legs(calibrated, POSE)
    # Each group the leg lengths depend on moves them by far more than the 10 um tolerance on its
    # own, so the published legs miss any one of them (the other groups: the node's geometry).
    for group in ('base_joints', 'platform_joints', 'leg_offsets'):
        without = calibrated.replace(**{group: getattr(NOMINAL, group)})
        assert np.max(np.abs(_legs(without, POSE) - q_new)) > 1e-4, group
    without_gains = calibrated.replace(
        sensors=dataclasses.replace(calibrated.sensors, leg_gain_errors=np.zeros(6))
    )
    assert np.max(np.abs(_legs(without_gains, POSE) - q_new)) > 1e-4

    parameters = [Parameter(name, value=value).to_parameter_msg() for name, value in sent.items()]
    service_type = SetParameters if service == 'set_parameters' else SetParametersAtomically
    client = harness.node.create_client(service_type, f'/{names.NODE_PLATFORM_SIM}/{service}')
    response = harness.call(client, service_type.Request(parameters=parameters))
    results = response.results if service == 'set_parameters' else [response.result]
    assert all(r.successful for r in results), [r.reason for r in results]

    # Every group reached the controller model, compared with the geometry sent (1e-12 in the
    # parameters' own units: m, rad, 1).
    applied = geometry_to_parameters(harness.sim._simulator.controller_geometry)
    for name, value in sent.items():
        np.testing.assert_allclose(applied[name], value, rtol=0, atol=1e-12, err_msg=name)

    # The legs hold until the next command, which uses the new geometry.
    q_old = _legs(NOMINAL, POSE)
    np.testing.assert_allclose(harness.leg_lengths_after(1)[0], q_old, atol=1e-5)
    command_id = harness.command(POSE)
    assert harness.wait_final(command_id)[-1].settled
    assert np.max(np.abs(q_new - q_old)) > 1e-3
    np.testing.assert_allclose(harness.leg_lengths_after(3)[-1], q_new, rtol=0, atol=1e-5)


def test_invalid_geometry_through_the_service_is_rejected(harness):
    parameters = geometry_to_parameters(NOMINAL)
    parameters['geometry.inclinometer_axes_angle'] = 4.0
    client = harness.node.create_client(
        SetParametersAtomically, f'/{names.NODE_PLATFORM_SIM}/set_parameters_atomically'
    )
    response = harness.call(
        client,
        SetParametersAtomically.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in parameters.items()]
        ),
    )
    assert not response.result.successful
    assert 'inclinometer_axes_angle' in response.result.reason
    np.testing.assert_array_equal(
        harness.sim.get_parameter('geometry.leg_offsets').value, NOMINAL.leg_offsets
    )


def test_markers_show_the_platform(harness):
    assert harness.spin_until(lambda: harness.markers)
    markers = harness.markers[-1].markers
    assert [len(m.points) for m in markers] == [7, 7, 12, 2]
    assert {m.header.frame_id for m in markers} == {names.FRAME_BASE}


@pytest.mark.parametrize(
    'overrides, words',
    [
        ([Parameter('publish_rate', value=0.0)], 'publish_rate'),
        ([Parameter('leg_lengths_noise_std', value=-1.0)], 'leg_lengths_noise_std'),
        (
            [Parameter('true_geometry_file', value='/nonexistent/geometry.yaml')],
            'true_geometry_file',
        ),
        ([Parameter('geometry.leg_offsets', value=[0.6, 0.6])], 'geometry.leg_offsets'),
        ([Parameter('effects.leg_stiffness', value=[-3e7] * 6)], 'effects.leg_stiffness'),
        ([Parameter('effects.backlash', value=[4e-6] * 5)], 'effects.backlash'),
        ([Parameter('effects.payload_mass', value=math.nan)], 'effects.payload_mass'),
        ([Parameter('effects.thermal_time_constant', value=0.0)], 'thermal_time_constant'),
    ],
)
def test_bad_start_up_parameters_are_a_clear_error(ros_context, overrides, words):
    with pytest.raises(ConfigurationError, match=words):
        PlatformSimNode(context=ros_context, parameter_overrides=overrides)


LIMITED = [
    Parameter('max_leg_speed', value=0.5),
    Parameter('max_leg_acceleration', value=2.0),
    Parameter('leg_lengths_noise_std', value=0.0),
    Parameter('settle_time', value=0.0),
]


@pytest.mark.parametrize('harness', [LIMITED], indirect=True)
def test_with_leg_limits_the_legs_follow_a_synchronised_profile_until_settled(harness):
    start = conversions.msg_to_leg_lengths(harness.leg_lengths[-1])
    target = inverse_kinematics(NOMINAL, POSE[None])[0]
    harness.leg_lengths.clear()
    command_id = harness.command(POSE)
    assert [s.state for s in harness.wait_final(command_id)] == ['moving', 'settled']
    # Everything received up to the settle, then the first readings after it.
    during = list(harness.leg_lengths)
    after = harness.leg_lengths_after(3)
    np.testing.assert_allclose(after, np.broadcast_to(target, after.shape), atol=1e-12)
    legs = np.array([conversions.msg_to_leg_lengths(m) for m in during])
    stamps = np.array([conversions.stamp_to_nanoseconds(m.header.stamp) for m in during]) * 1e-9
    order = np.argsort(stamps)
    legs, stamps = legs[order], stamps[order]
    # On the straight line from the start to the target (all legs at one fraction), 1 nm.
    span = target - start
    fraction = (legs - start) @ span / (span @ span)
    np.testing.assert_allclose(legs, start + fraction[:, None] * span, atol=1e-9)
    assert np.all(np.diff(fraction) >= -1e-12)
    assert np.any((fraction > 0.05) & (fraction < 0.95)), fraction  # seen under way
    # No leg faster than its limit (0.5 m/s, 1 mm/s of slack).
    speeds = np.abs(np.diff(legs, axis=0)) / np.maximum(np.diff(stamps), 1e-9)[:, None]
    assert np.max(speeds) <= 0.5 + 1e-3


#: A real platform with every effect but the thermal growth (whose pose moves with the clock).
EFFECTS = PlatformEffects(
    payload_mass=40.0,
    centre_of_mass=(0.01, 0.0, 0.05),
    leg_stiffness=np.full(6, 30e6),
    backlash=np.full(6, 4e-6),
    base_joint_offsets=np.full(6, 20e-6),
)


@pytest.mark.parametrize(
    'harness',
    [
        [Parameter(name, value=value) for name, value in EFFECTS.to_parameters('effects.').items()]
        + [Parameter('leg_lengths_noise_std', value=0.0)]
    ],
    indirect=True,
)
def test_the_true_pose_includes_the_effects_and_the_legs_read_the_command(harness):
    command_id = harness.command(POSE)
    assert harness.wait_final(command_id)[-1].settled
    q = inverse_kinematics(NOMINAL, POSE[None])[0]
    np.testing.assert_allclose(harness.leg_lengths_after(1)[0], q, atol=1e-12)
    home = inverse_kinematics(NOMINAL, home_pose()[None])[0]
    directions = np.where(q > home, 1.0, -1.0)[None]
    expected, ok = real_poses(TRUE, EFFECTS, q[None], POSE[None], directions)
    rigid = forward_kinematics(TRUE, TRUE.sensors.true_leg_lengths(q)[None], POSE[None])[0]
    true_pose = conversions.pose_stamped_to_pose(harness.true_poses[-1])
    assert ok[0] and np.linalg.norm(expected[0, :3] - rigid[:3]) > 5e-6
    np.testing.assert_allclose(true_pose, expected[0], atol=1e-12)
