"""Plans that can identify the effects (gsp_kinematics.planning.effect_plan): the reference revisits of
the thermal group, both approach directions of every leg for the backlash, and the Cramér-Rao
bound of each group against the identification's own covariance and a Monte Carlo."""

import numpy as np
import pytest

from gsp_kinematics.estimation.identification import Options, identify
from gsp_kinematics.estimation.verdict.model_choice import thermal_time_constant
from gsp_kinematics.model.effects import PlatformEffects, approach_directions
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import Workspace, sample_valid_postures
from gsp_kinematics.model.motion import MotionLimits, posture_leg_lengths
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.model.validation import simulate_commands, validate
from gsp_kinematics.planning.effect_plan import augment_route, group_identifiability

TRUE = default_geometry('true')
NOMINAL = default_geometry('nominal')
SIGMAS = DEFAULT_SENSOR_NOISE.averaged([10])
POSES = sample_valid_postures(
    NOMINAL, 40, np.random.default_rng(5), Workspace(rotation_range=np.radians(30.0))
)


def test_thermal_revisits_the_reference_every_n_postures_and_at_both_ends():
    route = augment_route(NOMINAL, POSES, ['thermal'], revisit_every=7, dwell_s=15.0)
    kinds = list(route.kind)
    assert [s for s, k in zip(route.source, kinds, strict=True) if k == 'plan'] == list(range(40))
    visits = [i for i, s in enumerate(route.source) if s == 0]
    assert visits[0] == 0 and visits[-1] == len(kinds) - 1
    gaps = np.diff(visits) - 1  # plan postures between two visits of the reference
    assert gaps.max() <= 7 and gaps[:-1].min() == 7
    assert np.allclose(route.poses[visits], POSES[0])
    # 15 s a posture, no travel time: each revisit costs one dwell.
    assert route.added_postures == len(visits) - 1
    assert route.added_s == pytest.approx(15.0 * route.added_postures)


def test_thermal_revisit_interval_in_seconds_bounds_the_time_between_visits():
    limits = MotionLimits(0.05, 0.2)
    route = augment_route(
        NOMINAL, POSES, 'thermal', revisit_interval_s=60.0, dwell_s=5.0, limits=limits
    )
    times = route.times_s[route.source == 0]
    assert len(times) >= 3
    # A revisit comes before the first plan posture measured 60 s after the last visit; that
    # posture's own move and dwell are at most one plain step later.
    steps = np.diff(augment_route(NOMINAL, POSES, [], dwell_s=5.0, limits=limits).times_s)
    assert np.diff(times).max() <= 60.0 + 2 * steps.max()
    assert route.added_s > 0.0 and route.total_s == pytest.approx(route.times_s[-1] + 5.0)


def test_backlash_makes_every_leg_arrive_from_both_directions():
    # Sorted by leg 1's length, leg 1 extends from posture to posture: one direction only.
    rising = POSES[np.argsort(posture_leg_lengths(NOMINAL, POSES)[:, 0])]
    plain = augment_route(NOMINAL, rising, [])
    assert 1 in plain.one_way_legs, plain.arrivals
    route = augment_route(NOMINAL, rising, ['backlash'], min_arrivals=3)
    assert route.one_way_legs == ()
    # The directions from the commanded legs of the route itself, recomputed independently.
    legs = posture_leg_lengths(NOMINAL, route.poses)
    directions = approach_directions(legs, posture_leg_lengths(NOMINAL, rising[:1])[0])
    assert np.array_equal(directions, route.directions)
    assert ((directions > 0).sum(axis=0) >= 3).all() and ((directions < 0).sum(axis=0) >= 3).all()
    assert [s for s, k in zip(route.source, route.kind, strict=True) if k == 'plan'] == list(
        range(40)
    )
    assert route.added_postures > 0


def test_the_planner_says_when_a_leg_cannot_arrive_both_ways():
    route = augment_route(NOMINAL, POSES[:1], ['backlash'])
    assert route.one_way_legs == (1, 2, 3, 4, 5, 6)


def _noisy(run, rng):
    scale = np.concatenate([np.full(6, SIGMAS.leg_lengths), SIGMAS.readings()])
    noise = rng.normal(size=(len(run.leg_readings), 10)) * scale
    return run.leg_readings + noise[:, :6], run.device_readings + noise[:, 6:]


