"""Calibrator parameters: defaults, checks and settings (pure, no ROS)."""

import math
import subprocess
import sys

import pytest

from gsp_calibrator.settings import (
    DEFAULTS,
    PARAMETER_SPECS,
    PARAMETERS,
    CalibratorSettings,
    check_parameters,
)
from gsp_kinematics.geometry import default_geometry_path


def test_defaults():
    assert DEFAULTS['posture_count'] == 60 and DEFAULTS['pool_size'] == 600
    assert DEFAULTS['samples_per_posture'] == 10
    assert DEFAULTS['sync_tolerance'] == pytest.approx(0.0025)
    assert DEFAULTS['free_parameters'] == ['extended']
    assert DEFAULTS['loss'] == 'linear' and DEFAULTS['required_position_accuracy_mm'] == 0.1
    assert DEFAULTS['formulation'] == 'implicit' and DEFAULTS['output_root'] == 'runs'
    assert DEFAULTS['apply_result'] is False and DEFAULTS['platform_node_name'] == 'platform_sim'
    assert DEFAULTS['nominal_geometry_file'] == default_geometry_path('nominal')
    assert DEFAULTS['sigma_inclinometer'] == pytest.approx(math.radians(0.001))
    assert DEFAULTS['sigma_leg_lengths'] == DEFAULTS['sigma_lvdt'] == 1e-6
    assert all(spec.description for spec in PARAMETERS)
    assert check_parameters(DEFAULTS) == ''


@pytest.mark.parametrize(
    'name, value, match',
    [
        ('posture_count', 0, 'must be >= 1'),
        ('pool_size', 0, 'must be >= 1'),
        ('pool_size', 59, 'must not exceed pool_size'),
        ('samples_per_posture', 0, 'must be >= 1'),
        ('sync_tolerance', -0.001, '>= 0'),
        ('sync_tolerance', math.inf, '>= 0'),
        ('settle_timeout', 0.0, '> 0'),
        ('topic_timeout', -1.0, '> 0'),
        ('topic_timeout', math.nan, '> 0'),
        ('seed', -1, '>= 0'),
        ('free_parameters', [], 'at least one'),
        ('free_parameters', ['A1x', 'Q9'], 'unknown parameter name'),
        ('free_parameters', ['D0', 'D0'], 'duplicated'),
        ('formulation', 'magic', 'must be one of'),
        ('sigma_leg_lengths', 0.0, '> 0'),
        ('sigma_inclinometer', -1e-5, '> 0'),
        ('sigma_encoder', math.nan, '> 0'),
        ('sigma_lvdt', math.inf, '> 0'),
        ('output_root', '  ', 'must not be empty'),
        ('platform_node_name', 'not a node', 'not a valid node name'),
        ('nominal_geometry_file', '/nonexistent/geometry.yaml', 'cannot read geometry file'),
        ('nominal_geometry_file', '', 'must name a geometry file'),
    ],
)
def test_bad_values_are_rejected_with_the_reason(name, value, match):
    reason = check_parameters({name: value}, DEFAULTS)
    assert match in reason
    assert reason.startswith(name) or 'pool_size' in reason


def test_changes_are_checked_against_the_current_values():
    current = dict(DEFAULTS, pool_size=100, posture_count=50)
    assert check_parameters({'posture_count': 100}, current) == ''
    assert 'must not exceed' in check_parameters({'posture_count': 101}, current)


def test_settings_from_values(tmp_path):
    settings = CalibratorSettings.from_values(
        {
            'posture_count': 12,
            'pool_size': 50,
            'free_parameters': ['D0', 'gamma'],
            'platform_node_name': '/sim/platform_sim',
            'sigma_encoder': 2e-5,
        }
    )
    assert settings.posture_count == 12 and settings.free_parameters == ('D0', 'gamma')
    assert settings.platform_node_name == 'sim/platform_sim'
    assert settings.sigmas.encoder == 2e-5 and settings.sigmas.lvdt == 1e-6
    assert settings.nominal.device_length > 0
    with pytest.raises(ValueError, match='formulation'):
        CalibratorSettings.from_values({'formulation': 'x'})
    assert set(PARAMETER_SPECS) == set(DEFAULTS)


def test_settings_import_without_loading_rclpy():
    code = 'import sys, gsp_calibrator.settings; assert "rclpy" not in sys.modules'
    subprocess.run([sys.executable, '-c', code], check=True)
