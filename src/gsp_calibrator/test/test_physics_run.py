"""A calibration of the physics backend (docs/physics.md) through the three nodes, in one
process, at the calibrator's DEFAULTS (issue 34): platform_sim on MuJoCo with the realistic
preset's leg limits (the calibrator's own defaults), faster than real time (``real_time_factor``,
the nodes on its /clock), device_driver's physics backend. Only the number of postures is the
test's (few, to keep it short). Checked in one seed: the run succeeds through the physics, the
verdict does not accept a result whose truth (the result as the controller of the physics
platform, commanded against reached) misses the requirement, and the inclinometer's estimated
noise is within 1.5x its configured value (the rest rule waits out the ringing). Not checked,
as the defaults do not reach them at 16 postures (issue 34 stays open, docs/physics.md): the
truth within 1.3x the physics floor and the held-out accuracy within 25 % of the truth."""

import math

import numpy as np
from calibrator_suite import make_suite
from rclpy.parameter import Parameter

from gsp_calibrator.run.directory import RunDirectory
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.settings import DEFAULTS
from gsp_calibrator.tools.bench.end_to_end import read_run_directory
from gsp_calibrator.tools.bench.physics import true_position_mm
from gsp_kinematics.geometry import default_geometry, default_geometry_path
from gsp_kinematics.kinematics import sample_valid_postures

POSTURES = 16
CHECK_POSTURES = 8
#: The physics this many times faster than wall time (2 cores, shared).
REAL_TIME_FACTOR = 4.0
#: The calibrator's defaults the test suite's helpers change, back to the product's.
DEFAULT_NAMES = (
    'pool_size',
    'pairs_per_posture',
    'sync_tolerance',
    'topic_timeout',
    'settle_timeout',
    'free_parameters',
)


def run_figures(ros_context, tmp_path, rest_lookback):
    """The issue's figures of one calibration of the physics platform."""
    sim_time = [Parameter('use_sim_time', value=True)]
    physics = [Parameter('backend', value='physics')]
    suite, *_ = make_suite(
        ros_context,
        tmp_path,
        default_geometry_path('true'),
        calibrator_overrides={
            **{name: DEFAULTS[name] for name in DEFAULT_NAMES},
            'posture_count': POSTURES,
            'rest_lookback': rest_lookback,
            'use_sim_time': True,
        },
        platform_overrides=physics
        + [
            Parameter('real_time_factor', value=REAL_TIME_FACTOR),
            Parameter('max_leg_speed', value=DEFAULTS['max_leg_speed']),
            Parameter('max_leg_acceleration', value=DEFAULTS['max_leg_acceleration']),
        ],
        device_overrides=physics + sim_time,
    )
    try:
        response = suite.wait(suite.call())
    finally:
        suite.close()
    assert response.success, response.message
    directory = parse_response(response.message).run_directory
    result = read_run_directory(directory)['result']
    check = sample_valid_postures(
        default_geometry('nominal'), CHECK_POSTURES, np.random.default_rng(5)
    )
    true_mm = true_position_mm(RunDirectory(directory).read_geometry(), check)
    held_out = result['accuracy']['calibrated']['position_mm']
    low, high = held_out.get('mean_interval_95') or (math.nan, math.nan)
    acceptance = result.get('acceptance') or {}
    requirement = (acceptance.get('requirement') or {}).get('position_mm', math.nan)
    return {
        'true_mm': true_mm,
        'floor_mm': true_position_mm(default_geometry('true'), check),
        'cv_mm': held_out['mean'],
        'interval_mm': (low, high),
        'accepted_while_truth_misses': bool(acceptance.get('accepted')) and true_mm > requirement,
        'inclinometer_noise_ratio': result['noise_estimates']['inclinometer']['ratio'],
    }


def test_the_calibrator_at_its_defaults_on_the_physics_platform(ros_context, tmp_path):
    figures = run_figures(ros_context, tmp_path, DEFAULTS['rest_lookback'])
    assert not figures['accepted_while_truth_misses'], figures
    assert figures['inclinometer_noise_ratio'] <= 1.5, figures
    # Far better than the nominal geometry through the physics (tens of um against mm).
    assert figures['true_mm'] < 0.2, figures
