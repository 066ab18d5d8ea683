"""The physics section's checks (:func:`gsp_bench.physics.seed_checks`): what the calibrator
must reach on the physics platform, judged on each seed's figures (``make bench`` runs the
seeds; no node here)."""

import math

import numpy as np

import gsp_bench.physics

GOOD = {
    'true_mm': 0.004,
    'verdict_met_truth_misses': False,
    'inclinometer_noise_ratio': 1.0,
}


def test_every_check_passes_on_seeds_that_meet_them():
    checks = gsp_bench.physics.seed_checks([GOOD, dict(GOOD, true_mm=0.19)])
    assert checks == dict.fromkeys(checks, True) and len(checks) == 4


def test_each_check_fails_on_one_seed_that_misses_it():
    defects = {
        'not_accepted_while_truth_misses': {'verdict_met_truth_misses': True},
        'inclinometer_noise_within_1_5x': {'inclinometer_noise_ratio': 1.6},
        'true_below_0_2_mm': {'true_mm': 0.2},
    }
    for check, defect in defects.items():
        checks = gsp_bench.physics.seed_checks([GOOD, dict(GOOD, **defect)])
        assert [key for key, met in checks.items() if not met] == [check], (check, checks)


def test_a_failed_seed_or_no_seed_fails():
    failed = {'seed': 1, 'failure': 'platform joint 6 angle 83.0 deg above 80.0 deg'}
    assert not gsp_bench.physics.seed_checks([GOOD, failed])['no_failed_seed']
    assert not any(gsp_bench.physics.seed_checks([failed]).values())
    assert not any(gsp_bench.physics.seed_checks([]).values())


def test_the_quick_mode_runs_a_seed_whose_postures_the_physics_platform_holds():
    """Seed 0's 14 postures (chosen under the nominal geometry) include one the true platform
    cannot hold, which failed the quick run; the quick mode takes the first seed without one."""
    from gsp_calibrator.run.postures import choose_postures, selection_arguments
    from gsp_calibrator.settings import CalibratorSettings
    from gsp_kinematics.model.geometry import default_geometry
    from gsp_platform_sim.physics import PhysicsSimulator

    def refused(seed):
        settings = CalibratorSettings.from_values({'posture_count': 14, 'seed': seed})
        simulator = PhysicsSimulator(default_geometry('true'), settings.nominal)
        poses = choose_postures(*selection_arguments(settings)).poses
        return [pose for pose in poses if not simulator.command(pose).accepted]

    (seed,) = gsp_bench.physics.held_seeds(1, gsp_bench.physics.QUICK_POSTURES)
    assert refused(0) and not refused(seed)


def test_poses_at_rest_are_the_rest_poses_and_nan_where_refused():
    from gsp_kinematics.model.geometry import default_geometry
    from gsp_kinematics.model.kinematics import home_pose
    from gsp_platform_sim.physics import PhysicsSimulator
    from gsp_platform_sim.physics_model import PhysicalParameters

    true = default_geometry('true')
    pose = home_pose() + [0.004, -0.003, 0.005, 0.004, -0.003, 0.006]
    rigid_no_load = PhysicalParameters(leg_stiffness=math.inf, gravity=False)
    sim = PhysicsSimulator(true, true, rigid_no_load)
    unreachable = home_pose() + [0.0, 0.0, 2.0, 0.0, 0.0, 0.0]
    reached = gsp_bench.physics.poses_at_rest(sim, np.stack([pose, unreachable, home_pose()]))
    assert np.all(np.isnan(reached[1]))
    np.testing.assert_allclose(reached[[0, 2]], np.stack([pose, home_pose()]), atol=1e-6)
