"""Parameter tables of the nodes: specs, checks and declaration (docs/parameters.md).

A check is ``value -> reason`` ('' when accepted).
"""

import dataclasses
import math

import numpy as np

from gsp_kinematics.model.geometry import default_geometry_path
from gsp_kinematics.model.motion import DEFAULT_SENSOR_RATE_HZ
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, NOISE_UNITS

from . import names
from .noise_parameters import TRUE_NOISE_PARAMETER

# rclpy is imported only where a node is needed: pure modules import specs without it.


class ConfigurationError(ValueError):
    """A parameter value prevents a node from starting; the message names the parameter."""


def is_finite_number(value):
    """True for an int or float that is finite (bools and strings are not numbers here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def greater_than(bound, unit='', reason=None):
    """Check: a finite number > ``bound``."""
    why = reason or f'must be > {bound:g} {unit}'.rstrip()
    return lambda v: '' if is_finite_number(v) and v > bound else why


def at_least(bound, unit='', reason=None):
    """Check: a finite number >= ``bound``."""
    why = reason or f'must be >= {bound:g} {unit}'.rstrip()
    return lambda v: '' if is_finite_number(v) and v >= bound else why


def not_blank(what='a value', reason=None):
    """Check: a string that is not empty or blank."""
    why = reason or f'must name {what}'
    return lambda v: '' if str(v).strip() else why


def one_of(options, reason=None):
    """Check: one of ``options``."""
    options = tuple(options)
    why = reason or f'must be one of {list(options)}'
    return lambda v: '' if v in options else why


#: ROS parameter type names by Python type of the default (``ros2 param describe`` wording).
_TYPE_NAMES = {bool: 'bool', int: 'integer', float: 'double', str: 'string'}


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """One node parameter: default (fixing its ROS type), description, ROS ranges and check.

    ``default_text``: how the docs show an installation-dependent default; ``subsets``: the
    node's parameter subsets this one belongs to.
    """

    name: str
    default: object
    description: str
    unit: str = ''
    read_only: bool = False
    float_range: tuple = None
    integer_range: tuple = None
    constraints: str = ''
    check: object = None
    default_text: str = ''
    subsets: frozenset = frozenset()

    @property
    def type_name(self):
        """The ROS parameter type of :attr:`default`: ``double``, ``string_array``..."""
        if isinstance(self.default, (list, tuple)):
            item = type(self.default[0]) if self.default else str
            return _TYPE_NAMES[item] + '_array'
        return _TYPE_NAMES[type(self.default)]

    def descriptor(self):
        """The ``ParameterDescriptor`` ROS shows for this parameter."""
        from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

        description = self.description + (f' ({self.unit})' if self.unit else '')
        descriptor = ParameterDescriptor(
            description=description,
            read_only=self.read_only,
            additional_constraints=self.constraints,
        )
        if self.float_range is not None:
            low, high = map(float, self.float_range)
            descriptor.floating_point_range = [FloatingPointRange(from_value=low, to_value=high)]
        if self.integer_range is not None:
            low, high = map(int, self.integer_range)
            descriptor.integer_range = [IntegerRange(from_value=low, to_value=high, step=1)]
        return descriptor

    def reason(self, value):
        """'' if ``value`` passes :attr:`check`, else ``'<name>: <value> rejected, <why>'``."""
        why = self.check(value) if self.check is not None else ''
        if not why:
            return ''
        shown = value if not isinstance(value, (list, tuple)) or len(value) < 8 else '[...]'
        return f'{self.name}: {shown!r} rejected, {why}'


def positive_spec(name, default, description, unit='', **fields):
    """A parameter whose value must be a finite number > 0 (in ``unit``)."""
    return ParameterSpec(name, default, description, unit, check=greater_than(0.0, unit), **fields)


def non_negative_spec(name, default, description, unit='', **fields):
    """A parameter whose value must be a finite number >= 0 (in ``unit``)."""
    return ParameterSpec(name, default, description, unit, check=at_least(0.0, unit), **fields)


# Parameters several nodes share (same name, type and checks everywhere).


def publish_rate_spec(what, default=DEFAULT_SENSOR_RATE_HZ):
    """``publish_rate`` (Hz, read-only): the rate of ``what``."""
    return positive_spec(
        'publish_rate', default, f'Rate of {what}', 'Hz', read_only=True, constraints='> 0'
    )


def seed_spec():
    """``seed`` (read-only): of the node's noise generator; -1 (default) draws one at each start."""
    return ParameterSpec(
        'seed',
        -1,
        'Seed of the noise generator; -1 = a fresh one at each start (logged). A fixed seed '
        'replays the same noise at every start of the node',
        read_only=True,
        integer_range=(-1, 2**31 - 1),
        check=at_least(-1, reason='must be >= 0, or -1 for a random seed'),
    )


def resolve_seed(seed):
    """``seed`` if >= 0, else a fresh one in [0, 2**31) from OS entropy (docs/faults.md)."""
    seed = int(seed)
    # Drawn in the parameter's own range, so the logged seed can be passed back to replay a life.
    return seed if seed >= 0 else int(np.random.SeedSequence().generate_state(1)[0] >> 1)


