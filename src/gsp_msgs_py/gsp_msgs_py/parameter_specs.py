"""The parameter tables of the gsp-calibration nodes: specs, checks, declaration, docs.

A node file is a table of :class:`ParameterSpec`, its wiring and ``main``
(:mod:`gsp_msgs_py.node_tools`)::

    PARAMETERS = (
        ParameterSpec('publish_rate', 200.0, 'Rate of the readings', unit='Hz',
                      read_only=True, check=greater_than(0.0)),
        ...
    )

    class MyNode(Node):
        def __init__(self, **kwargs):
            super().__init__('my_node', **kwargs)
            values = declare_parameters(self, PARAMETERS)   # ConfigurationError if invalid
            watch_parameters(self, PARAMETERS, apply=self._apply)

    def main(args=None):
        return run_node(MyNode, args, logger_name='my_node')

A check is a function ``value -> reason`` ('' when the value is accepted); the reason completes
``'<name>: <value> rejected, <reason>'``. The ``check`` factories below cover the usual cases.
"""

import dataclasses
import math

import numpy as np

from gsp_kinematics.model.motion import DEFAULT_SENSOR_RATE_HZ
from gsp_kinematics.model.sensor_noise import (
    DEFAULT_SENSOR_NOISE,
    NOISE_UNITS,
)

from . import names
from .noise_parameters import TRUE_NOISE_PARAMETER

# rclpy is imported inside the functions that need a node, so that pure modules (the
# calibrator's settings table, the docs generator) can import specs and checks without loading it.


class ConfigurationError(ValueError):
    """A parameter value prevents a node from starting; the message names the parameter."""


def is_finite_number(value):
    """True for an int or float that is finite (bools and strings are not numbers here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


# --- checks ------------------------------------------------------------------------------------
# Each factory takes an optional ``reason`` that replaces its default reason.


def _unit(unit):
    return f' {unit}' if unit else ''


def greater_than(bound, unit='', reason=None):
    """Check: a finite number > ``bound``."""
    why = reason or f'must be > {bound:g}{_unit(unit)}'
    return lambda v: '' if is_finite_number(v) and v > bound else why


def at_least(bound, unit='', reason=None):
    """Check: a finite number >= ``bound``."""
    why = reason or f'must be >= {bound:g}{_unit(unit)}'
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


# --- parameter specs ---------------------------------------------------------------------------

#: ROS parameter type names by Python type of the default (``ros2 param describe`` wording).
_TYPE_NAMES = {bool: 'bool', int: 'integer', float: 'double', str: 'string'}


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """One node parameter: its default (which fixes its ROS type), description and checks.

    ``float_range`` / ``integer_range`` are ``(from, to)`` pairs that ROS itself enforces;
    ``check`` is a function ``value -> reason`` ('' if accepted) applied at start-up and to every
    run-time change; ``constraints`` is the descriptor's human-readable summary of both.
    ``default_text`` is how the docs show a default that depends on the installation (a path).
    ``subsets``: names of the node's subsets of its parameters this one belongs to (the
    calibrator's: stored with a run, deciding the selection, accepted on a command line).
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
            descriptor.floating_point_range = [
                FloatingPointRange(
                    from_value=float(self.float_range[0]),
                    to_value=float(self.float_range[1]),
                    step=0.0,
                )
            ]
        if self.integer_range is not None:
            descriptor.integer_range = [
                IntegerRange(
                    from_value=int(self.integer_range[0]),
                    to_value=int(self.integer_range[1]),
                    step=1,
                )
            ]
        return descriptor

    def reason(self, value):
        """'' if ``value`` passes :attr:`check`, else ``'<name>: <value> rejected, <why>'``."""
        why = self.check(value) if self.check is not None else ''
        if not why:
            return ''
        shown = value if not isinstance(value, (list, tuple)) or len(value) < 8 else '[...]'
        return f'{self.name}: {shown!r} rejected, {why}'


# --- parameters several nodes share (same name, type and checks everywhere) -----------------


