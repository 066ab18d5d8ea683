"""Pure tests of the simulated platform (no ROS)."""

import numpy as np
import pytest
from builtin_interfaces.msg import Time

from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import forward_kinematics, home_pose, inverse_kinematics
from gsp_platform_sim.markers import make_marker_array, platform_lines
from gsp_platform_sim.simulator import PlatformSimulator

TRUE = default_geometry('true')
NOMINAL = default_geometry('nominal')
POSE = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])


def make_simulator(leg_lengths_noise_std=0.0, seed=0, **kwargs):
    return PlatformSimulator(
        TRUE, NOMINAL, leg_lengths_noise_std, np.random.default_rng(seed), **kwargs
    )


def test_starts_at_home_through_the_controller():
    sim = make_simulator()
    q = inverse_kinematics(NOMINAL, home_pose()[None])[0]
    np.testing.assert_allclose(sim.leg_lengths, q, atol=1e-12)
    np.testing.assert_allclose(
        sim.true_pose,
        forward_kinematics(TRUE, TRUE.sensors.true_leg_lengths(q)[None], home_pose()[None])[0],
        atol=1e-10,
    )


def test_accepted_command_reaches_fk_of_true_at_ik_of_controller():
    sim = make_simulator()
    outcome = sim.command(POSE)
    assert outcome.accepted and outcome.reason == ''
    q = inverse_kinematics(NOMINAL, POSE[None])[0]
    expected = forward_kinematics(TRUE, TRUE.sensors.true_leg_lengths(q)[None], POSE[None])[0]
    np.testing.assert_allclose(outcome.commanded_leg_lengths, q, atol=1e-12)
    np.testing.assert_allclose(outcome.true_pose, expected, atol=1e-10)
    np.testing.assert_allclose(sim.true_pose, expected, atol=1e-10)
    # The real legs are (1 + kq_true) times the readings the controller drove them to.
    np.testing.assert_allclose(
        inverse_kinematics(TRUE, sim.true_pose[None])[0],
        TRUE.sensors.true_leg_lengths(q),
        atol=1e-9,
    )
    # The geometric errors of the default true platform move it by millimetres, not metres.
    error = np.linalg.norm(sim.true_pose[:3] - POSE[:3])
    assert 1e-5 < error < 0.02


@pytest.mark.parametrize(
    'pose, words',
    [
        ([0.0, 0.0, 2.5, 0.0, 0.0, 0.0], 'stroke'),
        ([0.0, 0.0, 1.0, 0.0, 1.4, 0.0], 'joint'),
        ([0.0, np.nan, 1.0, 0.0, 0.0, 0.0], 'not finite'),
        ([0.0, 0.0, np.inf, 0.0, 0.0, 0.0], 'not finite'),
        ([0.0, 0.0, 1.0], 'shape'),
    ],
)
def test_rejected_command_gives_reason_and_keeps_the_platform(pose, words):
    sim = make_simulator()
    before_pose, before_q = sim.true_pose, sim.leg_lengths
    outcome = sim.command(pose)
    assert not outcome.accepted
    assert words in outcome.reason
    assert outcome.commanded_leg_lengths is None
    np.testing.assert_array_equal(outcome.true_pose, before_pose)
    np.testing.assert_array_equal(sim.true_pose, before_pose)
    np.testing.assert_array_equal(sim.leg_lengths, before_q)


def test_singularity_guard():
    sim = make_simulator()
    sim.max_condition = 1.0
    outcome = sim.command(POSE)
    assert not outcome.accepted and 'singularity' in outcome.reason


def test_forward_kinematics_failure_is_a_rejection():
    # A "real" platform whose legs are 0.3 m longer: FK lands far from the command.
    far = TRUE.replace(leg_offsets=TRUE.leg_offsets + 0.3)
    with pytest.raises(ValueError, match='initial pose'):
        PlatformSimulator(far, NOMINAL, 0.0, np.random.default_rng(0))
    sim = make_simulator()
    sim._true_geometry = far  # swap the hardware under a running simulator
    outcome = sim.command(POSE)
    assert not outcome.accepted and 'forward kinematics' in outcome.reason


