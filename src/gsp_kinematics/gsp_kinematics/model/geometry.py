"""Platform and device geometry: the identification parameters, the sensor errors and the
geometry file (a ROS 2 parameters YAML; docs/data.md)."""

import dataclasses
import math
import os
from importlib import resources

import numpy as np
import yaml

from ..fileio import atomic_write_text, yaml_float
from .effects import EFFECT_GROUPS, IdentifiedEffects

NUM_LEGS = 6
NUM_PARAMETERS = 44

PARAMETER_NAMES = tuple(
    [f'A{leg}{axis}' for leg in range(1, 7) for axis in 'xyz']
    + [f'B{leg}{axis}' for leg in range(1, 7) for axis in 'xyz']
    + [f'Loff{leg}' for leg in range(1, 7)]
    + ['D0', 'gamma']
)
#: The sensor-error parameters (docs/sensor_errors.md), after the 44 in the extended vector:
#: leg gain errors, inclinometer zero offsets (rad), encoder zero (rad), LVDT gain error.
SENSOR_PARAMETER_NAMES = tuple(
    [f'kq{leg}' for leg in range(1, 7)] + ['alpha0', 'beta0', 'phi0', 'kDm']
)
#: The 44 and the sensor errors: the vector the identification works on.
ALL_PARAMETER_NAMES = PARAMETER_NAMES + SENSOR_PARAMETER_NAMES
NUM_ALL_PARAMETERS = len(ALL_PARAMETER_NAMES)
PARAMETER_INDEX = {name: index for index, name in enumerate(ALL_PARAMETER_NAMES)}
#: Sensor parameters that are angles (rad); the others are dimensionless gain errors.
ANGULAR_SENSOR_PARAMETERS = ('alpha0', 'beta0', 'phi0')
#: Index of the only angular parameter (gamma); every other parameter is a length in m.
ANGULAR_PARAMETERS = (PARAMETER_INDEX['gamma'],)
#: The leg that each platform parameter belongs to (None for the device parameters).
PARAMETER_CHAIN = tuple(
    [leg for leg in range(1, 7) for _ in 'xyz']
    + [leg for leg in range(1, 7) for _ in 'xyz']
    + list(range(1, 7))
    + [None, None]
)

GEOMETRY_NAMESPACE = 'geometry'


class GeometryError(ValueError):
    """A geometry file or parameter set is malformed; the message names the key."""


@dataclasses.dataclass(frozen=True)
class Limits:
    """Reachability limits of the platform."""

    leg_stroke_min: float = 0.0  #: smallest articular variable q (m)
    leg_stroke_max: float = 0.9  #: largest articular variable q (m)
    base_joint_max_angle: float = math.radians(65.0)  #: leg to base normal (rad)
    platform_joint_max_angle: float = math.radians(75.0)  #: leg to platform normal (rad)

    def validate(self):
        if not self.leg_stroke_min < self.leg_stroke_max:
            raise GeometryError(
                f'geometry.limits: leg_stroke_min ({self.leg_stroke_min}) must be below '
                f'leg_stroke_max ({self.leg_stroke_max})'
            )
        for name in ('base_joint_max_angle', 'platform_joint_max_angle'):
            value = getattr(self, name)
            if not 0.0 < value <= math.pi:
                raise GeometryError(f'geometry.limits.{name}: {value} is not in (0, pi] rad')


