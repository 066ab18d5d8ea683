"""Geometry parameters, the params-file format and its error messages."""

import math

import numpy as np
import pytest

from gsp_kinematics.model.geometry import (
    PARAMETER_CHAIN,
    PARAMETER_NAMES,
    Geometry,
    GeometryError,
    Limits,
    default_geometry,
    default_geometry_path,
    geometry_from_parameters,
    geometry_from_yaml,
    geometry_to_parameters,
    geometry_to_yaml,
    load_geometry,
    parameter_errors,
    save_geometry,
)

VALID = """\
/**:
  ros__parameters:
    geometry:
      base_joints: [1.0, 0.0, 0.0, 0.5, 0.8, 0.0, -0.5, 0.8, 0.0, -1.0, 0.0, 0.0, -0.5, -0.8, 0.0, 0.5, -0.8, 0.0]
      platform_joints: [0.5, 0.1, 0.0, 0.2, 0.4, 0.0, -0.2, 0.4, 0.0, -0.5, 0.1, 0.0, -0.3, -0.4, 0.0, 0.3, -0.4, 0.0]
      leg_offsets: [0.6, 0.6, 0.6, 0.6, 0.6, 0.6]
      device_length: 0.85
      inclinometer_axes_angle: 1.5707963267948966
"""


def test_parameter_names():
    assert len(PARAMETER_NAMES) == 44 == len(set(PARAMETER_NAMES)) == len(PARAMETER_CHAIN)
    assert PARAMETER_NAMES[:4] == ('A1x', 'A1y', 'A1z', 'A2x')
    assert PARAMETER_NAMES[18] == 'B1x' and PARAMETER_NAMES[36] == 'Loff1'
    assert PARAMETER_NAMES[-2:] == ('D0', 'gamma')


def test_vector_round_trip(exact):
    vector = exact.to_vector()
    assert vector.shape == (44,)
    again = Geometry.from_vector(vector, exact.limits)
    np.testing.assert_array_equal(again.to_vector(), vector)
    assert again.limits == exact.limits
    with pytest.raises(GeometryError, match='44'):
        Geometry.from_vector(vector[:43])


def test_parameter_errors_are_in_mm_and_deg(exact):
    other = exact.replace(
        device_length=exact.device_length + 0.0002, inclinometer_axes_angle=math.radians(90.5)
    )
    errors = parameter_errors(other, exact)
    assert errors[42] == pytest.approx(0.2) and errors[43] == pytest.approx(0.5)
    assert np.all(errors[:42] == 0.0)


def test_yaml_round_trip_is_exact(nominal_sets, tmp_path):
    geometry = nominal_sets[3].replace(limits=Limits(0.01, 1.1, 1.2, 1.3))
    again = geometry_from_yaml(geometry_to_yaml(geometry, comment='set 3\nround trip'))
    np.testing.assert_array_equal(again.to_vector(), geometry.to_vector())
    assert again.limits == geometry.limits
    path = tmp_path / 'sub' / 'geometry.yaml'
    save_geometry(geometry, path, comment='saved')
    assert path.read_text().startswith('# saved\n/**:\n  ros__parameters:\n    geometry:\n')
    loaded = load_geometry(path)
    np.testing.assert_array_equal(loaded.to_vector(), geometry.to_vector())
    assert loaded.limits == geometry.limits
    assert list(tmp_path.glob('sub/*tmp*')) == []  # atomic write leaves nothing behind


def test_parameters_dict_round_trip(nominal_sets):
    geometry = nominal_sets[1]
    parameters = geometry_to_parameters(geometry)
    assert len(parameters['geometry.base_joints']) == 18
    again = geometry_from_parameters(parameters)
    np.testing.assert_array_equal(again.to_vector(), geometry.to_vector())
    assert again.limits == geometry.limits


def test_minimal_file_loads_with_default_limits():
    geometry = geometry_from_yaml(VALID)
    assert geometry.limits == Limits()
    assert geometry.device_length == 0.85
    np.testing.assert_array_equal(geometry.base_joints[1], [0.5, 0.8, 0.0])


@pytest.mark.parametrize('kind', ['true', 'nominal'])
def test_shipped_geometries_load(kind):
    geometry = default_geometry(kind)
    assert default_geometry_path(kind).endswith(f'{kind}_geometry.yaml')
    assert np.all(np.isfinite(geometry.to_vector()))


def replace_line(key, new_line):
    lines = VALID.splitlines()
    out = [new_line if line.strip().startswith(key + ':') else line for line in lines]
    return '\n'.join(line for line in out if line is not None) + '\n'


BAD_FILES = {
    'missing key': (
        replace_line('platform_joints', '      # platform_joints removed'),
        ['geometry.platform_joints', 'missing'],
    ),
    'missing scalar': (
        replace_line('device_length', '      # no device length'),
        ['geometry.device_length', 'missing'],
    ),
    'wrong length': (
        replace_line('base_joints', '      base_joints: [1.0, 2.0, 3.0]'),
        ['geometry.base_joints', '18', '3'],
    ),
    'not a list': (
        replace_line('leg_offsets', '      leg_offsets: 0.6'),
        ['geometry.leg_offsets', 'list'],
    ),
    'nan': (
        replace_line('leg_offsets', '      leg_offsets: [0.6, 0.6, .nan, 0.6, 0.6, 0.6]'),
        ['geometry.leg_offsets[2]', 'not finite'],
    ),
    'inf': (
        replace_line('device_length', '      device_length: .inf'),
        ['geometry.device_length', 'not finite'],
    ),
    'not a number': (
        replace_line('leg_offsets', '      leg_offsets: [0.6, 0.6, 0.6, abc, 0.6, 0.6]'),
        ['geometry.leg_offsets[3]', 'number'],
    ),
    'negative length': (
        replace_line('device_length', '      device_length: -0.85'),
        ['geometry.device_length'],
    ),
    'gamma out of range': (
        replace_line('inclinometer_axes_angle', '      inclinometer_axes_angle: 4.0'),
        ['geometry.inclinometer_axes_angle'],
    ),
    'not a mapping': ('- 1\n- 2\n', ['mapping']),
    'empty': ('', ['mapping']),
    'no ros__parameters': (VALID.replace('ros__parameters', 'parameters'), ['ros__parameters']),
    'ros__parameters not a mapping': (
        '/**:\n  ros__parameters: [1, 2]\n',
        ['ros__parameters', 'not a mapping'],
    ),
    'no geometry': ('/**:\n  ros__parameters:\n    other: 1\n', ['geometry', 'missing']),
    'invalid yaml': ('/**:\n  ros__parameters: {geometry: [\n', ['not valid YAML']),
    'bad limits': (
        VALID + '      limits:\n        leg_stroke_min: 2.0\n        leg_stroke_max: 1.0\n',
        ['leg_stroke_min'],
    ),
}


@pytest.mark.parametrize('case', sorted(BAD_FILES))
def test_bad_geometry_files_name_the_key(case, tmp_path):
    text, fragments = BAD_FILES[case]
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(GeometryError) as caught:
        load_geometry(path)
    message = str(caught.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, f'{fragment!r} not in {message!r}'


def test_unreadable_file_is_a_geometry_error(tmp_path):
    with pytest.raises(GeometryError, match='cannot read'):
        load_geometry(tmp_path / 'absent.yaml')
