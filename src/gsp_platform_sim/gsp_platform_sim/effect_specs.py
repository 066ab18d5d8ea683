"""``platform_sim``'s ``effects.*`` parameters: one per ``PlatformEffects`` field, read once at
start-up; the defaults switch every effect off (docs/platform_effects.md)."""

from gsp_kinematics.model.effects import FIELDS, EffectsError, PlatformEffects
from gsp_msgs_py.parameter_specs import ParameterSpec, is_finite_number

PREFIX = 'effects.'


def _spec(name, shape, unit, description, default):
    signed = name == 'centre_of_mass'
    what = 'a finite number' if shape is None else f'{shape} finite numbers'
    why = f'must be {what}' + ('' if signed else f' >= 0 {unit}')

    def check(value):
        values = [value] if shape is None else list(value)
        finite = len(values) == (shape or 1) and all(is_finite_number(v) for v in values)
        return '' if finite and (signed or min(values) >= 0.0) else why

    value = float(default) if shape is None else [float(v) for v in default]
    return ParameterSpec(
        PREFIX + name,
        value,
        f'Real platform: {description} (docs/platform_effects.md)',
        unit=unit,
        read_only=True,
        constraints=('' if signed else '>= 0') + ('' if shape is None else f', {shape} values'),
        check=check,
    )


_DEFAULTS = PlatformEffects()
EFFECT_SPECS = tuple(
    _spec(name, shape, unit, description, getattr(_DEFAULTS, name))
    for name, shape, unit, description in FIELDS
)


def effects_from_values(values):
    """:class:`PlatformEffects` of the checked ``{'effects.<field>': value}``; ValueError naming
    the parameter if they do not make one (a zero time constant)."""
    try:
        return PlatformEffects.from_parameters(values, PREFIX)
    except EffectsError as error:
        raise ValueError(f'{PREFIX}{error}') from None


def effects_summary(effects):
    """One line for the start-up log: the effects that are on."""
    if effects.ideal:
        return 'no platform effects (rigid, ideal)'
    parts = []
    if effects.compliant:
        stiffness = effects.leg_stiffness
        parts.append(
            f'{effects.payload_mass:g} kg on legs of {stiffness.min() * 1e-6:g}-'
            f'{stiffness.max() * 1e-6:g} N/um'
            + (f' of up to {effects.leg_mass.max():g} kg' if any(effects.leg_mass) else '')
        )
    if any(effects.backlash):
        parts.append(f'backlash up to {effects.backlash.max() * 1e6:g} um')
    if effects.thermal:
        parts.append(
            f'legs warming up to {effects.temperature_rise.max():g} K '
            f'(time constant {effects.thermal_time_constant:g} s)'
        )
    if any(effects.base_joint_offsets):
        parts.append(f'base joint axes up to {effects.base_joint_offsets.max() * 1e6:g} um apart')
    return 'platform effects: ' + ', '.join(parts)
