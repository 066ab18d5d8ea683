"""Choosing the model from the data (gsp_kinematics.verdict.model_choice): the plain model on a platform
it describes, the effect's group on a platform that has it; which groups a run can try."""

import numpy as np
import pytest

from gsp_kinematics.effects.groups import EffectDesign
from gsp_kinematics.effects.model import PlatformEffects
from gsp_kinematics.geometry import default_geometry
from gsp_kinematics.kinematics import Workspace, sample_valid_postures
from gsp_kinematics.sensors.noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.validation import simulate_commands
from gsp_kinematics.verdict.model_choice import available_groups, choose_model

TRUE = default_geometry('true')
NOMINAL = default_geometry('nominal')
SIGMAS = DEFAULT_SENSOR_NOISE.averaged([10])
COMPLIANT = PlatformEffects(
    payload_mass=40.0, centre_of_mass=(0.0, 0.0, 0.05), leg_stiffness=np.full(6, 10e6)
)


def noisy_run(effects, count=45):
    workspace = Workspace(rotation_range=np.radians(30.0))
    poses = sample_valid_postures(NOMINAL, 70, np.random.default_rng(21), workspace)
    poses = poses[simulate_commands(TRUE, NOMINAL, poses, COMPLIANT).reachable][:count]
    times = np.arange(len(poses)) * 10.0
    run = simulate_commands(TRUE, NOMINAL, poses, effects, times)
    scale = np.concatenate([np.full(6, SIGMAS.leg_lengths), SIGMAS.readings()])
    noise = np.random.default_rng(4).normal(size=(len(poses), 10)) * scale
    design = EffectDesign(times, run.directions, 40.0, (0.0, 0.0, 0.05), times[-1])
    return run.leg_readings + noise[:, :6], run.device_readings + noise[:, 6:], design, poses


@pytest.mark.parametrize('truth, expected', [(None, ()), (COMPLIANT, ('compliance',))])
def test_auto_keeps_the_plain_model_or_frees_the_effect_the_platform_has(truth, expected):
    legs, readings, design, poses = noisy_run(truth)
    choice = choose_model(NOMINAL, legs, readings, SIGMAS, design, pose_guesses=poses, folds=4)
    assert choice.groups == expected, choice.to_dict()
    plain = choice.candidates[0]
    assert plain.groups == () and plain.chosen == (expected == ())
    assert sum(candidate.chosen for candidate in choice.candidates) == 1
    assert set(choice.result.geometry.effects.groups()) <= set(expected)
    if expected:
        best = next(c for c in choice.candidates if c.chosen)
        assert best.position_mm < 0.85 * plain.position_mm


def test_a_run_tries_only_the_groups_its_design_identifies():
    directions = np.ones((4, 6))
    directions[1] = -1.0
    full = EffectDesign(np.arange(4.0), directions, 40.0)
    assert available_groups(full, 4) == ['compliance', 'backlash', 'thermal', 'joint_offsets']
    one_way = EffectDesign(np.arange(4.0), np.ones((4, 6)), 0.0)
    assert available_groups(one_way, 4) == ['thermal', 'joint_offsets']
    assert available_groups(None, 4) == ['joint_offsets']
