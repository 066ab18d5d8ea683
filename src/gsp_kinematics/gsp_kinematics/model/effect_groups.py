"""The effects as parameter groups of the identification (docs/platform_effects.md)."""

import dataclasses

import numpy as np

from .effects import (
    EFFECT_GROUPS,
    EFFECT_PARAMETER_NAMES,
    NUM_EFFECT_PARAMETERS,
    NUM_LEGS,
    EffectDesignError,
    IdentifiedEffects,
    PlatformEffects,
    approach_directions,
    base_joint_first_axes,
    leg_forces,
)
from .kinematics import (
    forward_kinematics_masked,
    inverse_kinematics,
    inverse_kinematics_jacobians,
    leg_vectors,
)

#: Among free parameter names: choose the effect groups from the data
#: (:func:`gsp_kinematics.estimation.verdict.model_choice.choose_model`); the other names are the plain model.
AUTO = 'auto'
#: The plain model of ``auto`` when no other name is given.
DEFAULT_AUTO_BASE = ('extended',)
#: The mass (kg) the compliance is identified for when the user gives none: the device
#: identifies the compliance times the load, so the per-leg ``c_i m / m_ref`` it finds with this
#: reference compensates the real load (at the stated centre of mass) exactly.
REFERENCE_PAYLOAD_MASS = 1.0


def split_auto(names):
    """``(plain names, auto)``: ``names`` without :data:`AUTO` (:data:`DEFAULT_AUTO_BASE` when
    nothing else is named) and whether it was among them."""
    names = [names] if isinstance(names, str) else list(names)
    if AUTO not in names:
        return names, False
    base = [n for n in names if n != AUTO]
    return (base or list(DEFAULT_AUTO_BASE)), True


@dataclasses.dataclass(frozen=True)
class EffectDesign:
    """What the effect groups need besides the readings (M rows in the run's order): ``times_s``
    (M,) s, approach ``directions`` (M, 6), the ``payload_mass`` (kg) and ``centre_of_mass``
    (platform frame, m), the thermal ``reference_time_s`` (s) and ``leg_mass`` (6,) kg."""

    times_s: np.ndarray | None = None
    directions: np.ndarray | None = None
    payload_mass: float = 0.0
    centre_of_mass: tuple = (0.0, 0.0, 0.0)
    reference_time_s: float = 0.0
    #: Time constant (s) of the legs' warming (first order, from ``times_s`` 0); 0: a linear
    #: growth. The strain rate is then the initial one.
    thermal_time_constant_s: float = 0.0
    leg_mass: tuple = (0.0,) * NUM_LEGS
    #: ``payload_mass`` is :data:`REFERENCE_PAYLOAD_MASS`, not the load's (the user gave none):
    #: the compliance identified is the legs' compliance times the load over it.
    payload_assumed: bool = False

    def thermal_clock(self, times_s):
        """The thermal regressor's clock (s): ``tau (1 - exp(-t / tau))``, or ``t`` when linear."""
        times = np.asarray(times_s, dtype=float)
        tau = self.thermal_time_constant_s
        return tau * -np.expm1(-np.maximum(times, 0.0) / tau) if tau > 0 else times

    def check(self, groups, count):
        """EffectDesignError naming what ``groups`` need and this design lacks for M = count."""
        if 'compliance' in groups and not self.payload_mass > 0.0:
            raise EffectDesignError('compliance needs the payload_mass (kg) the legs carry')
        if np.shape(self.leg_mass) != (NUM_LEGS,) or not np.all(np.asarray(self.leg_mass) >= 0):
            raise EffectDesignError(f'leg_mass must be 6 masses >= 0 kg, got {self.leg_mass}')
        if 'thermal' in groups and (self.times_s is None or np.shape(self.times_s) != (count,)):
            raise EffectDesignError(f'thermal needs times_s, one time (s) per posture ({count})')
        if 'backlash' in groups:
            if self.directions is None or np.shape(self.directions) != (count, NUM_LEGS):
                raise EffectDesignError(
                    f'backlash needs directions ({count}, 6), each leg +1 or -1 per posture'
                )
            if not np.all(np.isin(self.directions, (-1.0, 1.0))):
                raise EffectDesignError('backlash: directions must each be +1 or -1')


