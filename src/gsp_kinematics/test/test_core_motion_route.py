"""The motion model (trapezoidal and triangular synchronised moves) and the route (pure)."""

import math

import numpy as np
import pytest

from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import Workspace, home_pose, sample_valid_postures
from gsp_kinematics.model.motion import (
    LegMove,
    MotionLimits,
    leg_travel_time,
    move_time,
    posture_leg_lengths,
)
from gsp_kinematics.planning.route import (
    path_time,
    plan_route,
    shortest_path_order,
    spanning_tree_bound,
    travel_time_matrix,
)

NOMINAL = default_geometry('nominal')
LIMITS = MotionLimits(max_speed=0.05, max_acceleration=0.2)  # full speed after 12.5 mm


def test_a_long_move_is_a_trapezoid_and_a_short_one_a_triangle():
    # 0.1 m: 0.25 s up, 1.75 s at 0.05 m/s, 0.25 s down.
    assert leg_travel_time(0.1, LIMITS) == pytest.approx(0.1 / 0.05 + 0.05 / 0.2, abs=1e-12)
    # 5 mm < v^2/a = 12.5 mm: never reaches full speed; t = 2 sqrt(d / a).
    assert leg_travel_time(0.005, LIMITS) == pytest.approx(2 * math.sqrt(0.005 / 0.2), abs=1e-12)
    # The two agree where they meet.
    assert leg_travel_time(0.0125, LIMITS) == pytest.approx(0.5, abs=1e-12)
    assert leg_travel_time(0.0, LIMITS) == 0.0
    assert leg_travel_time(0.1, MotionLimits(0.05, math.inf)) == pytest.approx(2.0, abs=1e-12)
    assert MotionLimits.from_parameters(0.0, 0.0).instantaneous


def test_the_move_takes_the_slowest_legs_time_and_all_legs_arrive_together():
    start = np.zeros(6)
    end = np.array([0.1, -0.02, 0.0, 0.05, 0.003, -0.1])
    assert move_time(start, end, LIMITS) == pytest.approx(2.25, abs=1e-12)
    move = LegMove(start, end, LIMITS, start_s=10.0)
    assert move.duration_s == pytest.approx(2.25, abs=1e-12)
    times = 10.0 + np.linspace(0.0, 2.25, 901)
    legs = np.array([move.legs(t) for t in times])
    np.testing.assert_allclose(legs[-1], end, atol=0.0)
    # Every leg within its limits (finite differences: 1 µm/s and 1 mm/s^2 of slack).
    speed = np.diff(legs, axis=0) / np.diff(times)[:, None]
    assert np.max(np.abs(speed)) <= 0.05 + 1e-6
    acceleration = np.diff(speed, axis=0) / np.diff(times)[1:, None]
    assert np.max(np.abs(acceleration)) <= 0.2 + 1e-3
    # The slowest leg reaches full speed: the others run at their share of it.
    assert np.max(np.abs(speed[:, 0])) == pytest.approx(0.05, abs=1e-6)
    # Half way in time is half way in distance (a symmetric profile).
    np.testing.assert_allclose(move.legs(10.0 + 1.125), end / 2, atol=1e-12)
    # A stretched move keeps its shape and arrives at the asked time.
    slow = LegMove(start, end, LIMITS, 0.0, duration=4.5)
    np.testing.assert_allclose(slow.legs(2.25), end / 2, atol=1e-12)
    np.testing.assert_allclose(slow.legs(4.5), end, atol=0.0)


def test_a_triangular_move_peaks_at_sqrt_d_a():
    end = np.full(6, 0.005)
    move = LegMove(np.zeros(6), end, LIMITS)
    half = move.duration_s / 2
    step = 1e-6
    speed = (move.legs(half + step)[0] - move.legs(half - step)[0]) / (2 * step)
    assert speed == pytest.approx(math.sqrt(0.005 * 0.2), abs=1e-6)  # m/s


def random_postures(count, seed):
    return sample_valid_postures(NOMINAL, count, np.random.default_rng(seed), Workspace())


@pytest.mark.parametrize('seed', range(6))
def test_the_route_is_never_longer_than_the_given_order_nor_shorter_than_the_bound(seed):
    poses = random_postures(25, seed)
    legs = posture_leg_lengths(NOMINAL, np.vstack([home_pose()[None], poses]))
    times = travel_time_matrix(legs, LIMITS)
    order = shortest_path_order(times, 0)
    assert order[0] == 0 and sorted(order) == list(range(26))
    route_s = path_time(times, order)
    assert route_s <= path_time(times, np.arange(26)) + 1e-9
    assert route_s >= spanning_tree_bound(times) - 1e-9


def test_the_route_is_optimal_on_a_line():
    # Points on a line, given shuffled, from one end: the route walks them in order.
    positions = np.random.default_rng(3).permutation(np.arange(1, 12)) * 0.01
    legs = np.concatenate([[0.0], positions])[:, None] * np.ones(6)
    times = travel_time_matrix(legs, MotionLimits(0.05, math.inf))
    order = shortest_path_order(times, 0)
    assert path_time(times, order) == pytest.approx(0.11 / 0.05, abs=1e-9)
    # On a line the spanning tree is the path itself.
    assert spanning_tree_bound(times) == pytest.approx(0.11 / 0.05, abs=1e-9)


def test_plan_route_orders_the_poses_from_the_start_pose():
    poses = random_postures(15, 11)
    route = plan_route(NOMINAL, home_pose(), poses, LIMITS)
    assert sorted(route.order) == list(range(15))
    legs = posture_leg_lengths(NOMINAL, np.vstack([home_pose()[None], poses[route.order]]))
    expected = move_time(legs[:-1], legs[1:], LIMITS).sum()
    assert route.travel_s == pytest.approx(expected, abs=1e-9)
    assert route.lower_bound_s <= route.travel_s <= route.selection_order_s
