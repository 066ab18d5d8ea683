"""The simulated platform with effects (docs/platform_effects.md): its real pose includes them,
its leg readings stay what the actuators read (pure, no ROS)."""

import math

import numpy as np

from gsp_kinematics.model.effects import REALISTIC, IdentifiedEffects, PlatformEffects
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import forward_kinematics_masked, inverse_kinematics
from gsp_kinematics.model.motion import MotionLimits
from gsp_kinematics.model.real_pose import real_poses
from gsp_platform_sim.simulator import PlatformSimulator

TRUE = default_geometry('true')
NOMINAL = default_geometry('nominal')
POSE = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])
ABOVE = POSE + [0, 0, 0.05, 0, 0, 0]  # every leg longer
BELOW = POSE - [0, 0, 0.05, 0, 0, 0]  # every leg shorter
START_S = 1.7e9  # a ROS clock


def make(effects, **kwargs):
    return PlatformSimulator(TRUE, NOMINAL, effects=effects, start_s=START_S, **kwargs)


def test_without_effects_the_pose_is_the_rigid_forward_kinematics_bit_for_bit():
    for effects in (None, PlatformEffects()):
        sim = make(effects)
        outcome = sim.command(POSE, START_S + 1.0)
        q = inverse_kinematics(NOMINAL, POSE[None])[0]
        rigid, _ = forward_kinematics_masked(
            TRUE, TRUE.sensors.true_leg_lengths(q)[None], POSE[None]
        )
        np.testing.assert_array_equal(outcome.true_pose, rigid[0])
        sim.update(START_S + 1e4)
        np.testing.assert_array_equal(sim.true_pose, rigid[0])


def leg_span(pose):
    """Joint-to-joint distances (6,) of the real platform at ``pose`` (no joint offsets)."""
    return inverse_kinematics(TRUE, pose[None])[0] + TRUE.leg_offsets


def test_backlash_depends_on_the_direction_each_leg_arrives_from():
    backlash = np.full(6, 4e-6)
    sim = make(PlatformEffects(backlash=backlash))
    readings = sim.command(POSE, START_S).commanded_leg_lengths
    rigid = TRUE.leg_offsets + TRUE.sensors.true_leg_lengths(readings)
    sim.command(ABOVE, START_S)
    down = sim.command(POSE, START_S).true_pose  # retracting: longer by backlash / 2
    np.testing.assert_allclose(leg_span(down), rigid + backlash / 2, atol=1e-12)
    sim.command(BELOW, START_S)
    up = sim.command(POSE, START_S).true_pose  # extending: shorter by backlash / 2
    np.testing.assert_allclose(leg_span(up), rigid - backlash / 2, atol=1e-12)
    # The same command again moves no leg: each keeps the direction it last moved in.
    np.testing.assert_array_equal(sim.command(POSE, START_S).true_pose, up)


def test_a_superseded_move_takes_the_direction_from_where_the_legs_are():
    limits = MotionLimits(max_speed=0.01, max_acceleration=math.inf)  # legs linear in time
    sim = make(PlatformEffects(backlash=np.full(6, 4e-6)), limits=limits)
    sim.command(BELOW, START_S)
    sim.update(START_S + 100.0)
    away = sim.command(ABOVE, START_S + 100.0)
    sim.update(START_S + 100.0 + 0.25 * away.travel_s)  # a quarter of the way up
    # Commanded at half way, to about 37 % of the way: the legs are already past it, so they
    # arrive retracting (from where they were at the last update they would be extending).
    target = BELOW + 0.375 * (ABOVE - BELOW)
    sim.command(target, START_S + 100.0 + 0.5 * away.travel_s)
    np.testing.assert_array_equal(sim._directions, -np.ones(6))


def test_at_rest_the_pose_follows_the_thermal_growth():
    effects = PlatformEffects(temperature_rise=np.full(6, 1.5), thermal_time_constant=300.0)
    sim = make(effects)
    readings = sim.command(POSE, START_S).commanded_leg_lengths
    rigid = TRUE.leg_offsets + TRUE.sensors.true_leg_lengths(readings)
    np.testing.assert_allclose(leg_span(sim.true_pose), rigid, atol=1e-12)
    sim.update(START_S + 300.0)
    grown = rigid * (1.0 + 12e-6 * 1.5 * (1.0 - math.exp(-1.0)))
    np.testing.assert_allclose(leg_span(sim.true_pose), grown, atol=1e-12)
    np.testing.assert_array_equal(sim.leg_lengths, readings)  # the actuators read the same


def test_realistic_platform_pose_is_the_consistent_solution_and_readings_are_the_commands():
    sim = make(REALISTIC)
    sim.command(BELOW, START_S)
    outcome = sim.command(POSE, START_S + 60.0)
    q = inverse_kinematics(NOMINAL, POSE[None])[0]
    np.testing.assert_array_equal(outcome.commanded_leg_lengths, q)
    expected, ok = real_poses(TRUE, REALISTIC, q[None], POSE[None], np.ones((1, 6)), [60.0])
    assert ok[0]
    np.testing.assert_allclose(outcome.true_pose, expected[0], atol=1e-12)
    rigid, _ = forward_kinematics_masked(TRUE, TRUE.sensors.true_leg_lengths(q)[None], POSE[None])
    assert 1e-6 < np.linalg.norm(outcome.true_pose[:3] - rigid[0, :3]) < 1e-3


def test_a_controller_that_knows_the_effects_compensates_them():
    """The controller geometry carries identified effects (geometry.effects): it drives each leg
    so that the real platform reaches the command; without them it is off by micrometres."""
    truth = PlatformEffects(
        payload_mass=40.0,
        centre_of_mass=(0.0, 0.0, 0.05),
        leg_stiffness=np.full(6, 30e6),
        backlash=np.array([4, 3, 5, 4, 2, 6]) * 1e-6,
    )
    values = np.zeros(24)
    values[:6], values[6:12] = truth.leg_compliance, truth.backlash
    knowing = TRUE.replace(effects=IdentifiedEffects(values, 40.0, (0.0, 0.0, 0.05)))
    for controller, worst in ((TRUE, None), (knowing, 2e-8)):
        sim = PlatformSimulator(TRUE, controller, effects=truth)
        for pose in (BELOW, POSE, ABOVE, POSE):
            reached = sim.command(pose).true_pose
            error = np.linalg.norm(reached[:3] - pose[:3])
            if worst is None:
                assert error > 1e-6
            else:
                assert error < worst, (pose, error)
