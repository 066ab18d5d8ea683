"""The effects' parameters and each effect's physics, vectorised over postures (M)
(docs/platform_effects.md)."""

import dataclasses

import numpy as np

from ..rotation import euler_to_matrix
from .kinematics import home_pose, leg_vectors

NUM_LEGS = 6
#: Standard gravity (m/s^2), along -z of the base frame.
GRAVITY = 9.80665
#: Linear expansion coefficient of steel (1/K), the default material of the legs.
STEEL_EXPANSION = 12e-6
#: Where a leg's centre of mass and its spring sit, as fractions of the joint-to-joint length
#: from the base U joint (a uniform bar; the compliance of the actuator's screw and nut).
LEG_CENTRE_OF_MASS = 0.5
LEG_SPRING_POSITION = 0.5

# (field, shape (None: scalar), unit, description): the table the node parameters and the
# docs derive from.
FIELDS = (
    ('payload_mass', None, 'kg', 'mass the legs carry: moving platform and payload'),
    ('centre_of_mass', 3, 'm', 'centre of that mass, platform frame'),
    ('leg_mass', NUM_LEGS, 'kg', 'mass of each leg (a uniform bar between its joints)'),
    ('leg_stiffness', NUM_LEGS, 'N/m', 'axial stiffness of each leg (0: rigid)'),
    ('backlash', NUM_LEGS, 'm', 'lost motion of each leg between its two approach directions'),
    ('thermal_expansion', None, '1/K', 'linear expansion coefficient of the legs'),
    ('temperature_rise', NUM_LEGS, 'K', 'final temperature rise of each leg'),
    ('thermal_time_constant', None, 's', 'time constant of the first-order temperature rise'),
    ('base_joint_offsets', NUM_LEGS, 'm', 'distance between the two axes of each base U joint'),
)


class EffectsError(ValueError):
    """An effect parameter is malformed; the message names it."""


@dataclasses.dataclass(frozen=True)
class PlatformEffects:
    """The effects' parameters (SI units, all effects off by default: the rigid ideal platform)."""

    payload_mass: float = 0.0
    centre_of_mass: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    leg_mass: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_LEGS))
    leg_stiffness: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_LEGS))
    backlash: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_LEGS))
    thermal_expansion: float = STEEL_EXPANSION
    temperature_rise: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_LEGS))
    thermal_time_constant: float = 300.0
    base_joint_offsets: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_LEGS))

    def __post_init__(self):
        for name, shape, unit, _ in FIELDS:
            raw = getattr(self, name)
            try:
                value = np.array(raw, dtype=float)
                value = float(value) if shape is None else value.reshape(shape)
            except (TypeError, ValueError):
                size = 'a number' if shape is None else f'{shape} numbers'
                raise EffectsError(f'{name}: expected {size}, got {raw!r}') from None
            if not np.all(np.isfinite(value)):
                raise EffectsError(f'{name}: not finite ({raw!r})')
            if name != 'centre_of_mass' and np.any(np.asarray(value) < 0.0):
                raise EffectsError(f'{name}: must be >= 0 {unit}, got {np.round(value, 12)}')
            if shape is not None:
                value.setflags(write=False)
            object.__setattr__(self, name, value)
        if not self.thermal_time_constant > 0.0:
            raise EffectsError(
                f'thermal_time_constant: must be > 0 s, got {self.thermal_time_constant}'
            )

    @property
    def compliant(self):
        loaded = self.payload_mass > 0.0 or bool(np.any(self.leg_mass > 0.0))
        return loaded and bool(np.any(self.leg_stiffness > 0.0))

    @property
    def thermal(self):
        return self.thermal_expansion > 0.0 and bool(np.any(self.temperature_rise > 0.0))

    @property
    def ideal(self):
        """True when no effect is on (the platform is the rigid 44-parameter model)."""
        return not (
            self.compliant
            or self.thermal
            or np.any(self.backlash > 0.0)
            or np.any(self.base_joint_offsets > 0.0)
        )

    @property
    def leg_compliance(self):
        """``1 / leg_stiffness`` (6,) m/N; 0 for a rigid leg (stiffness 0)."""
        stiffness = self.leg_stiffness
        return np.divide(1.0, stiffness, out=np.zeros(NUM_LEGS), where=stiffness > 0.0)

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)

    def to_parameters(self, prefix=''):
        """``{prefix + field: value}`` with lists for the per-leg fields (ROS parameters)."""
        return {
            prefix + name: (float(value) if np.ndim(value) == 0 else value.tolist())
            for name, value in ((name, getattr(self, name)) for name, *_ in FIELDS)
        }

    @classmethod
    def from_parameters(cls, values, prefix=''):
        """From ``{prefix + field: value}``; absent fields keep their defaults."""
        return cls(
            **{name: values[prefix + name] for name, *_ in FIELDS if prefix + name in values}
        )