@dataclasses.dataclass(frozen=True)
class SensorErrors:
    """Systematic sensor errors (all 0: ideal sensors; sign conventions: docs/sensor_errors.md)."""

    leg_gain_errors: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_LEGS))
    inclinometer_offsets: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))
    encoder_offset: float = 0.0  #: phi0, rad
    lvdt_gain_error: float = 0.0  #: kDm

    def __post_init__(self):
        for name, size in (('leg_gain_errors', NUM_LEGS), ('inclinometer_offsets', 2)):
            value = np.array(getattr(self, name), dtype=float).reshape(size)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, 'encoder_offset', float(self.encoder_offset))
        object.__setattr__(self, 'lvdt_gain_error', float(self.lvdt_gain_error))

    def to_vector(self):
        """``[kq1..kq6, alpha0, beta0, phi0, kDm]``."""
        scalars = [self.encoder_offset, self.lvdt_gain_error]
        return np.concatenate([self.leg_gain_errors, self.inclinometer_offsets, scalars])

    @classmethod
    def from_vector(cls, values):
        values = np.asarray(values, dtype=float)
        return cls(values[0:6], values[6:8], values[8], values[9])

    @property
    def ideal(self):
        return not np.any(self.to_vector())

    def true_leg_lengths(self, leg_readings):
        """Articular variables ``(1 + kq) q`` (M, 6) the legs really have for readings q."""
        return np.asarray(leg_readings, dtype=float) * (1.0 + self.leg_gain_errors)

    def leg_readings(self, true_leg_lengths):
        """What the leg sensors read, ``q / (1 + kq)``, for true articular variables."""
        return np.asarray(true_leg_lengths, dtype=float) / (1.0 + self.leg_gain_errors)

    def device_readings(self, ideal_readings):
        """Readings ``[alpha, beta, phi, d_m]`` (M, 4) the sensors give for the ideal ones."""
        readings = np.array(ideal_readings, dtype=float)
        readings[..., 0:2] += self.inclinometer_offsets
        readings[..., 2] += self.encoder_offset
        readings[..., 3] /= 1.0 + self.lvdt_gain_error
        return readings

    def ideal_device_readings(self, readings):
        """Inverse of :meth:`device_readings`: the readings ideal sensors would give."""
        ideal = np.array(readings, dtype=float)
        ideal[..., 0:2] -= self.inclinometer_offsets
        ideal[..., 2] -= self.encoder_offset
        ideal[..., 3] *= 1.0 + self.lvdt_gain_error
        return ideal


@dataclasses.dataclass(frozen=True)
class Geometry:
    """The 44 parameters (m, rad), the sensor errors and the platform's limits."""

    base_joints: np.ndarray  #: A_i, (6, 3), base frame, m
    platform_joints: np.ndarray  #: B_i, (6, 3), platform frame, m
    leg_offsets: np.ndarray  #: L_off_i, (6,), m
    device_length: float  #: D0, m
    inclinometer_axes_angle: float  #: gamma, rad
    limits: Limits = dataclasses.field(default_factory=Limits)
    sensors: SensorErrors = dataclasses.field(default_factory=SensorErrors)
    #: Identified effects the controller compensates (docs/platform_effects.md; none: rigid).
    effects: IdentifiedEffects = dataclasses.field(default_factory=IdentifiedEffects)

    def __post_init__(self):
        for name, shape in (
            ('base_joints', (NUM_LEGS, 3)),
            ('platform_joints', (NUM_LEGS, 3)),
            ('leg_offsets', (NUM_LEGS,)),
        ):
            value = np.array(getattr(self, name), dtype=float).reshape(shape)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, 'device_length', float(self.device_length))
        object.__setattr__(self, 'inclinometer_axes_angle', float(self.inclinometer_axes_angle))

    def to_vector(self):
        """The 44-vector in :data:`PARAMETER_NAMES` order."""
        return np.concatenate(
            [
                self.base_joints.ravel(),
                self.platform_joints.ravel(),
                self.leg_offsets,
                [self.device_length, self.inclinometer_axes_angle],
            ]
        )

    @classmethod
    def from_vector(cls, parameters, limits=None):
        parameters = np.asarray(parameters, dtype=float)
        if parameters.shape != (NUM_PARAMETERS,):
            raise GeometryError(f'parameter vector must have {NUM_PARAMETERS} values')
        return cls(
            base_joints=parameters[0:18].reshape(6, 3),
            platform_joints=parameters[18:36].reshape(6, 3),
            leg_offsets=parameters[36:42],
            device_length=parameters[42],
            inclinometer_axes_angle=parameters[43],
            limits=limits if limits is not None else Limits(),
        )

    def to_full_vector(self):
        """The 44 and the sensor errors, in :data:`ALL_PARAMETER_NAMES` order."""
        return np.concatenate([self.to_vector(), self.sensors.to_vector()])

    @classmethod
    def from_full_vector(cls, parameters, limits=None):
        parameters = np.asarray(parameters, dtype=float)
        if parameters.shape != (NUM_ALL_PARAMETERS,):
            raise GeometryError(f'parameter vector must have {NUM_ALL_PARAMETERS} values')
        geometry = cls.from_vector(parameters[:NUM_PARAMETERS], limits)
        return geometry.replace(sensors=SensorErrors.from_vector(parameters[NUM_PARAMETERS:]))

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)