@pytest.mark.parametrize('group', ['compliance', 'backlash', 'thermal', 'joint_offsets'])
def test_the_plan_bound_is_the_identification_covariance(group):
    route = augment_route(NOMINAL, POSES, [group], dwell_s=15.0)
    design = route.design(40.0, (0.0, 0.0, 0.05))
    entry = group_identifiability(NOMINAL, route.poses, design, group, SIGMAS, 'extended')
    assert entry['identifiable'], entry
    # The identification's own (analytic) Jacobian at the truth, noise free.
    run = simulate_commands(TRUE, TRUE, route.poses, None, route.times_s)
    result = identify(
        TRUE,
        run.leg_readings,
        run.device_readings,
        SIGMAS,
        free=['extended', group],
        pose_guesses=route.poses,
        effects=design,
    )
    own = [result.effects[name][1] for name in entry['names']]
    # Evaluated at the nominal geometry by the plan, at the truth by the identification.
    assert np.allclose(entry['crb_std'], own, rtol=0.05), (entry['crb_std'], own)


def test_the_backlash_bound_matches_a_monte_carlo():
    route = augment_route(NOMINAL, POSES, ['backlash'], dwell_s=15.0)
    design = route.design()
    entry = group_identifiability(TRUE, route.poses, design, 'backlash', SIGMAS, 'extended')
    effects = PlatformEffects(backlash=np.full(6, 4e-6))
    run = simulate_commands(TRUE, TRUE, route.poses, effects, route.times_s)
    rng = np.random.default_rng(11)
    estimates = []
    for _ in range(40):
        legs, readings = _noisy(run, rng)
        result = identify(
            TRUE,
            legs,
            readings,
            SIGMAS,
            free=['extended', 'backlash'],
            pose_guesses=route.poses,
            effects=design,
        )
        estimates.append([result.effects[name][0] for name in entry['names']])
    spread = np.std(estimates, axis=0, ddof=1)
    # 40 draws: the sample deviation is within about 11 % (1 sigma) of the true one; 35 % is
    # three of those. The mean is the truth within 4 standard errors.
    assert np.allclose(spread, entry['crb_std'], rtol=0.35), (spread, entry['crb_std'])
    assert np.all(np.abs(np.mean(estimates, axis=0) - 4e-6) < 4 * spread / np.sqrt(40))


def _exact_run(effects, count=50):
    poses = POSES[simulate_commands(TRUE, NOMINAL, POSES, effects).reachable][:count]
    route = augment_route(NOMINAL, poses, ['thermal', 'backlash'], dwell_s=15.0)
    run = simulate_commands(TRUE, NOMINAL, route.poses, effects, route.times_s)
    return route, run


def test_compliance_is_recovered_at_the_geometry_being_estimated():
    # The legs' forces at the extreme postures are sensitive to the geometry: taken at the
    # nominal geometry (mm from the truth) they put the compliance 5-30 % off.
    effects = PlatformEffects(
        payload_mass=40.0, centre_of_mass=(0.0, 0.0, 0.05), leg_stiffness=np.full(6, 30e6)
    )
    route, run = _exact_run(effects)
    result = identify(
        NOMINAL,
        run.leg_readings,
        run.device_readings,
        SIGMAS,
        free=['extended', 'compliance'],
        pose_guesses=route.poses,
        effects=route.design(40.0, (0.0, 0.0, 0.05)),
    )
    values = [result.effects[f'compliance{leg}'][0] for leg in range(1, 7)]
    np.testing.assert_allclose(values, 1.0 / 30e6, rtol=1e-3)


def test_a_first_order_warming_is_identified_with_its_time_constant():
    effects = PlatformEffects(temperature_rise=np.full(6, 1.5), thermal_time_constant=300.0)
    route, run = _exact_run(effects)
    data = (run.leg_readings, run.device_readings, SIGMAS, route.poses, route.design(), None)
    tau, costs = thermal_time_constant(
        NOMINAL, data, ['extended'], ['thermal'], (0.0, 150.0, 300.0, 600.0), Options()
    )
    assert tau == 300.0 and costs[300.0] < 1e-6 * min(costs[0.0], costs[600.0]), costs
    design = route.design(thermal_time_constant_s=300.0)
    result = identify(
        NOMINAL,
        run.leg_readings,
        run.device_readings,
        SIGMAS,
        free=['extended', 'thermal'],
        pose_guesses=route.poses,
        effects=design,
    )
    values = [result.effects[f'strain_rate{leg}'][0] for leg in range(1, 7)]
    # The initial strain rate of a 1.5 K rise in 300 s of steel (12e-6 /K).
    np.testing.assert_allclose(values, 12e-6 * 1.5 / 300.0, rtol=1e-3)
    # The geometry is the one at the reference instant: the platform there, uncompensated.
    later = validate(
        TRUE, result.geometry, POSES[-10:], effects, np.full(10, design.reference_time_s)
    )
    assert later['position_mm_mean'] < 1e-4, later
