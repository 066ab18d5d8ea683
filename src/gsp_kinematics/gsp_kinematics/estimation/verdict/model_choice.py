"""Choose the model from the data (``auto``): which effect groups to free, by a significance test
of the fit with the known noise, guarded by cross-validated accuracy
(docs/platform_effects.md#choosing-the-model-auto)."""

import dataclasses
import math

import numpy as np
from scipy import special

from ...model.effect_groups import EffectDesign
from ...model.effects import EFFECT_GROUPS, NUM_LEGS
from ..identifiability import analyse_result, identifies_all
from ..identification import IdentificationError, Options, converged_identification
from .choice_accuracy import COMPENSATED_GROUPS, freeing_gain, workspace_postures
from .cross_validation import cross_validate, without_leverage
from .fold_fits import linearised_cost

#: Significance of the likelihood-ratio test of a round (Bonferroni over its groups).
DEFAULT_SIGNIFICANCE = 0.01
#: Largest relative growth of the held-out position error for which a significant group is kept.
DEFAULT_MAX_CV_LOSS = 0.5
DEFAULT_FOLDS = 5
#: Thermal time constants (s; 0: a linear growth) the calibrator chooses among: a leg warms
#: with a time constant of minutes to tens of minutes (docs/platform_effects.md).
DEFAULT_THERMAL_TIME_CONSTANTS = (0.0, 150.0, 300.0, 600.0, 1200.0)


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One model tried: its effect groups, held-out position error (mm,
    :func:`held_out_position_mm`; NaN: ``not_judged`` or ``not_measured`` says why), whether
    kept, ``chi2`` and the test against the model it extends (``delta_chi2``, ``added``,
    ``p_value``)."""

    groups: tuple
    position_mm: float
    chosen: bool = False
    chi2: float = float('nan')
    delta_chi2: float = float('nan')
    added: int = 0
    p_value: float = float('nan')
    #: Predicted rms position errors (mm) over the workspace without and with the groups it
    #: adds (:func:`gsp_kinematics.estimation.verdict.choice_accuracy.freeing_gain`; NaN: not judged).
    predicted_without_mm: float = float('nan')
    predicted_with_mm: float = float('nan')
    #: Why the candidate could not be judged, so is never kept ('' : judged): its fit did not
    #: converge or is not identifiable with the run's postures, its held-out error or its
    #: predicted gain could not be measured (:func:`_judged`).
    not_judged: str = ''
    #: Why its held-out error and predicted gain were not measured although they could be
    #: ('': measured or ``not_judged``): it failed the test, or a candidate of its round with a
    #: larger chi-square drop was kept; either way it cannot be kept (:func:`_first_kept`).
    not_measured: str = ''


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
    #: The tests' chi-squares were divided by this (:func:`variance_factor`; 1: the weights).
    variance_factor: float = 1.0

    def to_dict(self):
        return {
            'groups': list(self.groups),
            'reason': self.reason,
            'thermal_time_constant_s': self.thermal_time_constant_s,
            'thermal_costs': {str(tau): cost for tau, cost in self.thermal_costs.items()},
            'variance_factor': self.variance_factor,
            'candidates': [
                {
                    'groups': list(c.groups),
                    'cv_position_mm': c.position_mm,
                    'chi2': c.chi2,
                    'delta_chi2': c.delta_chi2,
                    'added_parameters': c.added,
                    'p_value': c.p_value,
                    'predicted_without_mm': c.predicted_without_mm,
                    'predicted_with_mm': c.predicted_with_mm,
                    'chosen': c.chosen,
                    'not_judged': c.not_judged,
                    'not_measured': c.not_measured,
                }
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


def _fit(nominal, data, free, options, design, start=None):
    """The converged identification of ``data``'s rows with ``free`` and the effect ``design``,
    or None. ``start``: a fit of the same rows whose poses start this one's (they are most of
    the unknowns: fewer iterations)."""
    leg_lengths, readings, sigmas, guesses, _, _ = data
    guesses = guesses if start is None else start.poses
    return converged_identification(
        nominal,
        leg_lengths,
        readings,
        sigmas,
        free=free,
        pose_guesses=guesses,
        options=options,
        effects=design,
    )


def _chi2(result, rows=None):
    """The fit's sum of squared weighted residuals over ``rows`` (M,) (default: those it used)."""
    residuals = np.asarray(result.residuals, dtype=float)
    used = np.all(np.isfinite(residuals), axis=1) if rows is None else rows
    return float(np.sum(residuals[used] ** 2))


