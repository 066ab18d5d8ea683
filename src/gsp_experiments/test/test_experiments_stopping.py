"""A run that stops when it is good enough (gsp_kinematics.stopping) on the benches' path."""

import numpy as np
import pytest

from gsp_experiments.bench_sensor_errors import SAMPLES, SIGMAS
from gsp_experiments.bench_upkeep import UpkeepDesign, _pool_measurements
from gsp_kinematics import stopping
from gsp_kinematics.kinematics import home_pose
from gsp_kinematics.travel.motion import MotionLimits


@pytest.fixture(scope='module')
def setting():
    design = UpkeepDesign.default()
    legs, readings, reached = _pool_measurements(design, design.true, 3)
    pool = design.pool[reached]
    planned = list(range(30))
    return design, pool, planned, lambda i: (legs[reached][i], readings[reached][i])


def run(setting, rule):
    design, pool, planned, measure = setting
    rows = SIGMAS.averaged([SAMPLES])
    return stopping.run_to_requirement(
        design.nominal, pool, planned, measure, rows, rule, MotionLimits(), home_pose(), 'extended'
    )


def test_a_loose_requirement_stops_at_the_first_cross_validation(setting):
    rule = stopping.StoppingRule(required_position_mm=0.1, minimum_postures=20)
    found = run(setting, rule)
    assert found['met'] and found['postures'] == 20 and found['added'] == 0
    assert found['platform_time_s'] < found['fixed_plan_time_s']
    assert found['bound_mm'] <= 0.1 and found['history'][-1]['postures'] == 20


def test_an_unreachable_requirement_adds_postures_by_information_per_second(setting):
    rule = stopping.StoppingRule(required_position_mm=1e-9, minimum_postures=28, max_added=3)
    found = run(setting, rule)
    assert not found['met'] and found['added'] == 3 and found['postures'] == 33
    assert [step['postures'] for step in found['history']] == [28, 30, 32, 33]
    # Each added posture is new, and the time counts every move and dwell.
    assert found['platform_time_s'] > found['fixed_plan_time_s']
    assert np.isfinite(found['cross_validated_mm'])
