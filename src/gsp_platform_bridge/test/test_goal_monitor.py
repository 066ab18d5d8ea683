"""The bridge's goal verdicts and the emulated controller's trajectory following (pure)."""

import math

import numpy as np
import pytest

from gsp_kinematics.model.motion import MotionLimits
from gsp_msgs_py.names import STATE_REJECTED, STATE_SETTLED
from gsp_platform_bridge.goal_monitor import GoalMonitor, pose_path, waypoint_times
from gsp_platform_sim.trajectory_follower import TrajectoryFollower

LEGS = ('leg_1', 'leg_2', 'leg_3', 'leg_4', 'leg_5', 'leg_6')
TARGET = np.full(6, 0.1)


def monitor():
    return GoalMonitor(LEGS, position_tolerance=1e-5, settle_time=0.1, state_timeout=0.5)


def test_settled_once_every_leg_stays_within_tolerance_for_the_settle_time():
    goal = monitor()
    goal.observe(LEGS, np.zeros(6), 0.0)
    goal.start(TARGET, deadline_s=5.0)
    assert goal.check(0.0) is None
    goal.observe(LEGS, TARGET + 5e-6, 1.0)
    assert goal.check(1.0) is None  # within, not yet for settle_time
    goal.observe(LEGS, TARGET + 5e-5, 1.05)  # overshoot: the settle clock restarts
    assert goal.check(1.05) is None
    goal.observe(LEGS, TARGET, 1.1)
    assert goal.check(1.15) is None
    goal.observe(LEGS, TARGET, 1.25)
    assert goal.check(1.25) == (STATE_SETTLED, '') and not goal.active


@pytest.mark.parametrize(
    'names, now, words',
    [
        (LEGS, 6.0, 'goal not reached in time: leg_1 is 100.000 mm'),
        (('leg_1', 'leg_2', 'leg_3', 'leg_4', 'leg_5', 'wrist'), 1.0, 'joint leg_6 missing'),
        (LEGS, 1.6, 'stale /joint_states'),
    ],
)
def test_a_goal_is_rejected_with_the_reason(names, now, words):
    goal = monitor()
    goal.observe(LEGS, np.zeros(6), 0.0)
    goal.start(TARGET, deadline_s=5.0)
    goal.observe(names, np.zeros(6), 1.0)
    if now > 5.0:  # fresh states, still at the start
        goal.observe(names, np.zeros(6), now)
    verdict = goal.check(now)
    assert verdict[0] == STATE_REJECTED and words in verdict[1]


def test_state_problem_before_any_joint_state():
    assert 'no /joint_states' in monitor().state_problem(0.0)


def test_the_path_is_cut_into_steps_along_the_cartesian_line():
    start, goal = np.zeros(6), np.array([0.05, 0, 0, 0, 0, 0.1])
    path = pose_path(start, goal, position_step=0.01, angle_step=0.02)
    assert len(path) == 5
    np.testing.assert_allclose(path[-1], goal)
    np.testing.assert_allclose(np.diff(np.vstack([start, path]), axis=0)[:, 0], 0.01)
    assert len(pose_path(start, start, 0.01, 0.02)) == 1


def test_waypoint_times_are_the_motion_models_closed_form_times():
    # Longest leg moves 5 mm then 40 mm; v = 50 mm/s, a = 200 mm/s^2 (v^2/a = 12.5 mm).
    waypoints = np.array([[0.002] * 5 + [0.005], [0.03] * 5 + [0.045]])
    limits = MotionLimits(0.05, 0.2)
    triangle = 2.0 * math.sqrt(0.005 / 0.2)  # too short to reach the speed limit
    trapezoid = 0.04 / 0.05 + 0.05 / 0.2
    np.testing.assert_allclose(
        waypoint_times(np.zeros(6), waypoints, limits, 0.0),
        [triangle, triangle + trapezoid],
        atol=1e-5,  # s (the 1 us spacing that keeps the times increasing)
    )
    # A speed limit alone; a minimum duration stretches the whole.
    speed_only = MotionLimits(0.1, math.inf)
    np.testing.assert_allclose(
        waypoint_times(np.zeros(6), waypoints, speed_only, 0.0), [0.05, 0.45], atol=1e-5
    )
    np.testing.assert_allclose(
        waypoint_times(np.zeros(6), waypoints, speed_only, 0.9), [0.1, 0.9], atol=1e-5
    )
    # No limits: the minimum duration, spread over the points.
    no_limits = MotionLimits.from_parameters(0.0, 0.0)
    np.testing.assert_allclose(
        waypoint_times(np.zeros(6), waypoints, no_limits, 0.2), [0.1, 0.2], atol=1e-5
    )


def test_controller_sim_arrives_at_the_bridges_waypoint_times():
    """The bridge's times are the ones controller_sim's follower can keep at the same limits."""
    limits = MotionLimits(0.05, 0.2)
    waypoints = np.cumsum(np.full((8, 6), 0.01) * np.linspace(0.2, 1.0, 6), axis=0)
    times = waypoint_times(np.zeros(6), waypoints, limits, 0.0)
    follower = TrajectoryFollower(np.zeros(6), limits)
    follower.set_trajectory(list(zip(times, waypoints, strict=True)), 0.0)
    for time_s, target in zip(times, waypoints, strict=True):
        np.testing.assert_allclose(follower.step(time_s), target, atol=1e-9)  # m


def test_the_follower_interpolates_at_the_point_time_and_respects_the_speed_limit():
    follower = TrajectoryFollower(np.zeros(6), MotionLimits(0.1, math.inf))
    follower.set_trajectory([(1.0, np.full(6, 0.05))], 0.0)
    np.testing.assert_allclose(follower.step(0.5), 0.025)
    np.testing.assert_allclose(follower.step(1.0), 0.05)
    follower.set_trajectory([(0.1, np.full(6, 0.15))], 2.0)  # too fast: limited to 0.1 m/s
    np.testing.assert_allclose(follower.step(2.5), 0.1)
    np.testing.assert_allclose(follower.step(3.0), 0.15)
    with pytest.raises(ValueError, match='6 finite'):
        follower.set_trajectory([(1.0, [0.0] * 5)], 3.0)


def test_the_follower_stops_where_it_is_told_on_a_fault():
    follower = TrajectoryFollower(np.zeros(6), MotionLimits(0.1, math.inf))
    follower.set_trajectory([(1.0, np.full(6, 0.05)), (2.0, np.full(6, 0.1))], 0.0)
    follower.step(0.5)
    follower.abort(np.full(6, 0.01))
    np.testing.assert_allclose(follower.step(3.0), 0.01)