def frame_id_spec(description):
    """``frame_id`` (read-only): the base frame of the node's messages."""
    return ParameterSpec(
        'frame_id',
        names.FRAME_BASE,
        description,
        read_only=True,
        check=not_blank(reason='must not be empty'),
    )


def settle_time_spec(what):
    """``settle_time`` (s): from the legs' arrival to the 'settled' status of ``what``."""
    description = f"Time from the legs' arrival to the 'settled' status of {what}"
    return non_negative_spec('settle_time', 0.05, description, 's', float_range=(0.0, 60.0))


def diagnostics_period_spec():
    """``diagnostics_period`` (s, read-only): how often the node publishes its health on
    ``/diagnostics`` (:class:`gsp_msgs_py.diagnostics.DiagnosticsPublisher`)."""
    description = f'Period of the health reports on {names.TOPIC_DIAGNOSTICS}'
    return positive_spec(
        'diagnostics_period', 1.0, description, 's', read_only=True, float_range=(0.01, 60.0)
    )


def motion_limit_specs(speed, acceleration, read_only=False):
    """``max_leg_speed`` (m/s) and ``max_leg_acceleration`` (m/s^2) of the simulated legs, with
    these defaults; 0 removes a limit (:class:`gsp_kinematics.model.motion.MotionLimits`)."""
    return tuple(
        non_negative_spec(
            name,
            float(default),
            f'{what} limit of every leg (synchronised moves, docs/planning.md); 0: no limit',
            unit,
            read_only=read_only,
            float_range=(0.0, 1e3),
            constraints='>= 0',
        )
        for name, default, what, unit in (
            ('max_leg_speed', speed, 'Speed', 'm/s'),
            ('max_leg_acceleration', acceleration, 'Acceleration', 'm/s^2'),
        )
    )


def true_noise_spec(sensor, description):
    """A simulated ``sensor``'s true noise std, ``<sensor>_noise_std``
    (:data:`gsp_msgs_py.noise_parameters.TRUE_NOISE_PARAMETER`, the sensor's unit), changeable
    at run time; the default is the suite's default noise."""
    unit = NOISE_UNITS[sensor]
    name, default = TRUE_NOISE_PARAMETER.format(sensor), getattr(DEFAULT_SENSOR_NOISE, sensor)
    return non_negative_spec(name, default, description, unit, float_range=(0.0, 1.0))


def true_geometry_file_spec(description):
    """``true_geometry_file`` (read-only): the real platform's geometry params file."""
    return ParameterSpec(
        'true_geometry_file',
        default_geometry_path('true'),
        description,
        read_only=True,
        check=not_blank('a geometry file'),
        default_text='gsp_kinematics/data/true_geometry.yaml (shipped)',
    )


def controller_name_spec(description):
    """``controller_name`` (read-only): a ros2_control joint_trajectory_controller."""
    return ParameterSpec(
        'controller_name',
        'joint_trajectory_controller',
        description,
        read_only=True,
        check=not_blank('a controller'),
    )


def joint_names_spec(description):
    """``joint_names`` (read-only): the ros2_control joints of legs 1..6, in leg order."""
    return ParameterSpec(
        'joint_names',
        list(names.LEG_JOINT_NAMES),
        description,
        read_only=True,
        check=lambda v: '' if len(v) == 6 and len(set(v)) == 6 else 'must be 6 distinct names',
    )


def _spec_table(specs):
    return specs if isinstance(specs, dict) else {spec.name: spec for spec in specs}


def validate_values(specs, values):
    """Reason ('' if none) why ``{name: value}`` fails the checks of ``specs`` (others pass)."""
    table = _spec_table(specs)
    reasons = (table[name].reason(value) for name, value in values.items() if name in table)
    return next((reason for reason in reasons if reason), '')


def declare_parameters(node, specs, validate=None):
    """Declare ``specs`` on ``node``; ``{name: value}``, or :class:`ConfigurationError`.

    ``validate``: optional ``{name: value} -> reason`` check of the whole set.
    """
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

    specs = tuple(_spec_table(specs).values())
    try:
        for spec in specs:
            node.declare_parameter(spec.name, spec.default, spec.descriptor())
    except (InvalidParameterValueException, InvalidParameterTypeException) as error:
        raise ConfigurationError(str(error)) from None
    values = {spec.name: node.get_parameter(spec.name).value for spec in specs}
    reason = validate_values(specs, values) or (validate(values) if validate is not None else '')
    if reason:
        raise ConfigurationError(reason)
    return values


def parameter_values(node, specs):
    """``{name: value}`` of the current values of ``specs`` on ``node``."""
    return {name: node.get_parameter(name).value for name in _spec_table(specs)}


def watch_parameters(node, specs, apply=None, validate=None):
    """Reject run-time changes failing a check or ``validate(changes, current)``; pass the
    accepted changes of ``specs`` to ``apply({name: value})``."""
    from rcl_interfaces.msg import SetParametersResult

    table = _spec_table(specs)

    def on_set(parameters):
        changes = {p.name: p.value for p in parameters}
        reason = validate_values(table, changes)
        if not reason and validate is not None:
            reason = validate(changes, parameter_values(node, table))
        return SetParametersResult(successful=not reason, reason=reason)

    def post_set(parameters):
        changes = {p.name: p.value for p in parameters if p.name in table}
        if changes and apply is not None:
            apply(changes)

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)
