"""The platform on MuJoCo (gsp_platform_sim.physics, docs/physics.md): it stands where the
kinematics says, its device reads eq 9 at rest, it sags under its load as the compliance model
predicts, and it rings after a move while the encoders are in position (pure, no ROS)."""

import dataclasses
import math

import numpy as np
import pytest

from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.effects import PlatformEffects
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.real_pose import real_poses
from gsp_platform_sim.physics import PhysicsSimulator
from gsp_platform_sim.physics_model import PhysicalParameters

TRUE = default_geometry('true')
NOMINAL = default_geometry('nominal')
POSE = home_pose() + [0.004, -0.003, 0.005, 0.004, -0.003, 0.006]
RIGID_NO_LOAD = PhysicalParameters(leg_stiffness=math.inf, gravity=False)


def rest_at(sim, pose, extra_s=1.0):
    """Command ``pose``, wait for the encoders in position, then ``extra_s`` more (s)."""
    outcome = sim.command(pose)
    assert outcome.accepted, outcome.reason
    while not sim.in_position:
        sim.advance(sim.time_s + 0.005)
    sim.advance(sim.time_s + extra_s)
    return outcome


def test_with_the_true_geometry_rigid_and_unloaded_it_stands_at_the_command():
    sim = PhysicsSimulator(TRUE, TRUE, RIGID_NO_LOAD)
    rest_at(sim, POSE)
    error = sim.true_pose - POSE
    assert np.max(np.abs(error[:3])) < 1e-6  # m
    assert np.max(np.abs(error[3:])) < 1e-6  # rad


def test_with_another_controller_it_stands_at_the_true_forward_kinematics():
    sim = PhysicsSimulator(TRUE, NOMINAL, RIGID_NO_LOAD)
    outcome = rest_at(sim, POSE)
    assert np.max(np.abs(outcome.true_pose - POSE)[:3]) > 1e-4  # the geometries differ
    assert np.max(np.abs(sim.true_pose - outcome.true_pose)[:3]) < 1e-6


def test_at_rest_the_device_reads_eq_9_at_the_simulated_pose():
    sim = PhysicsSimulator(TRUE, NOMINAL)
    rest_at(sim, POSE + [0.03, 0.02, 0.0, 0.0, 0.0, 0.1])
    expected = device_readings(TRUE, sim.true_pose[None])[0]
    # rad, rad, rad, m
    np.testing.assert_allclose(sim.device_readings(), expected, rtol=0.0, atol=1e-6)


def test_under_its_load_it_sags_about_as_the_compliance_model_predicts():
    load = PhysicalParameters(payload_mass=40.0)
    sims = [
        PhysicsSimulator(TRUE, TRUE, dataclasses.replace(load, gravity=gravity))
        for gravity in (False, True)
    ]
    for sim in sims:
        rest_at(sim, POSE)
    sag = sims[0].true_pose[2] - sims[1].true_pose[2]
    carried = load.platform_mass + load.payload_mass
    effects = PlatformEffects(
        payload_mass=carried,
        centre_of_mass=np.array(load.payload_center) * load.payload_mass / carried,
        leg_stiffness=np.full(6, load.leg_stiffness),
    )
    readings = sims[0].leg_lengths[None]
    model, converged = real_poses(TRUE, effects, readings, POSE[None])
    rigid, _ = real_poses(TRUE, None, readings, POSE[None])
    predicted = rigid[0, 2] - model[0, 2]
    assert converged[0] and predicted > 1e-6
    # The legs' own weight adds to the load the massless-leg model knows.
    assert 1.0 < sag / predicted < 2.5, (sag, predicted)


def test_after_a_move_the_encoders_are_in_position_while_the_platform_still_rings():
    sim = PhysicsSimulator(TRUE, NOMINAL)
    outcome = sim.command(POSE + [0.03, -0.02, 0.03, 0.0, 0.0, 0.02])
    sim.advance(sim.time_s + outcome.travel_s)
    while not sim.in_position:
        sim.advance(sim.time_s + 0.0005)
    poses, readings = [sim.true_pose], []
    for _ in range(10):
        sim.advance(sim.time_s + 0.005)
        poses.append(sim.true_pose)
        readings.append(sim.device_readings())
    path = np.sum(np.linalg.norm(np.diff(np.array(poses)[:, :3], axis=0), axis=1))
    assert path > 1e-6  # m travelled in the 50 ms after "in position": > 0.02 mm/s
    spread = np.ptp(np.array(readings)[:, :2], axis=0)
    assert np.max(spread) > 1e-5  # rad: the inclinometer feels the ringing
    sim.advance(sim.time_s + 2.0)
    rest = sim.device_readings()
    sim.advance(sim.time_s + 0.1)
    np.testing.assert_allclose(sim.device_readings(), rest, rtol=0.0, atol=1e-7)


