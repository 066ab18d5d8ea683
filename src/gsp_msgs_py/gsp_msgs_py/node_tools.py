"""The node skeleton shared by every gsp-calibration node.

A node file is a table of :class:`ParameterSpec`, its wiring and ``main``::

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

import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException


class ConfigurationError(ValueError):
    """A parameter value prevents a node from starting; the message names the parameter."""


def is_finite_number(value):
    """True for an int or float that is finite (bools and strings are not numbers here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


# --- checks ------------------------------------------------------------------------------------


def _unit(unit):
    return f' {unit}' if unit else ''


def greater_than(bound, unit=''):
    """Check: a finite number > ``bound``."""
    return lambda v: '' if is_finite_number(v) and v > bound else f'must be > {bound:g}{_unit(unit)}'


def at_least(bound, unit=''):
    """Check: a finite number >= ``bound``."""
    return lambda v: '' if is_finite_number(v) and v >= bound else f'must be >= {bound:g}{_unit(unit)}'


def not_blank(what='a value'):
    """Check: a string that is not empty or blank."""
    return lambda v: '' if str(v).strip() else f'must name {what}'


def one_of(options):
    """Check: one of ``options``."""
    options = tuple(options)
    return lambda v: '' if v in options else f'must be one of {list(options)}'


# --- parameter specs ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """One node parameter: its default (which fixes its ROS type), description and checks.

    ``float_range`` / ``integer_range`` are ``(from, to)`` pairs that ROS itself enforces;
    ``check`` is a function ``value -> reason`` ('' if accepted) applied at start-up and to every
    run-time change; ``constraints`` is the descriptor's human-readable summary of both.
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

    def descriptor(self):
        """The ``ParameterDescriptor`` ROS shows for this parameter."""
        description = self.description + (f' ({self.unit})' if self.unit else '')
        descriptor = ParameterDescriptor(
            description=description, read_only=self.read_only,
            additional_constraints=self.constraints)
        if self.float_range is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.float_range[0]), to_value=float(self.float_range[1]),
                step=0.0)]
        if self.integer_range is not None:
            descriptor.integer_range = [IntegerRange(
                from_value=int(self.integer_range[0]), to_value=int(self.integer_range[1]),
                step=1)]
        return descriptor

    def reason(self, value):
        """'' if ``value`` passes :attr:`check`, else ``'<name>: <value> rejected, <why>'``."""
        why = self.check(value) if self.check is not None else ''
        if not why:
            return ''
        shown = value if not isinstance(value, (list, tuple)) or len(value) < 8 else '[...]'
        return f'{self.name}: {shown!r} rejected, {why}'


def _spec_table(specs):
    return specs if isinstance(specs, dict) else {spec.name: spec for spec in specs}


def check_values(specs, values):
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
    specs = tuple(_spec_table(specs).values())
    try:
        for spec in specs:
            node.declare_parameter(spec.name, spec.default, spec.descriptor())
    except (InvalidParameterValueException, InvalidParameterTypeException) as error:
        raise ConfigurationError(str(error)) from None
    values = {spec.name: node.get_parameter(spec.name).value for spec in specs}
    reason = check_values(specs, values) or (validate(values) if validate is not None else '')
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
    table = _spec_table(specs)

    def on_set(parameters):
        changes = {p.name: p.value for p in parameters}
        reason = check_values(table, changes)
        if not reason and validate is not None:
            reason = validate(changes, parameter_values(node, table))
        return SetParametersResult(successful=not reason, reason=reason)

    def post_set(parameters):
        changes = {p.name: p.value for p in parameters if p.name in table}
        if changes and apply is not None:
            apply(changes)

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)


# --- main --------------------------------------------------------------------------------------


def run_node(make_node, args=None, executor=None, *, logger_name):
    """Initialise rclpy, build a node with ``make_node()`` and spin it until shutdown.

    ``executor`` is an executor instance or a factory (e.g. a class) called after the node is
    built; without one the node is spun with ``rclpy.spin``. Returns the process exit code:
    1 if the node raised :class:`ConfigurationError` (logged as fatal under ``logger_name``),
    otherwise 0 (including Ctrl-C and external shutdown).
    """
    rclpy.init(args=args)
    node = None
    active_executor = None
    exit_code = 0
    try:
        node = make_node()
        if executor is None:
            rclpy.spin(node)
        else:
            active_executor = executor() if callable(executor) else executor
            active_executor.add_node(node)
            active_executor.spin()
    except ConfigurationError as error:
        rclpy.logging.get_logger(logger_name).fatal(f'cannot start: {error}')
        exit_code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # rclpy's signal handler shuts the context down from another thread; spin can then fail
        # to build its wait set (RCLError) instead of raising ExternalShutdownException.
        if rclpy.ok():
            raise
    finally:
        if active_executor is not None:
            active_executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return exit_code


# --- TEMPORARY (removed once every node uses ParameterSpec) -------------------------------------


def first_failed_check(checks, values):
    """Reason ('' if none) why ``{name: value}`` fails ``checks`` ``{name: (test, requirement)}``."""
    for name, value in values.items():
        if name in checks:
            test, requirement = checks[name]
            if not test(value):
                return f'{name}: {value!r} rejected, {requirement}'
    return ''


def parameter_descriptor(description, *, read_only=False, float_range=None, integer_range=None,
                         constraints=''):
    """A ``ParameterDescriptor``; ``float_range``/``integer_range`` are ``(from, to)`` pairs."""
    return ParameterSpec('', None, description, read_only=read_only, float_range=float_range,
                         integer_range=integer_range, constraints=constraints).descriptor()