def parameter_errors(estimate, reference):
    """Per-parameter error ``estimate - reference`` in report units (mm, and deg for gamma)."""
    errors = estimate.to_vector() - reference.to_vector()
    return to_report_units(errors)


def to_report_units(parameter_values):
    """Convert a 44-vector (m, rad) to report units (mm, deg for gamma)."""
    values = np.asarray(parameter_values, dtype=float) * 1000.0
    values[..., ANGULAR_PARAMETERS] = np.degrees(
        np.asarray(parameter_values, dtype=float)[..., ANGULAR_PARAMETERS]
    )
    return values


# --- parameter dictionaries (ROS parameter names) ---------------------------------------------

#: ``geometry.*`` keys -> number of values (None: a scalar), the 44 parameters.
_REQUIRED_KEYS = {
    'base_joints': 18,
    'platform_joints': 18,
    'leg_offsets': 6,
    'device_length': None,
    'inclinometer_axes_angle': None,
}
_LIMITS = f'{GEOMETRY_NAMESPACE}.limits'
#: ``geometry.limits.*`` keys (optional, scalars).
_LIMIT_KEYS = dict.fromkeys(field.name for field in dataclasses.fields(Limits))
_SENSORS = f'{GEOMETRY_NAMESPACE}.sensors'
#: ``geometry.sensors.*`` keys (optional section) -> number of values (None: a scalar).
SENSOR_KEYS = {
    'leg_gain_errors': NUM_LEGS,
    'inclinometer_offsets': 2,
    'encoder_offset': None,
    'lvdt_gain_error': None,
}
_EFFECTS = f'{GEOMETRY_NAMESPACE}.effects'
_EFFECT_STEMS = tuple(stem for stem, _, _ in EFFECT_GROUPS.values())
#: ``geometry.effects.*`` keys (optional section) -> number of values (None: a scalar).
EFFECT_KEYS = {
    **dict.fromkeys(_EFFECT_STEMS, NUM_LEGS),
    'payload_mass': None,
    'centre_of_mass': 3,
    'leg_mass': NUM_LEGS,
    'reference_time': None,
}


def geometry_to_parameters(geometry, all_effects=False):
    """Flat ``{'geometry.base_joints': [...], ...}`` ROS parameters, only the identified effects;
    ``all_effects``: all (0: not identified), what a compensating controller is set to."""
    parameters = {
        f'{GEOMETRY_NAMESPACE}.{key}': getattr(geometry, key).ravel().tolist()
        if length
        else getattr(geometry, key)
        for key, length in _REQUIRED_KEYS.items()
    }
    for key in _LIMIT_KEYS:
        parameters[f'{_LIMITS}.{key}'] = float(getattr(geometry.limits, key))
    for key in SENSOR_KEYS:  # the SensorErrors fields
        value = getattr(geometry.sensors, key)
        parameters[f'{_SENSORS}.{key}'] = value.tolist() if np.ndim(value) else value
    parameters.update(_effect_parameters(geometry.effects, all_effects))
    return parameters


def _effect_parameters(effects, every=False):
    """``{'geometry.effects.<key>': value}`` (the mass first: ros2 param load sets one at a time)
    of the identified groups, their load and reference instant; ``every``: all, 0 if not."""
    groups = effects.groups()
    kept = {stem: g in groups for g, stem in zip(EFFECT_GROUPS, _EFFECT_STEMS, strict=True)}
    load = kept['payload_mass'] = kept['centre_of_mass'] = 'compliance' in groups
    kept['leg_mass'] = load and any(effects.leg_mass)  # the legs' masses only when known
    thermal = kept['reference_time'] = 'thermal' in groups
    values = {
        'payload_mass': float(effects.payload_mass) if load else 0.0,
        'centre_of_mass': [float(v) if load else 0.0 for v in effects.centre_of_mass],
        'leg_mass': [float(v) if load else 0.0 for v in effects.leg_mass],
        'reference_time': float(effects.reference_time_s) if thermal else 0.0,
    }
    values.update(zip(_EFFECT_STEMS, effects.values.reshape(-1, NUM_LEGS).tolist(), strict=True))
    return {f'{_EFFECTS}.{key}': value for key, value in values.items() if every or kept[key]}