def likelihood_ratio(reference, extended, added, variance_factor=1.0):
    """``(delta chi2, p value)`` of ``extended`` (``added`` more parameters than ``reference``,
    same rows and weights): the chi-square drop over the rows both used, and its probability
    under ``chi2(added)`` after dividing by ``variance_factor``."""
    rows = np.all(np.isfinite(reference.residuals), axis=1)
    rows &= np.all(np.isfinite(extended.residuals), axis=1)
    delta = _chi2(reference, rows) - _chi2(extended, rows)
    return delta, float(special.chdtrc(added, max(delta / variance_factor, 0.0)))


def variance_factor(result):
    """``max(1, chi2 / dof)`` of the fit ``result`` with every group the run allows: it scales
    the tests' chi-squares (an F test)."""
    fit = None if result is None else result.goodness_of_fit
    if fit is None or not fit.dof > 0:
        return 1.0
    return max(1.0, _chi2(result) / fit.dof)


def _unidentifiable(result, count):
    """Why the converged fit ``result`` of ``count`` postures is not identifiable ('' when it is):
    a rank-deficient information matrix, whose covariance means nothing."""
    analysis = analyse_result(result)
    if identifies_all(analysis):
        return ''
    names = analysis['names']
    shown = ', '.join(names[:6]) + (f' and {len(names) - 6} more' if len(names) > 6 else '')
    return (
        f'not identifiable with {count} postures (rank {analysis["rank"]} of '
        f'{analysis["parameters"]}: {shown or "unnamed"})'
    )


def _tested(nominal, data, base, groups, settings, reference=None, fitted=None):
    """``(result, Candidate)`` of the model ``base`` + ``groups`` (``fitted``: its fit, if made),
    tested against ``reference`` = ``(result, its groups)`` when given (``settings``:
    :func:`_forward`'s); its held-out error not yet measured (:func:`_judged`). ``result`` None:
    the fit failed."""
    options, factor = settings[1], settings[4]
    start = None if reference is None else reference[0]
    result = fitted or _fit(nominal, data, list(base) + list(groups), options, data[4], start)
    if result is None:
        return None, Candidate(tuple(groups), math.nan, not_judged='the fit did not converge')
    unidentifiable = _unidentifiable(result, len(data[0]))
    if unidentifiable:
        return result, Candidate(tuple(groups), math.nan, not_judged=unidentifiable)
    test = {}
    if reference is not None:
        added = NUM_LEGS * (len(groups) - len(reference[1]))
        delta, p_value = likelihood_ratio(reference[0], result, added, factor)
        test = {'delta_chi2': delta, 'added': added, 'p_value': p_value}
    return result, Candidate(tuple(groups), math.nan, chi2=_chi2(result), **test)


