"""``platform_sim``'s ``physics.*`` parameters (``PhysicalParameters`` and the in-position rule),
read once at start-up (docs/physics.md)."""

import dataclasses

from gsp_msgs_py.parameter_specs import ParameterSpec, positive_spec

from .physics import DEFAULT_IN_POSITION_TIME, DEFAULT_IN_POSITION_WINDOW
from .physics_model import FIELD_DOCS, PhysicalParameters

PREFIX = 'physics.'
#: The backends of ``platform_sim``.
BACKENDS = ('kinematic', 'physics')


def _value(default):
    if isinstance(default, tuple):
        return [float(v) for v in default]
    return default if isinstance(default, bool) else float(default)


PHYSICS_SPECS = (
    *(
        ParameterSpec(
            PREFIX + field.name,
            _value(field.default),
            f'physics backend: {FIELD_DOCS[field.name][1]}',
            unit=FIELD_DOCS[field.name][0],
            read_only=True,
        )
        for field in dataclasses.fields(PhysicalParameters)
    ),
    positive_spec(
        PREFIX + 'in_position_window',
        DEFAULT_IN_POSITION_WINDOW,
        'physics backend: the controller reports a move done (settled) once every encoder is '
        'this close to its target ...',
        'm',
        read_only=True,
    ),
    positive_spec(
        PREFIX + 'in_position_time',
        DEFAULT_IN_POSITION_TIME,
        'physics backend: ... for this long',
        's',
        read_only=True,
    ),
)


def physics_from_values(values):
    """``(PhysicalParameters, in_position_window, in_position_time)`` from the node's values;
    ValueError naming a bad one."""
    fields = {
        field.name: values[PREFIX + field.name] for field in dataclasses.fields(PhysicalParameters)
    }
    for name in ('platform_inertia', 'payload_center'):
        if len(fields[name]) != 3:
            raise ValueError(f'{PREFIX}{name} must have 3 values, got {len(fields[name])}')
        fields[name] = tuple(float(v) for v in fields[name])
    return (
        PhysicalParameters(**fields),
        values[PREFIX + 'in_position_window'],
        values[PREFIX + 'in_position_time'],
    )