def test_leg_lengths_noise_std_is_honoured():
    sim = make_simulator(leg_lengths_noise_std=2e-6, seed=42)
    errors = np.stack([sim.measured_leg_lengths() for _ in range(20000)]) - sim.leg_lengths
    assert abs(errors.mean()) < 3 * 2e-6 / np.sqrt(errors.size)
    np.testing.assert_allclose(errors.std(axis=0), 2e-6, rtol=0.03)
    sim.leg_lengths_noise_std = 0.0
    np.testing.assert_array_equal(sim.measured_leg_lengths(), sim.leg_lengths)


def test_noise_is_reproducible_with_a_seed():
    a, b = make_simulator(1e-6, seed=7), make_simulator(1e-6, seed=7)
    np.testing.assert_array_equal(a.measured_leg_lengths(), b.measured_leg_lengths())


def test_new_controller_geometry_applies_from_the_next_command():
    sim = make_simulator()
    sim.command(POSE)
    held = sim.leg_lengths
    calibrated = NOMINAL.replace(leg_offsets=NOMINAL.leg_offsets + 0.002)
    sim.controller_geometry = calibrated
    np.testing.assert_array_equal(sim.leg_lengths, held)
    assert sim.command(POSE).accepted
    np.testing.assert_allclose(
        sim.leg_lengths, inverse_kinematics(calibrated, POSE[None])[0], atol=1e-12
    )
    np.testing.assert_allclose(sim.leg_lengths, held - 0.002, atol=1e-12)


def test_with_a_perfect_controller_the_platform_reaches_the_command():
    sim = PlatformSimulator(TRUE, TRUE, 0.0, np.random.default_rng(0))
    assert sim.command(POSE).accepted
    np.testing.assert_allclose(sim.true_pose, POSE, atol=1e-10)


def test_marker_lines():
    lines = platform_lines(NOMINAL, POSE)
    assert lines['base'].shape == lines['platform'].shape == (7, 3)
    np.testing.assert_array_equal(lines['base'][0], lines['base'][-1])
    np.testing.assert_array_equal(lines['platform'][0], lines['platform'][-1])
    leg_lengths = np.linalg.norm(lines['legs'][1::2] - lines['legs'][0::2], axis=1)
    np.testing.assert_allclose(
        leg_lengths - NOMINAL.leg_offsets, inverse_kinematics(NOMINAL, POSE[None])[0], atol=1e-12
    )
    np.testing.assert_allclose(lines['device_link'], [np.zeros(3), POSE[:3]])
    markers = make_marker_array(NOMINAL, POSE, Time(sec=1), 'gsp_base').markers
    assert [len(m.points) for m in markers] == [7, 7, 12, 2]
    assert len({(m.ns, m.id) for m in markers}) == 4
    assert all(m.header.frame_id == 'gsp_base' for m in markers)


def test_with_motion_limits_the_legs_move_from_where_they_are():
    from gsp_kinematics.model.motion import MotionLimits, move_time

    limits = MotionLimits(0.05, 0.2)
    sim = make_simulator(limits=limits)
    home_legs = sim.leg_lengths
    outcome = sim.command(POSE, now_s=100.0)
    target = inverse_kinematics(NOMINAL, POSE[None])[0]
    assert outcome.accepted and outcome.travel_s == pytest.approx(
        move_time(home_legs, target, limits), abs=1e-12
    )
    assert sim.moving
    np.testing.assert_allclose(sim.leg_lengths, home_legs, atol=0.0)  # not yet under way
    sim.update(100.0 + outcome.travel_s / 2)  # symmetric profile: half way
    np.testing.assert_allclose(sim.leg_lengths, (home_legs + target) / 2, atol=1e-12)
    # A new command starts from the legs' current lengths.
    halfway = sim.leg_lengths
    second = sim.command(home_pose(), now_s=100.0 + outcome.travel_s / 2)
    assert second.travel_s == pytest.approx(move_time(halfway, home_legs, limits), abs=1e-12)
    sim.update(1e6)
    assert not sim.moving
    np.testing.assert_allclose(sim.leg_lengths, home_legs, atol=0.0)
    np.testing.assert_allclose(sim.true_pose, second.true_pose, atol=0.0)