def _judged(nominal, data, tested, settings, reference=None):
    """``(result, Candidate)`` of :func:`_tested`'s ``tested`` with its held-out error and, for
    a compensated group added to ``reference``, its predicted gain (or why not)."""
    folds, options, _, _, _, workspace, linearised = settings
    leg_lengths, readings, sigmas, _, design, noise = data
    result, candidate = tested
    validation = cross_validate(
        result,
        nominal,
        leg_lengths,
        readings,
        sigmas,
        folds,
        options,
        noise,
        design,
        workspace=None,
        linearised=linearised,
        truth_draws=False,
    )
    position = held_out_position_mm(validation)
    gain, why = {}, []
    if not math.isfinite(position):
        why.append(
            'held-out error not measured: no fit without a fold converged to an identifiable '
            f'fit (failed folds {list(validation.failed_folds)} of {validation.folds})'
        )
    added = set(candidate.groups) - set(() if reference is None else reference[1])
    if reference is not None and workspace is not None and added & set(COMPENSATED_GROUPS):
        predicted = freeing_gain(reference[0], result, workspace)
        gain = {
            'predicted_without_mm': predicted.without_mm,
            'predicted_with_mm': predicted.with_mm,
        }
        if not math.isfinite(predicted.without_mm + predicted.with_mm):
            why.append('predicted gain not computed: a covariance is not positive semi-definite')
    judged = dataclasses.replace(candidate, position_mm=position, not_judged='; '.join(why), **gain)
    return result, judged


def _score(nominal, data, base, groups, settings, reference=None, fitted=None):
    """``(result, Candidate)`` of the model ``base`` + ``groups`` fitted, tested against
    ``reference`` (:func:`_tested`) and, if it could be fitted, judged on held-out postures
    (:func:`_judged`)."""
    tested = _tested(nominal, data, base, groups, settings, reference, fitted)
    if tested[0] is None or tested[1].not_judged:
        return tested
    return _judged(nominal, data, tested, settings, reference)


def _first_kept(nominal, data, trials, reference, best, threshold, settings):
    """``(trials, index of the one kept or None)``: of a round's :func:`_tested` ``trials``
    (against ``reference``), those that pass the test at ``threshold`` judged (:func:`_judged`)
    in order of their chi-square drop until one is kept (:func:`_keeps` over ``best``): the
    round keeps the largest drop kept, so no other needs its held-out error; each trial not
    judged says why (``Candidate.not_measured``)."""
    trials, kept = list(trials), None
    testable = [
        i for i, (result, c) in enumerate(trials) if result is not None and not c.not_judged
    ]
    for i in sorted(testable, key=lambda i: -trials[i][1].delta_chi2):
        result, candidate = trials[i]
        if not candidate.p_value < threshold:
            why = f'not measured: the test failed at level {threshold:.3g}'
        elif kept is not None:
            winner = '+'.join(trials[kept][1].groups)
            why = f'not measured: {winner} lowered the chi-square more and was kept'
        else:
            trials[i] = _judged(nominal, data, trials[i], settings, reference)
            kept = i if _keeps(trials[i][1], best, threshold, settings[3]) else None
            continue
        trials[i] = (result, dataclasses.replace(candidate, not_measured=why))
    return trials, kept


def held_out_position_mm(validation):
    """The mean held-out position error (mm) of ``validation`` (a ``CrossValidation``) as
    measured, each posture's leverage taken out (:func:`.cross_validation.without_leverage`):
    the held-out guard's figure (docs/platform_effects.md)."""
    errors = np.linalg.norm(validation.position_error, axis=1)
    if validation.position_leverage is not None:
        errors = without_leverage(
            errors,
            validation.position_noise,
            validation.position_leverage,
            validation.position_held_out_variance,
        )
    finite = np.isfinite(errors)
    return 1e3 * float(np.mean(errors[finite])) if finite.any() else float('nan')