def _effects_from_parameters(parameters):
    """The optional ``geometry.effects`` section (absent keys: 0, nothing compensated)."""
    values = _optional_section(parameters, _EFFECTS, EFFECT_KEYS)
    mass = values.get('payload_mass', 0.0)
    if mass < 0.0 or (np.any(values.get('compliance', 0.0)) and not mass > 0.0):
        raise GeometryError(
            f'{_EFFECTS}.payload_mass: the compliance needs the mass it was identified for '
            f'(> 0 kg), got {mass}'
        )
    return IdentifiedEffects(
        np.concatenate([values.get(stem, np.zeros(NUM_LEGS)) for stem in _EFFECT_STEMS]),
        mass,
        tuple(values.get('centre_of_mass', (0.0, 0.0, 0.0))),
        values.get('reference_time', 0.0),
        tuple(values.get('leg_mass', (0.0,) * NUM_LEGS)),
    )


def _finite_float(value, key):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise GeometryError(f'{key}: expected a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise GeometryError(f'{key}: value is not finite ({value})')
    return value


def _finite_list(raw, length, key):
    if isinstance(raw, (str, bytes)) or not hasattr(raw, '__len__'):
        raise GeometryError(f'{key}: expected a list of {length} numbers, got {raw!r}')
    if len(raw) != length:
        raise GeometryError(f'{key}: expected {length} values, got {len(raw)}')
    return [_finite_float(item, f'{key}[{index}]') for index, item in enumerate(raw)]


def _optional_section(parameters, section, keys):
    """``{key: value}`` of the ``keys`` (-> length, None: a scalar) of ``section`` present."""
    present = {
        key: f'{section}.{key}' for key in keys if parameters.get(f'{section}.{key}') is not None
    }
    return {
        key: _finite_float(parameters[full], full)
        if keys[key] is None
        else _finite_list(parameters[full], keys[key], full)
        for key, full in present.items()
    }


def _sensor_errors_from_parameters(parameters):
    """The optional ``geometry.sensors`` section (absent keys: ideal sensors)."""
    values = _optional_section(parameters, _SENSORS, SENSOR_KEYS)
    for key in ('leg_gain_errors', 'lvdt_gain_error'):
        gains = np.atleast_1d(values.get(key, 0.0))
        if np.any(np.abs(gains) >= 0.5):
            raise GeometryError(
                f'{_SENSORS}.{key}: a gain error is a small fraction (|k| < 0.5), got '
                f'{gains.tolist()}'
            )
    return SensorErrors(**values)


def geometry_from_parameters(parameters, default_limits=None):
    """Build a :class:`Geometry` from a flat ``geometry.*`` dictionary, checking every key."""
    prefix = GEOMETRY_NAMESPACE + '.'
    for key in _REQUIRED_KEYS:
        if parameters.get(prefix + key) is None:
            raise GeometryError(f'{prefix}{key}: missing')
    values = _optional_section(parameters, GEOMETRY_NAMESPACE, _REQUIRED_KEYS)
    if values['device_length'] <= 0.0:
        raise GeometryError(
            f'{prefix}device_length: must be positive, got {values["device_length"]}'
        )
    if not 0.0 < values['inclinometer_axes_angle'] < math.pi:
        raise GeometryError(
            f'{prefix}inclinometer_axes_angle: must be in (0, pi) rad, '
            f'got {values["inclinometer_axes_angle"]}'
        )
    limits = default_limits if default_limits is not None else Limits()
    limits = dataclasses.replace(limits, **_optional_section(parameters, _LIMITS, _LIMIT_KEYS))
    limits.validate()
    return Geometry(
        **values,
        limits=limits,
        sensors=_sensor_errors_from_parameters(parameters),
        effects=_effects_from_parameters(parameters),
    )


def _flatten(tree, prefix=''):
    flat = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def _ros_parameters_section(document, source):
    if not isinstance(document, dict) or not document:
        raise GeometryError(f'{source}: expected a ROS 2 parameters YAML mapping')
    # Accept '/**', a node name, or a namespaced node name: take the first with ros__parameters.
    for node_name, section in document.items():
        if isinstance(section, dict) and 'ros__parameters' in section:
            parameters = section['ros__parameters']
            if not isinstance(parameters, dict):
                raise GeometryError(f'{source}: {node_name}.ros__parameters is not a mapping')
            return parameters
    raise GeometryError(f"{source}: no '<node>: ros__parameters:' section (expected '/**:')")


def geometry_from_yaml(text, source='<string>'):
    """Parse the canonical params-file text into a :class:`Geometry`."""
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise GeometryError(f'{source}: not valid YAML: {error}') from error
    parameters = _ros_parameters_section(document, source)
    if GEOMETRY_NAMESPACE not in parameters or not isinstance(parameters[GEOMETRY_NAMESPACE], dict):
        raise GeometryError(f'{source}: geometry: missing (expected ros__parameters.geometry)')
    try:
        return geometry_from_parameters(_flatten({GEOMETRY_NAMESPACE: parameters['geometry']}))
    except GeometryError as error:
        raise GeometryError(f'{source}: {error}') from None


def load_geometry(path):
    """Load a geometry params file; raises :class:`GeometryError` naming the key at fault."""
    path = os.fspath(path)
    try:
        with open(path, encoding='utf-8') as stream:
            text = stream.read()
    except OSError as error:
        raise GeometryError(f'{path}: cannot read geometry file ({error.strerror})') from error
    return geometry_from_yaml(text, source=path)


def geometry_to_yaml(geometry, node_name='/**', comment=None, extra_parameters=None):
    """Serialise to the canonical params-file text (full float precision)."""

    def floats(values):
        return '[' + ', '.join(yaml_float(value) for value in values) + ']'

    lines = []
    if comment:
        lines += [f'# {line}' for line in comment.splitlines()]
    limits = geometry.limits
    lines += [
        f'{node_name}:',
        '  ros__parameters:',
        '    geometry:',
        f'      base_joints: {floats(geometry.base_joints.ravel())}  # A_1..A_6 xyz, base frame, m',
        f'      platform_joints: {floats(geometry.platform_joints.ravel())}'
        '  # B_1..B_6 xyz, platform frame, m',
        f'      leg_offsets: {floats(geometry.leg_offsets)}  # L_off_i, m',
        f'      device_length: {geometry.device_length!r}  # D0, m',
        f'      inclinometer_axes_angle: {geometry.inclinometer_axes_angle!r}  # gamma, rad',
        '      limits:',
        f'        leg_stroke_min: {limits.leg_stroke_min!r}  # q_min, m',
        f'        leg_stroke_max: {limits.leg_stroke_max!r}  # q_max, m',
        f'        base_joint_max_angle: {limits.base_joint_max_angle!r}  # rad',
        f'        platform_joint_max_angle: {limits.platform_joint_max_angle!r}  # rad',
    ]
    sensors = geometry.sensors
    if not sensors.ideal:  # ideal sensors: no section, as in files written before it existed
        lines += [
            '      sensors:  # docs/sensor_errors.md',
            f'        leg_gain_errors: {floats(sensors.leg_gain_errors)}  # kq1..kq6',
            f'        inclinometer_offsets: {floats(sensors.inclinometer_offsets)}'
            '  # alpha0, beta0, rad',
            f'        encoder_offset: {sensors.encoder_offset!r}  # phi0, rad',
            f'        lvdt_gain_error: {sensors.lvdt_gain_error!r}  # kDm',
        ]
    if not geometry.effects.none:  # docs/platform_effects.md; none: no section
        lines.append('      effects:  # identified, compensated by the controller')
        for name, value in _effect_parameters(geometry.effects).items():
            text = floats(value) if isinstance(value, list) else yaml_float(value)
            lines.append(f'        {name.rpartition(".")[2]}: {text}')
    for key, value in (extra_parameters or {}).items():
        lines.append(f'    {key}: {yaml.safe_dump(value, default_flow_style=True).strip()}')
    return '\n'.join(lines) + '\n'


def save_geometry(geometry, path, **kwargs):
    """Write the params file atomically; ``kwargs`` go to :func:`geometry_to_yaml`."""
    atomic_write_text(path, geometry_to_yaml(geometry, **kwargs))


def default_geometry_path(kind='true'):
    """Path of the shipped default geometry file, ``kind`` in {'true', 'nominal'}."""
    if kind not in ('true', 'nominal'):
        raise ValueError(f"kind must be 'true' or 'nominal', got {kind!r}")
    return str(resources.files('gsp_kinematics') / 'data' / f'{kind}_geometry.yaml')


def default_geometry(kind='true'):
    return load_geometry(default_geometry_path(kind))
