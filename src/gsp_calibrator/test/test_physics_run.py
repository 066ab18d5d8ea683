"""A calibration of the physics backend (docs/physics.md) through the three nodes, in one
process: platform_sim on MuJoCo with the realistic preset's leg limits, device_driver's physics
backend, the calibrator at its defaults but for the number of postures (the fewest its model
needs, to keep the test short) and the settle timeout (its default, 5 s, is shorter than a move
at its own default leg limits). The result, applied as the controller of the physics platform,
lands it much closer to commanded workspace postures than the nominal geometry did. The legs
move five times faster than the realistic preset's (the physics is the same; the test is
shorter). Whether the result meets the requirement is the ``physics`` bench's figure
(docs/physics.md): the calibrator's defaults do not model the sag of legs that have a mass."""

import numpy as np
from calibrator_suite import make_suite
from rclpy.parameter import Parameter

from gsp_calibrator.run.directory import RunDirectory
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.settings import DEFAULTS
from gsp_calibrator.tools.demo_commands import MOVING_SETTLE_TIMEOUT_S
from gsp_kinematics.geometry import default_geometry, default_geometry_path
from gsp_kinematics.kinematics import sample_valid_postures
from gsp_kinematics.travel.motion import (
    REALISTIC_MAX_ACCELERATION,
    REALISTIC_MAX_SPEED,
    MotionLimits,
)
from gsp_platform_sim.physics import PhysicsSimulator, poses_at_rest

POSTURES = 16
CHECK_POSTURES = 8


def position_errors_mm(true, controller, poses):
    reached = poses_at_rest(PhysicsSimulator(true, controller), poses)
    return 1e3 * np.linalg.norm(reached[:, :3] - poses[:, :3], axis=1)


def test_the_calibrator_at_its_defaults_calibrates_the_physics_platform(ros_context, tmp_path):
    limits = MotionLimits(5 * REALISTIC_MAX_SPEED, 5 * REALISTIC_MAX_ACCELERATION)
    physics = [
        Parameter('backend', value='physics'),
    ]
    suite, *_ = make_suite(
        ros_context,
        tmp_path,
        default_geometry_path('true'),
        calibrator_overrides={
            'posture_count': POSTURES,
            'pool_size': 10 * POSTURES,
            'free_parameters': DEFAULTS['free_parameters'],
            'samples_per_posture': DEFAULTS['samples_per_posture'],
            # A move at the legs' limits takes seconds: the wait the demo gives moving legs.
            'settle_timeout': MOVING_SETTLE_TIMEOUT_S,
            'apply_result': True,
        },
        platform_overrides=physics
        + [
            Parameter('max_leg_speed', value=limits.max_speed),
            Parameter('max_leg_acceleration', value=limits.max_acceleration),
        ],
        device_overrides=physics,
    )
    try:
        response = suite.wait(suite.call())
    finally:
        suite.close()
    assert response.success, response.message
    run = RunDirectory(parse_response(response.message).run_directory)
    assert len(run.read_samples()) >= POSTURES - 1
    true, nominal = default_geometry('true'), default_geometry('nominal')
    check = sample_valid_postures(nominal, CHECK_POSTURES, np.random.default_rng(5))
    before = position_errors_mm(true, nominal, check)
    after = position_errors_mm(true, run.read_geometry(), check)
    assert np.all(np.isfinite(after))
    # mm: the nominal is millimetres off; the calibrated geometry 0.1 mm (seed 0: 0.103 mm,
    # the held-out accuracy said 0.016 mm: the unmodelled sag)
    assert np.mean(after) < 0.2 and np.mean(after) < np.mean(before) / 20.0