def thermal_time_constant(nominal, data, base, groups, candidates, options, fits=None):
    """``(tau, {tau: cost})``: of the thermal time constants ``candidates`` (s; 0: linear), the
    one whose fit of ``base`` + ``groups`` has the least cost (the first fitted, the others one
    Gauss-Newton step from it, :func:`.fold_fits.linearised_cost`, the least refitted; a robust
    ``options.loss``: all fitted). ``fits``: a dict that receives ``{tau: fit}`` of the fitted."""
    design, free = data[4], list(base) + list(groups)
    costs, fits, first = {}, {} if fits is None else fits, None
    for tau in map(float, candidates):
        timed = dataclasses.replace(design, thermal_time_constant_s=tau)
        if first is not None and options.loss == 'linear':
            costs[tau] = linearised_cost(first, nominal, *data[:3], timed)
            continue
        result = _fit(nominal, data, free, options, timed, first)
        if result is not None:
            costs[tau], fits[tau], first = float(result.cost), result, first or result
    if not costs:
        return design.thermal_time_constant_s, costs
    tau = min(costs, key=costs.get)
    if tau not in fits:
        timed = dataclasses.replace(design, thermal_time_constant_s=tau)
        result = _fit(nominal, data, free, options, timed, first)
        if result is not None:
            costs[tau], fits[tau] = float(result.cost), result
    return tau, costs


def _keeps(trial, best, threshold, max_cv_loss):
    """Whether ``trial`` passes the test at ``threshold``, the held-out guard over ``best`` and
    is not predicted to make the compensated platform less accurate. Never by a NaN comparison:
    a ``not_judged`` candidate is not kept, nor any when ``best``'s held-out error is unknown."""
    if trial.not_judged or best.not_judged or not math.isfinite(best.position_mm):
        return False
    worse = trial.predicted_with_mm > trial.predicted_without_mm  # NaN (not judged): False
    return bool(
        trial.p_value < threshold
        and trial.position_mm <= (1.0 + max_cv_loss) * best.position_mm
        and not worse
    )


def _forward(nominal, data, base, available, settings, every=None):
    """Forward selection (module docstring): ``(result, best Candidate, chosen, tried)``.
    ``every``: the fit with every available group, which a candidate with all of them reuses."""
    significance = settings[2]

    def tested(groups, reference):
        fitted = every if set(groups) == set(available) else None
        return _tested(nominal, data, base, groups, settings, reference, fitted)

    result, best = _score(nominal, data, base, (), settings)
    if result is None:
        raise IdentificationError('the plain model did not converge: no model to choose from')
    if best.not_judged:  # e.g. too few postures: no group can be judged beside it
        return result, best, (), [best]
    tried, chosen, remaining = [best], (), list(available)
    path = [(result, best, chosen)]
    while remaining:
        reference = (result, chosen)
        trials = [tested(chosen + (group,), reference) for group in remaining]
        threshold = significance / len(trials)
        trials, kept = _first_kept(nominal, data, trials, reference, best, threshold, settings)
        tried += [candidate for _, candidate in trials]
        if kept is None:
            break
        result, best = trials[kept]
        chosen = best.groups
        path.append((result, best, chosen))
        remaining = [group for group in remaining if group not in chosen]
    if len(remaining) > 1:
        # Effects that mask each other: no one group alone is kept, together they may be.
        reference = (result, chosen)
        trial = tested(chosen + tuple(remaining), reference)
        trials, kept = _first_kept(nominal, data, [trial], reference, best, significance, settings)
        tried.append(trials[0][1])
        if kept is not None:
            path.append((trials[0][0], trials[0][1], trials[0][1].groups))
    result, best, chosen = never_worse_held_out(path)
    return result, best, chosen, tried


def never_worse_held_out(path):
    """Of the models kept in turn, ``path`` = ``[(result, Candidate, groups)]`` from the plain
    model on, the last whose held-out position error is not above the plain model's."""
    plain = path[0][1].position_mm
    for step in reversed(path):
        if step[1].position_mm <= plain:
            return step
    return path[0]