def publish_rate_spec(what, default=DEFAULT_SENSOR_RATE_HZ):
    """``publish_rate`` (Hz, read-only): the rate of ``what``."""
    return ParameterSpec(
        'publish_rate',
        default,
        f'Rate of {what}',
        unit='Hz',
        read_only=True,
        constraints='> 0',
        check=greater_than(0.0, 'Hz'),
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
    """The noise seed a node uses: ``seed`` if >= 0, else a fresh one in [0, 2**31) from the OS
    entropy.

    Fresh by default because a simulated sensor restarted with a fixed seed replays the noise of
    its previous life: a resumed calibration would then average the same draws twice and its
    parameters would be less independent than their standard deviations say (docs/faults.md).
    """
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
    return ParameterSpec(
        'settle_time',
        0.05,
        f"Time from the legs' arrival to the 'settled' status of {what}",
        unit='s',
        float_range=(0.0, 60.0),
        check=at_least(0.0, 's'),
    )


def diagnostics_period_spec():
    """``diagnostics_period`` (s, read-only): how often the node publishes its health on
    ``/diagnostics`` (:class:`gsp_msgs_py.diagnostics.DiagnosticsPublisher`)."""
    return ParameterSpec(
        'diagnostics_period',
        1.0,
        f'Period of the health reports on {names.TOPIC_DIAGNOSTICS}',
        unit='s',
        read_only=True,
        float_range=(0.01, 60.0),
        check=greater_than(0.0, 's'),
    )


def motion_limit_specs(speed, acceleration, read_only=False):
    """``max_leg_speed`` (m/s) and ``max_leg_acceleration`` (m/s^2) of the simulated legs, with
    these defaults; 0 removes a limit (:class:`gsp_kinematics.model.motion.MotionLimits`)."""
    return tuple(
        ParameterSpec(
            name,
            float(default),
            f'{what} limit of every leg (synchronised moves, docs/planning.md); 0: no limit',
            unit=unit,
            read_only=read_only,
            float_range=(0.0, 1e3),
            constraints='>= 0',
            check=at_least(0.0, unit),
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
    return ParameterSpec(
        TRUE_NOISE_PARAMETER.format(sensor),
        getattr(DEFAULT_SENSOR_NOISE, sensor),
        description,
        unit=unit,
        float_range=(0.0, 1.0),
        check=at_least(0.0, unit),
    )


def geometry_file_spec(name, default, description, default_text=''):
    """A read-only geometry params file parameter."""
    return ParameterSpec(
        name,
        default,
        description,
        read_only=True,
        check=not_blank('a geometry file'),
        default_text=default_text,
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
    """Reason ('' if none) why ``{name: value}`` fails the checks of ``specs``.

    Names without a spec are not checked (another part of the node owns them).
    """
    table = _spec_table(specs)
    for name, value in values.items():
        spec = table.get(name)
        if spec is not None:
            reason = spec.reason(value)
            if reason:
                return reason
    return ''


def declare_parameters(node, specs, validate=None):
    """Declare every spec on ``node`` and check the values it starts with.

    ``validate``: optional ``{name: value} -> reason`` check of the whole set (e.g. a value that
    must not exceed another). Returns ``{name: value}``; raises :class:`ConfigurationError`
    naming the parameter when a value has the wrong type, is out of range or fails a check.
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
    """Check run-time changes of ``specs`` and hand the accepted ones to ``apply``.

    The on-set callback rejects a change with the reason of the first failed check; then
    ``validate(changes, current)`` (optional, ``{name: value}`` of the change and of every spec's
    current value) may reject it too, returning a reason. The post-set callback calls
    ``apply({name: value})`` with the accepted changes of ``specs`` (names of other parameters
    are left out; nothing is called when none changed).
    """
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


# --- documentation -----------------------------------------------------------------------------


def _format_value(value):
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f'{value:.6g}'
    if isinstance(value, str):
        return repr(value)
    return str(value)


def _format_default(spec):
    if spec.default_text:
        return spec.default_text
    value = spec.default
    if isinstance(value, (list, tuple)):
        shown = ', '.join(_format_value(v) for v in value[:6])
        more = f', ... ({len(value)} values)' if len(value) > 6 else ''
        return f'[{shown}{more}]'
    return _format_value(value)


def _format_constraints(spec):
    parts = [spec.constraints] if spec.constraints else []
    for bounds in (spec.float_range, spec.integer_range):
        if bounds is not None:
            parts.append(f'in [{_format_value(bounds[0])}, {_format_value(bounds[1])}]')
    return '; '.join(parts)


def parameter_table_markdown(specs):
    """A Markdown table of ``specs``: name, type, default, unit, read-only, constraints and
    description, one row per parameter in declaration order."""

    def cell(text):
        # '|' would end the cell; '<' would open an HTML tag (e.g. '<UTC timestamp>/').
        return str(text).replace('|', '\\|').replace('<', '&lt;').replace('\n', ' ')

    rows = [
        '| name | type | default | unit | read-only | constraints | description |',
        '| --- | --- | --- | --- | --- | --- | --- |',
    ]
    for spec in _spec_table(specs).values():
        rows.append(
            '| '
            + ' | '.join(
                cell(text)
                for text in (
                    f'`{spec.name}`',
                    spec.type_name,
                    f'`{_format_default(spec)}`',
                    spec.unit,
                    'yes' if spec.read_only else 'no',
                    _format_constraints(spec),
                    spec.description,
                )
            )
            + ' |'
        )
    return '\n'.join(rows) + '\n'
