"""Helpers shared by the gsp-calibration nodes: parameter descriptors and a ``main()`` runner."""

import math

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException


class ConfigurationError(ValueError):
    """A parameter value prevents a node from starting; the message names the parameter."""


def is_finite_number(value):
    """True for an int or float that is finite (bools and strings are not numbers here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


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
    descriptor = ParameterDescriptor(description=description, read_only=read_only,
                                     additional_constraints=constraints)
    if float_range is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float_range[0], to_value=float_range[1], step=0.0)]
    if integer_range is not None:
        descriptor.integer_range = [
            IntegerRange(from_value=integer_range[0], to_value=integer_range[1], step=1)]
    return descriptor


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
