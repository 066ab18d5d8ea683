"""Choose the model from the data (``auto``): which effect groups to free, by cross-validated
accuracy (docs/platform_effects.md#choosing-the-model).

Forward selection from the plain model (``base``, e.g. ``extended``): each round fits the
current set plus each remaining effect group whose run design allows it, cross-validates each
(:func:`gsp_kinematics.verdict.cross_validation.cross_validate`), and keeps the best group only if it
lowers the held-out position error by more than ``min_gain`` (relative): the guard against
over-fitting, so that on a platform the plain model describes, the plain model stays. When
no group alone gains enough, all the remaining groups together are tried once (effects that
mask each other). The
score is the measured mean held-out position error: every candidate predicts the same postures
with the same noise, so the noise does not bias the comparison.
"""

import dataclasses

import numpy as np

from ..effects.groups import EFFECT_GROUPS, EffectDesign
from ..identification import IdentificationError, Options, identify
from .cross_validation import cross_validate

#: Smallest relative drop of the held-out position error for which a group is kept.
DEFAULT_MIN_GAIN = 0.15
DEFAULT_FOLDS = 5


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One model tried: its effect groups, held-out position error (mm, measured mean; NaN if
    the fit failed), its cross-validation summary and whether it was kept."""

    groups: tuple
    position_mm: float
    summary: dict | None
    chosen: bool = False


@dataclasses.dataclass(frozen=True)
class ModelChoice:
    """The chosen groups, the identification with them, every candidate and why."""

    groups: tuple
    result: object
    candidates: tuple
    reason: str
    #: The thermal time constant (s) used (0: linear growth) and each one tried: {tau: cost}.
    thermal_time_constant_s: float = 0.0
    thermal_costs: dict = dataclasses.field(default_factory=dict)

    def to_dict(self):
        return {
            'groups': list(self.groups),
            'reason': self.reason,
            'thermal_time_constant_s': self.thermal_time_constant_s,
            'thermal_costs': {str(tau): cost for tau, cost in self.thermal_costs.items()},
            'candidates': [
                {'groups': list(c.groups), 'cv_position_mm': c.position_mm, 'chosen': c.chosen}
                for c in self.candidates
            ],
        }


def available_groups(design, count):
    """The effect groups the run's ``design`` (M = ``count`` postures) can identify: a mass for
    the compliance, times for the thermal growth, both approach directions for the backlash."""
    if design is None:
        return ['joint_offsets']
    groups = []
    for group in EFFECT_GROUPS:
        try:
            design.check([group], count)
        except ValueError:
            continue
        if group == 'backlash':
            directions = np.asarray(design.directions)
            if not np.all((directions > 0).any(axis=0) & (directions < 0).any(axis=0)):
                continue  # some leg arrives from one direction only
        groups.append(group)
    return groups


def _fit(nominal, data, free, options, design):
    """The converged identification of ``data``'s rows with ``free`` and the effect ``design``,
    or None (no convergence, or an identification error)."""
    leg_lengths, readings, sigmas, guesses, _, _ = data
    try:
        result = identify(
            nominal,
            leg_lengths,
            readings,
            sigmas,
            free=free,
            pose_guesses=guesses,
            options=options,
            effects=design,
        )
    except IdentificationError:
        return None
    return result if result.converged else None


def _score(nominal, data, base, groups, folds, options):
    """``(result, Candidate)`` of the model ``base`` + ``groups``."""
    leg_lengths, readings, sigmas, _, design, noise = data
    result = _fit(nominal, data, list(base) + list(groups), options, design)
    if result is None:
        return None, Candidate(tuple(groups), float('nan'), None)
    validation = cross_validate(
        result, nominal, leg_lengths, readings, sigmas, folds, options, noise, design
    )
    summary = validation.summary()
    position = summary['calibrated']['position_mm']['measured_mean']
    return result, Candidate(tuple(groups), float(position), summary)


def thermal_time_constant(nominal, data, base, groups, candidates, options):
    """``(tau, {tau: cost})``: of the thermal time constants ``candidates`` (s; 0: linear), the
    one whose fit of ``base`` + ``groups`` (thermal among them) has the least cost. The
    candidates share the parameters and the data, so their costs compare directly."""
    design = data[4]
    costs = {}
    for tau in candidates:
        timed = dataclasses.replace(design, thermal_time_constant_s=float(tau))
        result = _fit(nominal, data, list(base) + list(groups), options, timed)
        if result is not None:
            costs[float(tau)] = float(result.cost)
    if not costs:
        return design.thermal_time_constant_s, costs
    return min(costs, key=costs.get), costs


def choose_model(
    nominal,
    leg_lengths,
    readings,
    sigmas,
    design=None,
    base=('extended',),
    pose_guesses=None,
    folds=DEFAULT_FOLDS,
    min_gain=DEFAULT_MIN_GAIN,
    options=Options(),
    noise=None,
    thermal_time_constants=(),
):
    """:class:`ModelChoice` for the rows ``leg_lengths`` (M, 6), ``readings`` (M, 4) with the
    row weights ``sigmas`` and the run's :class:`EffectDesign` ``design`` (None: no times,
    directions or mass: only the joint offsets can be tried). ``thermal_time_constants`` (s;
    0: linear): when the thermal group can be tried, its time constant is first chosen among
    these by the cost of the fit with every available group (:func:`thermal_time_constant`);
    empty: the design's."""
    design = design or EffectDesign()
    tau, costs = design.thermal_time_constant_s, {}
    available = available_groups(design, len(leg_lengths))
    if 'thermal' in available and len(thermal_time_constants):
        data = (leg_lengths, readings, sigmas, pose_guesses, design, noise)
        tau, costs = thermal_time_constant(
            nominal, data, base, available, thermal_time_constants, options
        )
        design = dataclasses.replace(design, thermal_time_constant_s=tau)
    data = (leg_lengths, readings, sigmas, pose_guesses, design, noise)
    result, best = _score(nominal, data, base, (), folds, options)
    if result is None:
        raise IdentificationError('the plain model did not converge: no model to choose from')
    tried, chosen = [best], ()
    remaining = list(available)
    while remaining:
        trials = [
            (group, *_score(nominal, data, base, chosen + (group,), folds, options))
            for group in remaining
        ]
        tried += [candidate for _, _, candidate in trials]
        group, trial_result, trial = min(
            trials,
            key=lambda item: np.inf if np.isnan(item[2].position_mm) else item[2].position_mm,
        )
        if not trial.position_mm < (1.0 - min_gain) * best.position_mm:
            break
        result, best, chosen = trial_result, trial, chosen + (group,)
        remaining.remove(group)
    if len(remaining) > 1:
        # Effects that mask each other: no one group alone gains enough, together they may.
        together_result, together = _score(
            nominal, data, base, chosen + tuple(remaining), folds, options
        )
        tried.append(together)
        if together.position_mm < (1.0 - min_gain) * best.position_mm:
            result, best, chosen = together_result, together, together.groups
    tried = [dataclasses.replace(c, chosen=c.groups == chosen) for c in tried]
    names = ', '.join(chosen) if chosen else 'none'
    reason = (
        f'groups {names}: held-out position error {best.position_mm:.4f} mm; each kept group '
        f'lowered it by more than {100 * min_gain:.0f} %, no other group did'
    )
    if 'thermal' in chosen and costs:
        shape = f'a first-order warming, {tau:g} s' if tau > 0 else 'a linear growth'
        reason += f'; thermal as {shape} (least fit cost of {sorted(costs)} s, 0: linear)'
    return ModelChoice(chosen, result, tuple(tried), reason, tau, costs)
