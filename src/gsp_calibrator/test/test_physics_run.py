"""A calibration of the physics backend (docs/physics.md) through the three nodes, in one
process, at the calibrator's DEFAULTS (issue 34's done-when): platform_sim on MuJoCo with the
realistic preset's leg limits (the calibrator's own defaults), faster than real time
(``real_time_factor``, the nodes on its /clock), device_driver's physics backend. Only the
number of postures is the test's (few, to keep it short). The figures of the issue in one seed:
the truth (the result as the controller of the physics platform, commanded against reached)
within 1.3x the physics floor (the true geometry as the controller), the held-out accuracy
within 25 % of the truth or its 95 % interval holding it, no verdict that accepts a result whose
truth misses the requirement, the inclinometer's estimated noise within 1.5x its configured
value. With the settle rule off (``settle_lookback`` 0) the same run must miss them. At the
defaults of this commit both runs miss the floor (the rule-on case is an expected failure): the
rule does not yet make the difference the issue asks for."""

import math

import numpy as np
import pytest
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
    'samples_per_posture',
    'sync_tolerance',
    'topic_timeout',
    'settle_timeout',
    'free_parameters',
)


def run_figures(ros_context, tmp_path, settle_lookback):
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
            'settle_lookback': settle_lookback,
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


def misses(figures):
    """The issue's figures that ``figures`` miss (names with the values)."""
    true_mm, (low, high) = figures['true_mm'], figures['interval_mm']
    missed = []
    if not true_mm <= 1.3 * figures['floor_mm']:
        missed.append('truth over 1.3x the floor')
    if not (abs(figures['cv_mm'] - true_mm) <= 0.25 * true_mm or low <= true_mm <= high):
        missed.append('held out off the truth by over 25 %, its interval missing it')
    if figures['accepted_while_truth_misses']:
        missed.append('accepted while the truth misses the requirement')
    if not figures['inclinometer_noise_ratio'] <= 1.5:
        missed.append('inclinometer noise over 1.5x its configured value')
    return missed


@pytest.mark.parametrize(
    ('settle_lookback', 'expect_met'),
    [
        pytest.param(
            DEFAULTS['settle_lookback'],
            True,
            # Measured (16 postures, 10:25 UTC 2026-11-28): truth 0.093 mm against a floor of
            # 0.061 mm (1.54x), held out 0.046 mm (95 %: 0.022-0.088 mm), noise 1.02x, not
            # accepted. The compliance identified from few postures does not reach the floor of
            # legs that sag under their own mass (docs/physics.md): issue 34 stays open.
            marks=pytest.mark.xfail(strict=True, reason='issue 34: the defaults miss the floor'),
        ),
        # The settle rule off: expected to MISS the figures. Measured (10:30 UTC): truth
        # 0.081 mm (1.33x the floor), held out 0.043 mm (95 %: 0.020-0.081 mm), noise 1.36x,
        # accepted: it misses the floor only, as the run with the rule on does.
        (0.0, False),
    ],
    ids=['settle-rule-on', 'settle-rule-off-misses'],
)
def test_the_calibrator_at_its_defaults_meets_the_figures_on_the_physics_platform(
    ros_context, tmp_path, settle_lookback, expect_met
):
    figures = run_figures(ros_context, tmp_path, settle_lookback)
    missed = misses(figures)
    if expect_met:
        assert not missed, f'{missed}: {figures}'
    else:
        assert missed, f'the settle rule off met every figure: {figures}'