def effect_groups_of(names):
    """The effect groups among ``names`` (groups or effect parameter names)."""
    names = [names] if isinstance(names, str) else list(names)
    return [group for group in EFFECT_GROUPS if group in names]


def resolve_effects(free):
    """A mask (24,) over :data:`EFFECT_PARAMETER_NAMES` of the effect groups and effect
    parameter names in ``free`` (other names are ignored: they are the geometry's)."""
    names = [free] if isinstance(free, str) else list(free or ())
    mask = np.zeros(NUM_EFFECT_PARAMETERS, dtype=bool)
    for index, (group, (stem, _, _)) in enumerate(EFFECT_GROUPS.items()):
        block = slice(NUM_LEGS * index, NUM_LEGS * (index + 1))
        if group in names:
            mask[block] = True
        for leg in range(NUM_LEGS):
            if f'{stem}{leg + 1}' in names:
                mask[block.start + leg] = True
    return mask


def is_effect_name(name):
    return name in EFFECT_GROUPS or name in EFFECT_PARAMETER_NAMES


class EffectTerms:
    """The regressors of the free effect parameters (``mask`` (24,)) for a run."""

    def __init__(self, nominal, design, mask, count):
        self.mask = np.asarray(mask, dtype=bool)
        self.count = int(self.mask.sum())
        groups = [g for i, g in enumerate(EFFECT_GROUPS) if self.mask[6 * i : 6 * i + 6].any()]
        design.check(groups, count)
        self.nominal = nominal
        self.design = design
        self._load = PlatformEffects(
            payload_mass=design.payload_mass,
            centre_of_mass=design.centre_of_mass,
            leg_mass=design.leg_mass,
        )
        self._axes = base_joint_first_axes(nominal)
        self._legs = np.flatnonzero(self.mask) % NUM_LEGS  # the leg of each free parameter

    def regressors(self, poses, geometry=None):
        """``h`` (M, 6, count): column j is nonzero only in the row of its leg. ``geometry``: the
        geometry to take the forces and leg directions of (default the one given at
        construction); the identification passes its current estimate: at the extreme postures
        the forces are sensitive enough to the geometry that the nominal's are percents off."""
        poses = np.atleast_2d(poses)
        geometry = self.nominal if geometry is None else geometry
        full = np.zeros((poses.shape[0], NUM_LEGS, NUM_EFFECT_PARAMETERS))
        legs = np.arange(NUM_LEGS)
        blocks = self.mask.reshape(len(EFFECT_GROUPS), NUM_LEGS).any(axis=1)
        if blocks[0]:
            full[:, legs, legs] = leg_forces(geometry, self._load, poses)
        if blocks[1]:
            full[:, legs, 6 + legs] = 0.5 * np.asarray(self.design.directions, dtype=float)
        vectors, _ = leg_vectors(geometry, poses)
        lengths = np.linalg.norm(vectors, axis=2)
        if blocks[2]:
            clock = self.design.thermal_clock
            elapsed = clock(self.design.times_s) - clock(self.design.reference_time_s)
            full[:, legs, 12 + legs] = -elapsed[:, None] * lengths
        if blocks[3]:
            along = np.einsum('mik,ik->mi', vectors / lengths[..., None], self._axes)
            full[:, legs, 18 + legs] = -np.sqrt(np.maximum(1.0 - along**2, 0.0))
        return full[:, :, self.mask]


