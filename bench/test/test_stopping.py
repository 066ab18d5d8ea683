"""A run that stops when it is good enough (gsp_bench.stopping_run) on the benches' path."""

import math

import numpy as np
import pytest

from gsp_bench import stopping_run
from gsp_bench.sensor_errors import SAMPLES, SIGMAS
from gsp_bench.upkeep import UpkeepDesign, _pool_measurements
from gsp_kinematics.estimation.identifiability import posture_information
from gsp_kinematics.estimation.identification import resolve_free
from gsp_kinematics.model.kinematics import home_pose
from gsp_kinematics.model.motion import MotionLimits, move_time, posture_leg_lengths
from gsp_kinematics.upkeep import stopping

ROWS = SIGMAS.averaged([SAMPLES])


@pytest.fixture(scope='module')
def setting():
    design = UpkeepDesign.default()
    legs, readings, reached = _pool_measurements(design, design.true, 3)
    pool = design.pool[reached]
    return design, pool, legs[reached], readings[reached]


def run(setting, rule, planned=range(30)):
    design, pool, legs, readings = setting
    measured = []

    def rows(indices):
        return legs[indices], readings[indices]

    found = stopping_run.run_to_requirement(
        posture_leg_lengths(design.nominal, pool),
        list(planned),
        lambda index, elapsed: measured.append((index, elapsed)),
        stopping_run.core_judge(design.nominal, pool, rows, ROWS, 'extended'),
        lambda result: posture_information(result.geometry, pool, ROWS, resolve_free('extended')),
        rule,
        MotionLimits(),
        posture_leg_lengths(design.nominal, home_pose()[None])[0],
    )
    return found, measured


def test_a_loose_requirement_stops_at_the_first_judgement(setting):
    rule = stopping.StoppingRule(required_position_mm=0.1, minimum_postures=20)
    found, measured = run(setting, rule)
    assert found['met'] and found['postures'] == 20 and found['added'] == 0
    assert found['platform_time_s'] < found['fixed_plan_time_s']
    assert found['bounds']['position_bound_mm'] <= 0.1 and found['history'][-1]['postures'] == 20
    # The platform time grows with each posture measured, and is the last one's.
    times = [elapsed for _, elapsed in measured]
    assert np.all(np.diff(times) > 0) and times[-1] == found['platform_time_s']


def test_an_unreachable_requirement_adds_postures_by_information_per_second(setting):
    rule = stopping.StoppingRule(required_position_mm=1e-9, minimum_postures=28, max_added=3)
    found, measured = run(setting, rule)
    assert not found['met'] and found['added'] == 3 and found['postures'] == 33
    assert [step['postures'] for step in found['history']] == [28, 30, 32, 33]
    added = found['indices'][30:]
    assert len(set(found['indices'])) == 33 and not set(added) & set(range(30))
    assert found['platform_time_s'] > found['fixed_plan_time_s']
    assert math.isfinite(found['bounds']['position_mm'])


def test_an_addition_is_the_most_information_per_second():
    # Two candidates give the same information; the nearer one (less travel) is chosen, and a
    # farther one is chosen when it gives enough more information to be worth its travel.
    limits = MotionLimits()
    legs = np.array([[0.70] * 6, [0.80] * 6, [0.71] * 6])
    seconds = np.asarray(move_time(legs[0], legs, limits)) + stopping.DWELL_S
    base = np.eye(2)
    same = np.array([np.zeros((2, 2)), np.eye(2), np.eye(2)])
    assert stopping.best_addition(base, same, legs, legs[0], [0], limits, stopping.DWELL_S) == 2
    gain_near = np.log(4.0)  # log det(2 I) - log det(I) with the near one
    factor = math.exp(gain_near * seconds[1] / seconds[2] / 2) * 1.5  # worth more per second
    richer = np.array([np.zeros((2, 2)), (factor**2 - 1) * np.eye(2), np.eye(2)])
    assert stopping.best_addition(base, richer, legs, legs[0], [0], limits, stopping.DWELL_S) == 1


def test_the_informative_order_starts_with_the_most_information_per_second():
    limits = MotionLimits()
    legs = np.array([[0.80] * 6, [0.71] * 6, [0.72] * 6])
    information = np.array([np.eye(2), np.eye(2), np.diag([1.0, 1e-6])])
    order = stopping_run.informative_order(information, legs, np.full(6, 0.70), limits)
    assert sorted(order) == [0, 1, 2] and order[0] == 1