#: A realistic platform (docs/platform_effects.md): 40 kg on 30 N/um legs, centre of mass
#: 50 mm above the platform joints, 4 um backlash, legs warming 1.5 K within 15 min (three time
#: constants), base U joints with 20 um between their axes.
REALISTIC = PlatformEffects(
    payload_mass=40.0,
    centre_of_mass=(0.0, 0.0, 0.05),
    leg_stiffness=np.full(NUM_LEGS, 30e6),
    backlash=np.full(NUM_LEGS, 4e-6),
    temperature_rise=np.full(NUM_LEGS, 1.5),
    thermal_time_constant=300.0,
    base_joint_offsets=np.full(NUM_LEGS, 20e-6),
)
#: Named presets (``gsp_demo --platform-effects``).
PRESETS = {'none': PlatformEffects(), 'realistic': REALISTIC}


# --- backlash -----------------------------------------------------------------------------------


def approach_directions(leg_readings, previous=None, initial=None):
    """Direction (M, 6) from which each leg arrives at each row of ``leg_readings`` (M, 6): +1
    extending, -1 retracting, a still leg keeping its last. ``previous`` (6,): the readings before
    (None: the first row is the start); ``initial`` (6,): the directions before (default +1)."""
    readings = np.atleast_2d(np.asarray(leg_readings, dtype=float))
    start = np.broadcast_to(
        1.0 if initial is None else np.asarray(initial, dtype=float), (NUM_LEGS,)
    )
    before = readings[:1] if previous is None else np.asarray(previous, dtype=float)[None]
    steps = np.sign(np.diff(np.concatenate([before, readings]), axis=0))
    # Forward-fill the zero steps with the last nonzero one (or the initial direction).
    filled = np.concatenate([start[None], steps])
    index = np.where(filled != 0.0, np.arange(filled.shape[0])[:, None], 0)
    index = np.maximum.accumulate(index, axis=0)
    return np.take_along_axis(filled, index, axis=0)[1:]


def backlash_lengths(effects, directions):
    """Leg length change (M, 6) m of the backlash for the approach ``directions`` (M, 6)."""
    return -0.5 * np.asarray(directions, dtype=float) * effects.backlash


# --- thermal growth -----------------------------------------------------------------------------


def temperature_rises(effects, times_s):
    """Temperature rise (M, 6) K of each leg at ``times_s`` (M,) s since the start."""
    times = np.maximum(np.atleast_1d(np.asarray(times_s, dtype=float)), 0.0)
    fraction = -np.expm1(-times / effects.thermal_time_constant)
    return fraction[:, None] * effects.temperature_rise[None]


def thermal_strains(effects, times_s):
    """Relative growth (M, 6) of each leg at ``times_s`` (M,)."""
    return effects.thermal_expansion * temperature_rises(effects, times_s)


# --- joint offsets ------------------------------------------------------------------------------


def _unit(vectors):
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def base_joint_first_axes(geometry):
    """First axis (6, 3) of each base U joint: horizontal, perpendicular to its leg at the home
    pose (the axis about which the leg's main tilt turns); for a leg vertical there, tangent to
    the base circle."""
    vectors, _ = leg_vectors(geometry, home_pose()[None])
    axes = np.cross([0.0, 0.0, 1.0], vectors[0])
    vertical = np.linalg.norm(axes, axis=1) < 1e-9 * np.linalg.norm(vectors[0], axis=1)
    axes[vertical] = np.cross([0.0, 0.0, 1.0], geometry.base_joints[vertical])
    return _unit(axes)


def effective_base_joints(geometry, effects, poses, iterations=3):
    """Effective base joint points (M, 6, 3): on each joint's second axis where the leg's line
    crosses it, ``A_i + e_i n_i`` with ``n_i`` the unit part of the leg direction normal to the
    first axis. The leg direction depends on the point: a fixed point iteration (each one
    multiplies the error by about e / L)."""
    poses = np.atleast_2d(poses)
    rotation = euler_to_matrix(poses[:, 3:])
    platform_points = (
        np.einsum('mjk,ik->mij', rotation, geometry.platform_joints) + poses[:, None, :3]
    )
    base = np.broadcast_to(geometry.base_joints, platform_points.shape)
    offsets = effects.base_joint_offsets
    if not np.any(offsets):
        return base.copy()
    axes = base_joint_first_axes(geometry)
    points = base
    for _ in range(iterations):
        direction = _unit(platform_points - points)
        normal = _unit(direction - np.einsum('mik,ik->mi', direction, axes)[..., None] * axes)
        points = base + offsets[None, :, None] * normal
    return points


# --- compliance ---------------------------------------------------------------------------------