def _reason(chosen, best, tried, significance, max_cv_loss, predicted_gain):
    """Why ``chosen`` (the groups of the ``best`` candidate) were kept, under the rule's
    settings, and why each of the ``tried`` candidates that could not be judged was not; when
    the plain model cannot be judged (too few postures), that no group was tried and why."""
    if best.not_judged:
        return f'groups none: no effect group tried, the plain model cannot be judged: {best.not_judged}'
    names = ', '.join(chosen) if chosen else 'none'
    unjudged = {}
    for candidate in tried:
        if candidate.not_judged:
            unjudged.setdefault(candidate.not_judged, []).append('+'.join(candidate.groups))
    return (
        f'groups {names}: held-out position error {best.position_mm:.4f} mm; each kept group '
        f'lowered the chi-square significantly (likelihood ratio, p < {significance:g} over the '
        f'groups of its round) without raising the held-out error by more than '
        f'{100 * max_cv_loss:.0f} %'
        + (
            ' or the predicted position error over the workspace (the bias of leaving it out '
            'against the spread of its estimates)'
            if predicted_gain
            else ''
        )
        + '; no other group did'
        + (
            f"; and its held-out error is not above the plain model's "
            f'({tried[0].position_mm:.4f} mm)'
            if chosen
            else ''
        )
        + ''.join(
            f'; not judged, so not kept: {", ".join(groups)} ({why})'
            for why, groups in unjudged.items()
        )
    )


def choose_model(
    nominal,
    leg_lengths,
    readings,
    sigmas,
    design=None,
    base=('extended',),
    pose_guesses=None,
    folds=DEFAULT_FOLDS,
    significance=DEFAULT_SIGNIFICANCE,
    max_cv_loss=DEFAULT_MAX_CV_LOSS,
    options=Options(),
    noise=None,
    thermal_time_constants=(),
    predicted_gain=True,
    linearised=True,
):
    """:class:`ModelChoice` for the rows ``leg_lengths`` (M, 6), ``readings`` (M, 4) with the
    row weights ``sigmas`` (their real noise) and the run's :class:`EffectDesign` ``design``
    (None: only the joint offsets can be tried); ``significance``, ``max_cv_loss``: the rule
    (docs/platform_effects.md). ``thermal_time_constants`` (s; 0: linear; empty: the design's):
    chosen first by :func:`thermal_time_constant`. ``predicted_gain``: a compensated group must
    not be predicted to lose accuracy (:mod:`.choice_accuracy`). ``linearised``: held-out errors
    from :func:`.fold_fits.linearised_refits` (False: refits)."""
    design = design or EffectDesign()
    tau, costs = design.thermal_time_constant_s, {}
    available = available_groups(design, len(leg_lengths))
    fits = {}  # the fits with every available group, by thermal time constant
    if 'thermal' in available and len(thermal_time_constants):
        data = (leg_lengths, readings, sigmas, pose_guesses, design, noise)
        tau, costs = thermal_time_constant(
            nominal, data, base, available, thermal_time_constants, options, fits
        )
        design = dataclasses.replace(design, thermal_time_constant_s=tau)
    data = (leg_lengths, readings, sigmas, pose_guesses, design, noise)
    every = fits.get(tau)
    if available and every is None:
        every = _fit(nominal, data, list(base) + available, options, design)
    factor = variance_factor(every) if available else 1.0
    workspace = workspace_postures(nominal) if predicted_gain else None
    settings = (folds, options, significance, max_cv_loss, factor, workspace, linearised)
    result, best, chosen, tried = _forward(nominal, data, base, available, settings, every)
    tried = [dataclasses.replace(c, chosen=c.groups == chosen) for c in tried]
    reason = _reason(chosen, best, tried, significance, max_cv_loss, predicted_gain)
    if 'thermal' in chosen and costs:
        shape = f'a first-order warming, {tau:g} s' if tau > 0 else 'a linear growth'
        reason += f'; thermal as {shape} (least fit cost of {sorted(costs)} s, 0: linear)'
    if factor > 1.0:
        reason += f'; chi-squares over {factor:.2f}, the chi2/dof that every group together leaves'
    return ModelChoice(chosen, result, tuple(tried), reason, tau, costs, factor)