def compensated_leg_readings(
    geometry, identified, poses, directions=None, times_s=None, thermal=False
):
    """Leg readings (M, 6) that bring a platform with the ``identified`` effects to ``poses``
    (M, 6), ``q_i = (IK_i + sum theta h) / (1 + kq_i)``; ``directions`` (M, 6) default +1,
    ``times_s`` (M,) s; the thermal drift only with ``thermal`` (docs/platform_effects.md)."""
    poses = np.atleast_2d(poses)
    rigid = inverse_kinematics(geometry, poses)
    values = np.array(identified.values)
    if not thermal:
        values[12:18] = 0.0
    mask = values != 0.0
    if mask.any():
        count = poses.shape[0]
        design = EffectDesign(
            np.zeros(count) if times_s is None else np.asarray(times_s, float),
            np.ones((count, NUM_LEGS)) if directions is None else np.asarray(directions, float),
            identified.payload_mass,
            identified.centre_of_mass,
            identified.reference_time_s,
            leg_mass=identified.leg_mass,
        )
        terms = EffectTerms(geometry, design, mask, count)
        rigid = rigid + terms.regressors(poses) @ values[mask]
    return geometry.sensors.leg_readings(rigid)


def commanded_leg_readings(geometry, poses, previous_readings=None):
    """The leg readings (M, 6) a controller with ``geometry`` drives to for ``poses`` (M, 6)
    visited in order from ``previous_readings`` (6,; None: the first is the start): its IK
    through its sensor model plus the compensation of ``geometry.effects``."""
    poses = np.atleast_2d(poses)
    readings = geometry.sensors.leg_readings(inverse_kinematics(geometry, poses))
    if geometry.effects.none:
        return readings
    directions = approach_directions(readings, previous_readings)
    return compensated_leg_readings(geometry, geometry.effects, poses, directions)


def model_poses(geometry, leg_readings, guesses, design, tolerance=1e-12, iterations=12):
    """Poses (M, 6) where the identification's model with ``geometry.effects`` predicts the leg
    readings (M, 6) of the :class:`EffectDesign` rows ``design``, and ``converged`` (M,): the
    rigid FK of the readings less the effects at the ``guesses``, then Newton steps."""
    target = geometry.sensors.true_leg_lengths(np.atleast_2d(leg_readings))
    values = geometry.effects.values
    if geometry.effects.none:
        return forward_kinematics_masked(geometry, target, guesses)
    terms = EffectTerms(geometry, design, values != 0.0, len(target))
    guesses = np.broadcast_to(np.asarray(guesses, dtype=float), target.shape)
    shifted = target - terms.regressors(guesses) @ values[values != 0.0]
    poses, converged = forward_kinematics_masked(geometry, shifted, guesses)
    for _ in range(iterations):
        rigid, jacobian, _ = inverse_kinematics_jacobians(geometry, poses)
        residual = rigid + terms.regressors(poses) @ values[values != 0.0] - target
        residual[~converged] = 0.0
        if not np.max(np.abs(residual), initial=0.0) > tolerance:
            break
        jacobian[~converged] = np.eye(6)
        poses = poses - np.linalg.solve(jacobian, residual[..., None])[..., 0]
    return poses, converged & (np.max(np.abs(residual), axis=1) < 1e-9)


def design_rows(design, rows):
    """The :class:`EffectDesign` of the postures ``rows`` (a mask or indices) of a run."""
    if design is None:
        return None
    return dataclasses.replace(
        design,
        times_s=None if design.times_s is None else np.asarray(design.times_s)[rows],
        directions=None if design.directions is None else np.asarray(design.directions)[rows],
    )


def effect_estimates(model, point, status, all_deviations):
    """Of an identification's ``model`` at ``point``: ``(free (24,), estimates (24,), standard deviations (24,))`` of the effect parameters;
    ``all_deviations``: of the free parameters, then of the free effects."""
    count = NUM_EFFECT_PARAMETERS
    free, values, deviations = np.zeros(count, bool), np.zeros(count), np.full(count, np.nan)
    if model.effects is not None:
        first = int(model.free.sum())
        free = model.effects.mask.copy()
        deviations[free] = all_deviations[first:]
        if status >= 0:
            values[free] = point.values[first:]
    return free, values, deviations


def geometry_with_effects(geometry, model, effect_values):
    """``geometry`` carrying the identified effects (what its controller compensates)."""
    if model.effects is None:
        return geometry
    design = model.effects.design
    return geometry.replace(effects=IdentifiedEffects.from_result_values(effect_values, design))