def test_an_unreachable_command_is_refused_and_nothing_moves():
    sim = PhysicsSimulator(TRUE, NOMINAL)
    before = sim.true_pose
    outcome = sim.command(home_pose() + [0.0, 0.0, 2.0, 0.0, 0.0, 0.0])
    assert not outcome.accepted
    assert 'unreachable' in outcome.reason and 'stroke' in outcome.reason
    assert sim.in_position
    sim.advance(sim.time_s + 0.1)
    np.testing.assert_allclose(sim.true_pose, before, rtol=0.0, atol=1e-7)  # m, rad: at rest


def test_bad_physical_parameters_are_named():
    with pytest.raises(ValueError, match='leg_rod_mass'):
        PhysicalParameters(leg_rod_mass=0.0)
    with pytest.raises(ValueError, match='payload_mass'):
        PhysicalParameters(payload_mass=-1.0)


def test_a_command_the_real_platform_cannot_hold_is_refused_though_the_controller_accepts_it():
    from gsp_platform_sim.simulator import PlatformSimulator

    # The nominal controller's legs put the real platform past two platform joint stops and
    # near a singularity (condition ~300), where the compliant legs sag by centimetres.
    edge = np.array([0.376, -0.188, 1.048, 0.363, -0.493, 0.517])
    assert PlatformSimulator(TRUE, NOMINAL).command(edge).accepted
    sim = PhysicsSimulator(TRUE, NOMINAL)
    outcome = sim.command(edge)
    assert not outcome.accepted
    assert outcome.reason.startswith('the real platform cannot hold it: platform joint')
    # The refused command left the controller where it was: the next one moves as usual.
    rest_at(sim, POSE, extra_s=0.5)
    assert np.linalg.norm(sim.true_pose[:3] - POSE[:3]) < 0.01  # m (nominal controller)


def preset_max_condition():
    """``max_condition`` of the package's physics preset (config/physics_realistic.yaml)."""
    import pathlib

    import yaml

    path = pathlib.Path(__file__).parents[1] / 'config' / 'physics_realistic.yaml'
    return yaml.safe_load(path.read_text())['platform_sim']['ros__parameters']['max_condition']


#: Pairs of consecutive postures of default 60-posture plans where the real platform snapped:
#: the nominal controller's legs for the second put it at a condition number of 49.6 (seed 3: it
#: never comes in position) and of 28.7 (seed 4: the servos report in position 76 mm away).
SNAPS = {
    'seed 3, condition 49.6': (
        [-0.0334060, -0.3965572, 0.8578618, -0.1061830, -0.5120312, 0.4212123],
        [0.3595978, -0.3655890, 1.1043762, 0.4876390, -0.3922559, 0.6677015],
    ),
    'seed 4, condition 28.7': (
        [-0.1890095, -0.2807851, 1.0841913, 0.6090951, 0.0695728, -0.6611898],
        [0.3131249, -0.2215131, 1.0194787, 0.3998316, -0.4405969, 0.5606005],
    ),
}


@pytest.mark.parametrize('case', sorted(SNAPS))
def test_near_a_singularity_the_platform_snaps_and_the_preset_refuses_to_go_there(case):
    from gsp_kinematics.model.kinematics import pose_from_leg_readings
    from gsp_kinematics.model.motion import MotionLimits

    start, edge = SNAPS[case]
    sim = PhysicsSimulator(TRUE, NOMINAL, initial_pose=np.array(start), limits=MotionLimits())
    outcome = sim.command(np.array(edge))
    assert outcome.accepted  # within the default guard
    sim.advance(sim.time_s + outcome.travel_s + 5.0)
    # The legs are where the controller sent them, the platform is not: it sagged, then snapped.
    expected = pose_from_leg_readings(TRUE, sim.leg_lengths, outcome.true_pose)
    assert np.linalg.norm(sim.true_pose[:3] - expected[:3]) > 0.005  # m

    guarded = PhysicsSimulator(
        TRUE,
        NOMINAL,
        initial_pose=np.array(start),
        limits=MotionLimits(),
        max_condition=preset_max_condition(),
    )
    outcome = guarded.command(np.array(edge))
    assert not outcome.accepted
    assert 'near a singularity (condition number' in outcome.reason, outcome.reason


def test_a_simulation_behind_the_clock_slips_without_simulating_the_gap():
    sim = PhysicsSimulator(TRUE, NOMINAL, start_s=100.0)
    assert sim.time_s == pytest.approx(100.0, abs=1e-9)
    outcome = sim.command(POSE + [0.03, -0.02, 0.03, 0.0, 0.0, 0.02])
    sim.advance(100.3)
    moved = sim.true_pose
    sim.slip_to(110.0)  # 9.7 s the machine could not simulate: the clock jumps, the legs do not
    assert sim.time_s == pytest.approx(110.0, abs=1e-9)
    np.testing.assert_array_equal(sim.true_pose, moved)
    sim.slip_to(105.0)  # never back
    assert sim.time_s == pytest.approx(110.0, abs=1e-9)
    assert outcome.travel_s > 0.3 and not sim.in_position  # the move goes on from where it was