def leg_forces(geometry, effects, poses, base_points=None):
    """Axial forces (M, 6) N in the legs' springs, compression positive, holding the platform's
    and the legs' weight at ``poses`` (M, 6) (the statics: docs/platform_effects.md; NaN at a
    singular pose). ``base_points`` (M, 6, 3): the effective base joints (default: ``A_i``)."""
    poses = np.atleast_2d(poses)
    rotation = euler_to_matrix(poses[:, 3:])
    arms = np.einsum('mjk,ik->mij', rotation, geometry.platform_joints)
    if base_points is None:
        base_points = np.broadcast_to(geometry.base_joints, arms.shape)
    directions = _unit(arms + poses[:, None, :3] - base_points)
    wrenches = np.concatenate([directions, np.cross(arms, directions)], axis=2)  # (M, 6 legs, 6)
    weight = np.array([0.0, 0.0, -effects.payload_mass * GRAVITY])
    centre = np.einsum('mjk,k->mj', rotation, effects.centre_of_mass)
    load = np.concatenate([np.broadcast_to(weight, centre.shape), np.cross(centre, weight)], axis=1)
    leg_weights = -GRAVITY * effects.leg_mass  # (6,) N along z
    axial = leg_weights * directions[..., 2]  # (M, 6): the weight's part along u_i
    across = LEG_CENTRE_OF_MASS * (
        leg_weights[:, None] * np.array([0.0, 0.0, 1.0]) - axial[..., None] * directions
    )  # (M, 6, 3): the force each leg's weight puts on its platform joint
    load = load + np.concatenate([across.sum(axis=1), np.cross(arms, across).sum(axis=1)], axis=1)
    matrices = np.swapaxes(wrenches, 1, 2)
    held = np.linalg.det(matrices) != 0.0  # a singular pose's legs hold no load: NaN there
    at_platform = np.full(load.shape, np.nan)
    at_platform[held] = np.linalg.solve(matrices[held], -load[held, :, None])[..., 0]
    return at_platform - (1.0 - LEG_SPRING_POSITION) * axial


#: Group -> its per-leg parameter name stem, unit and what it is.
EFFECT_GROUPS = {
    'compliance': ('compliance', 'm/N', 'axial compliance of each leg (1 / stiffness)'),
    'backlash': ('backlash', 'm', 'lost motion between the approach directions'),
    'thermal': ('strain_rate', '1/s', 'relative growth rate of each leg'),
    'joint_offsets': ('joint_offset', 'm', 'distance between the base U joint axes'),
}
#: The effect parameters, group by group, leg by leg.
EFFECT_PARAMETER_NAMES = tuple(
    f'{stem}{leg}' for stem, _, _ in EFFECT_GROUPS.values() for leg in range(1, NUM_LEGS + 1)
)
NUM_EFFECT_PARAMETERS = len(EFFECT_PARAMETER_NAMES)


class EffectDesignError(ValueError):
    """An effect group lacks what it needs (times, directions, a mass); the message says which."""


@dataclasses.dataclass(frozen=True)
class IdentifiedEffects:
    """Effect parameters a calibration identified: ``values`` (24,) in
    :data:`EFFECT_PARAMETER_NAMES` order (0: not identified), ``payload_mass`` (kg),
    ``centre_of_mass`` (platform frame, m), ``reference_time_s`` (s) and ``leg_mass`` (6,) kg."""

    values: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_EFFECT_PARAMETERS))
    payload_mass: float = 0.0
    centre_of_mass: tuple = (0.0, 0.0, 0.0)
    reference_time_s: float = 0.0
    leg_mass: tuple = (0.0,) * NUM_LEGS

    def __post_init__(self):
        object.__setattr__(self, 'leg_mass', tuple(float(m) for m in self.leg_mass))
        if len(self.leg_mass) != NUM_LEGS or not all(m >= 0.0 for m in self.leg_mass):
            raise EffectDesignError(f'leg_mass must be 6 masses >= 0 kg, got {self.leg_mass}')
        values = np.array(self.values, dtype=float).reshape(NUM_EFFECT_PARAMETERS)
        if not np.all(np.isfinite(values)):
            raise EffectDesignError(f'identified effects are not finite: {values.tolist()}')
        values.setflags(write=False)
        object.__setattr__(self, 'values', values)

    @classmethod
    def from_result_values(cls, values, design):
        """The effects of identified ``values`` (24,) of a run with the :class:`~gsp_kinematics.model.effect_groups.EffectDesign`."""
        return cls(
            values,
            design.payload_mass,
            design.centre_of_mass,
            design.reference_time_s,
            design.leg_mass,
        )

    @property
    def none(self):
        return not np.any(self.values)

    def groups(self):
        """The groups with a nonzero parameter."""
        blocks = self.values.reshape(len(EFFECT_GROUPS), NUM_LEGS)
        return [group for group, block in zip(EFFECT_GROUPS, blocks, strict=True) if block.any()]
