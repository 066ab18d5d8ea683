"""The ``geometry.*`` parameters of a node that plays the platform's controller."""

from gsp_kinematics.model.effects import EffectDesignError
from gsp_kinematics.model.geometry import (
    GeometryError,
    default_geometry,
    geometry_from_parameters,
    geometry_to_parameters,
)

from .parameter_specs import ParameterSpec

_NOMINAL_PARAMETERS = geometry_to_parameters(default_geometry('nominal'), all_effects=True)
GEOMETRY_PARAMETER_NAMES = tuple(_NOMINAL_PARAMETERS)
#: Prefix of the identified effects' parameters: a controller that declares none of them runs
#: the rigid geometry only (the calibrator then applies the effects folded in).
EFFECT_PARAMETER_PREFIX = 'geometry.effects.'
#: The ``geometry.effects.*`` parameters a controller that compensates the effects declares.
EFFECT_PARAMETER_NAMES = tuple(
    name for name in GEOMETRY_PARAMETER_NAMES if name.startswith(EFFECT_PARAMETER_PREFIX)
)
#: name -> (description, unit) of the controller geometry parameters.
_GEOMETRY_DESCRIPTIONS = {
    'geometry.base_joints': (
        'Controller model: base joints A_1..A_6 as 18 values x1 y1 z1 ...',
        'm, base frame',
    ),
    'geometry.platform_joints': (
        'Controller model: platform joints B_1..B_6 as 18 values',
        'm, platform frame',
    ),
    'geometry.leg_offsets': (
        'Controller model: leg offsets L_off_1..L_off_6, L_i = q_i + L_off_i',
        'm',
    ),
    'geometry.device_length': (
        'Controller model: measuring device length D0 (m; unused by the platform)',
        '',
    ),
    'geometry.inclinometer_axes_angle': (
        'Controller model: inclinometer axes angle gamma (rad; unused by the platform)',
        '',
    ),
    'geometry.limits.leg_stroke_min': ('Smallest commandable articular variable q', 'm'),
    'geometry.limits.leg_stroke_max': ('Largest commandable articular variable q', 'm'),
    'geometry.limits.base_joint_max_angle': ('Largest leg angle to the base normal', 'rad'),
    'geometry.limits.platform_joint_max_angle': ('Largest leg angle to the platform normal', 'rad'),
    'geometry.sensors.leg_gain_errors': (
        'Controller model: leg sensor gain errors kq_1..kq_6; the controller drives leg i '
        'until its sensor reads IK / (1 + kq_i) (docs/sensor_errors.md)',
        '1',
    ),
    'geometry.sensors.inclinometer_offsets': (
        'Controller model: inclinometer zero offsets alpha0, beta0 (unused by the platform)',
        'rad',
    ),
    'geometry.sensors.encoder_offset': (
        'Controller model: encoder zero phi0 (unused by the platform)',
        'rad',
    ),
    'geometry.sensors.lvdt_gain_error': (
        'Controller model: LVDT gain error kDm (unused by the platform)',
        '1',
    ),
    # Identified effects, compensated by the controller (docs/platform_effects.md).
    'geometry.effects.compliance': ('Identified effect: axial compliance of legs 1..6', 'm/N'),
    'geometry.effects.backlash': (
        'Identified effect: backlash of legs 1..6 (a leg arriving extending is driven half of '
        'it further)',
        'm',
    ),
    'geometry.effects.strain_rate': (
        'Identified effect: thermal growth rate of legs 1..6 during the run (reported, not '
        'compensated)',
        '1/s',
    ),
    'geometry.effects.joint_offset': (
        'Identified effect: distance between the two axes of base U joints 1..6',
        'm',
    ),
    'geometry.effects.payload_mass': (
        'The mass the compliance was identified for (the platform and its payload)',
        'kg',
    ),
    'geometry.effects.centre_of_mass': ('Its centre, platform frame', 'm'),
    'geometry.effects.leg_mass': ("The legs' own masses 1..6, loading the compliance too", 'kg'),
    'geometry.effects.reference_time': (
        'Instant the geometry refers to (thermal growth), on the run clock',
        's',
    ),
}

#: The specs, nominal defaults; the whole set must stay a valid geometry.
CONTROLLER_GEOMETRY_SPECS = tuple(
    ParameterSpec(
        name,
        _NOMINAL_PARAMETERS[name],
        *_GEOMETRY_DESCRIPTIONS[name],
        constraints='the whole geometry.* set must be valid '
        '(geometry_from_parameters); applies from the next pose command',
    )
    for name in GEOMETRY_PARAMETER_NAMES
)


def controller_geometry_error(values):
    """Why the ``geometry.*`` entries of ``{name: value}`` are not a valid geometry ('' if they
    are)."""
    try:
        controller_geometry(values)
    except (GeometryError, EffectDesignError) as error:  # the effects' own checks (leg_mass)
        return str(error)
    return ''


def validate_geometry_change(changes, current):
    """Run-time check: the geometry after ``changes`` must be valid as a whole."""
    if not any(name in GEOMETRY_PARAMETER_NAMES for name in changes):
        return ''
    return controller_geometry_error({**current, **changes})


def controller_geometry(values):
    """The Geometry of the ``geometry.*`` entries of ``{name: value}`` (GeometryError if bad)."""
    return geometry_from_parameters({name: values[name] for name in GEOMETRY_PARAMETER_NAMES})
