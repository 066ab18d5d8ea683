"""Calibrator parameters: defaults, checks and settings (pure, no ROS)."""

import argparse
import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import pytest

from gsp_calibrator import settings_fields
from gsp_calibrator.recording.recorder import settings_options
from gsp_calibrator.run.record import selection_options
from gsp_calibrator.settings import (
    DEFAULTS,
    PARAMETER_SPECS,
    PARAMETERS,
    REIDENTIFY_COMMAND_LINE,
    SELECTION_PARAMETERS,
    STORED_PARAMETERS,
    CalibratorSettings,
    add_run_options,
    names_in,
    option_value,
    run_options_error,
    validate_parameters,
)
from gsp_kinematics.model.geometry import default_geometry_path
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoise


def test_defaults():
    assert DEFAULTS['posture_count'] == 60 and DEFAULTS['pool_size'] == 600
    assert DEFAULTS['pairs_per_posture'] == 10
    assert DEFAULTS['sync_tolerance'] == pytest.approx(0.0025)
    assert DEFAULTS['free_parameters'] == ['auto']
    assert DEFAULTS['loss'] == 'linear' and DEFAULTS['required_position_accuracy_mm'] == 0.1
    assert DEFAULTS['formulation'] == 'implicit' and DEFAULTS['output_root'] == 'runs'
    assert DEFAULTS['apply_result'] is False and DEFAULTS['platform_node_name'] == 'platform_sim'
    assert DEFAULTS['nominal_geometry_file'] == default_geometry_path('nominal')
    assert DEFAULTS['sigma_inclinometer'] == pytest.approx(math.radians(0.001))
    assert DEFAULTS['sigma_leg_lengths'] == DEFAULTS['sigma_lvdt'] == 1e-6
    assert all(spec.description for spec in PARAMETERS)
    assert validate_parameters(DEFAULTS) == ''


@pytest.mark.parametrize(
    'name, value, match',
    [
        ('posture_count', 0, 'must be >= 1'),
        ('pool_size', 0, 'must be >= 1'),
        ('pool_size', 59, 'must not exceed pool_size'),
        ('pairs_per_posture', 0, 'must be >= 1'),
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
        ('rest_sigmas', 0.0, 'must be > 0'),
        ('rest_sigmas', math.nan, 'must be > 0'),
    ],
)
def test_bad_values_are_rejected_with_the_reason(name, value, match):
    reason = validate_parameters({name: value}, DEFAULTS)
    assert match in reason
    assert reason.startswith(name) or 'pool_size' in reason


def test_an_infinite_rest_sigmas_turns_the_rest_rule_off():
    """docs/sensor_errors.md: ``rest_sigmas`` .inf turns both rest tests off (the physics
    bench's run with the rule off); the node accepts it."""
    assert validate_parameters({'rest_sigmas': math.inf}, DEFAULTS) == ''
    assert CalibratorSettings.from_values({'rest_sigmas': math.inf}).rest_sigmas == math.inf


def test_changes_are_checked_against_the_current_values():
    current = dict(DEFAULTS, pool_size=100, posture_count=50)
    assert validate_parameters({'posture_count': 100}, current) == ''
    assert 'must not exceed' in validate_parameters({'posture_count': 101}, current)


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


def test_the_settings_and_their_subsets_are_derived_from_the_one_table():
    settings = CalibratorSettings.from_values({'sigma_lvdt': 5e-6, 'free_parameters': ['paper']})
    assert {field.name for field in dataclasses.fields(settings)} == set(PARAMETER_SPECS) | {
        'nominal'
    }
    assert settings.sigmas == SensorNoise(
        DEFAULT_SENSOR_NOISE.leg_lengths,
        DEFAULT_SENSOR_NOISE.inclinometer,
        DEFAULT_SENSOR_NOISE.encoder,
        5e-6,
    )
    assert settings.free_parameters == ('paper',)
    stored = settings_options(settings)
    assert tuple(stored) == STORED_PARAMETERS and stored['free_parameters'] == ['paper']
    assert set(SELECTION_PARAMETERS) <= set(STORED_PARAMETERS)
    assert set(SELECTION_PARAMETERS) <= set(selection_options(settings))
    assert 'sigma_lvdt' in SELECTION_PARAMETERS  # the assumed noise weighs the selection


def test_the_requirement_is_the_three_required_parameters():
    values = {
        'required_position_accuracy_mm': 0.05,
        'required_orientation_accuracy_deg': 0.02,
        'required_improvement_over_nominal': 4.0,
    }
    requirement = CalibratorSettings.from_values(values).requirement
    assert (requirement.position_mm, requirement.orientation_deg) == (0.05, 0.02)
    assert requirement.improvement == 4.0


def _fields_source():
    """The text of settings_fields.py the table gives."""
    path = Path(settings_fields.__file__)
    text = path.read_text()
    head = text[: text.index('    nominal: Geometry\n') + len('    nominal: Geometry\n')]
    lines = []
    for spec in PARAMETERS:
        default = spec.default
        if isinstance(default, list):
            lines.append(f'    {spec.name}: tuple[{type(default[0]).__name__}, ...]\n')
        else:
            lines.append(f'    {spec.name}: {type(default).__name__}\n')
    return head + ''.join(lines)


def test_the_typed_settings_fields_are_the_tables():
    expected = _fields_source()
    assert Path(settings_fields.__file__).read_text() == expected, (
        'settings_fields.py differs from settings.PARAMETERS; its text should be:\n' + expected
    )


@pytest.mark.parametrize(
    'name, value, expected',
    [
        ('noise_source', 'guessed', "--noise-source: 'guessed' rejected, must be one of"),
        ('free_parameters', ['paper,Q9'], "unknown parameter name(s) ['Q9']"),
        ('sigma_lvdt', -1.0, '--sigma-lvdt: -1.0 rejected, must be a finite number > 0'),
        ('pairs_per_posture', 0, '--pairs-per-posture: 0 rejected'),
    ],
)
def test_command_lines_check_options_with_the_parameters_checks(name, value, expected):
    assert name in names_in(REIDENTIFY_COMMAND_LINE)
    with pytest.raises(ValueError) as raised:
        option_value(name, value)
    assert expected in str(raised.value)
    assert validate_parameters({name: value})  # the node refuses the same value


def test_run_options_are_the_marked_parameters_with_their_defaults():
    parser = argparse.ArgumentParser()
    add_run_options(parser)
    args = parser.parse_args(['--postures', '7', '--free', 'paper,kq1'])
    assert run_options_error(args) == ''
    assert (args.posture_count, args.pool_size, args.free_parameters) == (7, 600, ['paper', 'kq1'])
    bad = parser.parse_args(['--formulation', 'nonsense'])
    assert run_options_error(bad).startswith("--formulation: 'nonsense' rejected")
