"""The one-minute check of a calibrated platform (pure numpy/scipy; docs/upkeep.md)."""

import dataclasses
import math

import numpy as np
from scipy import stats

from ..estimation.identifiability import posture_factors
from ..estimation.identification import converged_identification, resolve_free
from ..estimation.verdict import cross_validation
from ..model.geometry import ALL_PARAMETER_NAMES, PARAMETER_INDEX
from ..model.motion import (
    DEFAULT_PAIRS_PER_POSTURE,
    DEFAULT_SENSOR_RATE_HZ,
    MotionLimits,
    move_time,
    posture_leg_lengths,
)
from . import drift

#: The parameters the check identifies: the leg offsets (what a leg's re-homing, a replaced
#: encoder or a knock changes; a joint's change shows mostly in its leg's offset too).
CHECK_PARAMETERS = tuple(f'Loff{leg}' for leg in range(1, 7))
#: Platform time a check may take (s) at the realistic leg speeds of gsp_kinematics.planning.
CHECK_BUDGET_S = 60.0
#: Postures of a check at most (fewer when their route and dwell exceed the budget).
CHECK_POSTURES = 10
#: Time at each posture besides the samples (s): the rest rule's wait.
SETTLE_ALLOWANCE_S = 0.5
#: Leg distance (m) within which the platform already holds a posture: its readings would not
#: change, and the collection would skip it (the calibrator's ``run.postures.HELD_TOLERANCE``).
HELD_TOLERANCE_M = 1e-4
VERDICTS = ('within tolerance', 'recalibrate')


@dataclasses.dataclass(frozen=True)
class CheckPlan:
    """The postures of a check in route order and the platform time they take."""

    poses: np.ndarray  #: (N, 6) in visiting order
    travel_s: float  #: the route from the start pose
    dwell_s: float  #: settle allowance and samples, all postures
    pool_indices: np.ndarray  #: the postures' indices in the pool, visiting order

    @property
    def platform_time_s(self):
        return self.travel_s + self.dwell_s


def choose_check_postures(
    controller,
    pool,
    start_pose,
    sigmas,
    pairs_per_posture=DEFAULT_PAIRS_PER_POSTURE,
    rate_hz=DEFAULT_SENSOR_RATE_HZ,
    limits=MotionLimits(),
    count=CHECK_POSTURES,
    budget_s=CHECK_BUDGET_S,
    free=CHECK_PARAMETERS,
):
    """The postures of a check from ``pool`` (N, 6), greedily by information on ``free`` per
    second of platform time from ``start_pose``, until ``count`` postures or the ``budget_s``
    (:class:`CheckPlan`; docs/upkeep.md)."""
    pool = np.atleast_2d(np.asarray(pool, dtype=float))
    per_posture = SETTLE_ALLOWANCE_S + pairs_per_posture / rate_hz
    factors = posture_factors(controller, pool, sigmas, list(free))
    candidate_information = np.einsum('mri,mrj->mij', factors, factors)
    scale = 1.0 / np.sqrt(np.maximum(np.einsum('mii->i', candidate_information), 1e-300))
    candidate_information *= np.outer(scale, scale)[None] * len(pool)
    legs = posture_leg_lengths(controller, np.vstack([np.asarray(start_pose, float), pool]))
    information = 1e-6 * np.eye(len(free))
    current, chosen, travel = 0, [], 0.0
    available = np.max(np.abs(legs[1:] - legs[0]), axis=1) > HELD_TOLERANCE_M
    while len(chosen) < count:
        moves = np.asarray(move_time(legs[current], legs[1:], limits), dtype=float)
        fits = available & (travel + moves + per_posture * (len(chosen) + 1) <= budget_s)
        if not fits.any():
            break
        _, base = np.linalg.slogdet(information)
        _, logdet = np.linalg.slogdet(information[None] + candidate_information)
        score = np.where(fits, (logdet - base) / (moves + per_posture), -np.inf)
        best = int(np.argmax(score))
        chosen.append(best)
        travel += float(moves[best])
        information = information + candidate_information[best]
        available[best] = False
        current = best + 1
    if len(chosen) < 2:
        raise ValueError(f'no check fits in {budget_s} s from the start pose')
    order = np.array(chosen)
    return CheckPlan(pool[order], travel, len(chosen) * per_posture, order)


def calibration_share(controller, poses, sigmas, calibration, free=CHECK_PARAMETERS):
    """``K C K^T``: the covariance the calibration's own uncertainty (``calibration``, a
    ``drift.Calibration``) gives the check's estimate of ``free`` at ``poses``, ``K = -(G_f^T
    G_f)^-1 G_f^T G_c`` over the postures' information factors (docs/upkeep.md)."""
    mask = resolve_free(list(dict.fromkeys(list(calibration.names) + list(free))))
    names = [name for name, is_free in zip(ALL_PARAMETER_NAMES, mask, strict=True) if is_free]
    factors = posture_factors(controller, poses, sigmas, mask).reshape(-1, len(names))
    check_columns = factors[:, [names.index(name) for name in free]]
    calibration_columns = factors[:, [names.index(name) for name in calibration.names]]
    gain = -np.linalg.lstsq(check_columns, calibration_columns, rcond=None)[0]
    return gain @ calibration.covariance @ gain.T


def accuracy_now(controller, leg_lengths, readings, guesses, row_sigmas):
    """The controller's accuracy at the checked postures: ``{position_mm, phi_deg}`` each as
    ``cross_validation``'s statistics (noise removed) with ``sigma_of_mean``, and the
    per-posture errors (mm, deg)."""
    position, phi, converged = cross_validation.prediction_errors(
        controller, leg_lengths, readings, guesses
    )
    position_noise, phi_noise = cross_validation.noise_variances(
        controller, guesses, readings, row_sigmas
    )
    magnitudes = np.linalg.norm(position, axis=1)
    summary = {'postures': int(converged.sum())}
    for key, values, variances, scale in (
        ('position_mm', magnitudes, position_noise, 1e3),
        ('phi_deg', np.abs(phi), phi_noise, math.degrees(1.0)),
    ):
        entry = cross_validation._statistics(values, variances, scale)  # the verdict's statistics
        finite = values[np.isfinite(values)]
        spread = np.std(finite, ddof=1) if finite.size > 1 else math.nan
        entry['sigma_of_mean'] = float(scale * spread / math.sqrt(max(finite.size, 1)))
        entry['per_posture'] = (scale * values).tolist()
        summary[key] = entry
    return summary


def check_platform(
    controller,
    leg_lengths,
    readings,
    commanded,
    row_sigmas,
    required,
    calibration=None,
    level=drift.DEFAULT_LEVEL,
    free=CHECK_PARAMETERS,
):
    """The check of ``controller`` from the measured rows ``leg_lengths`` (M, 6) and
    ``readings`` (M, 4) at the ``commanded`` poses (M, 6), with the rows' noise ``row_sigmas`` (a
    ``SensorNoise``) and the ``Requirement`` ``required``; ``calibration``: the
    ``drift.Calibration`` the controller came from (None: exact). A JSON-ready dict: ``verdict``,
    ``reasons``, ``notes``, ``accuracy``, ``change``, ``moved``, ``identification`` and
    ``geometry_si`` (docs/data.md)."""
    commanded = np.atleast_2d(np.asarray(commanded, dtype=float))
    accuracy = accuracy_now(controller, leg_lengths, readings, commanded, row_sigmas)
    reasons = []
    position, phi = accuracy['position_mm']['mean'], accuracy['phi_deg']['mean']
    if not position <= required.position_mm:
        reasons.append(f'position error {position:.4f} mm > required {required.position_mm} mm')
    if not phi <= required.orientation_deg:
        reasons.append(f'phi error {phi:.5f} deg > required {required.orientation_deg} deg')
    data = {
        'kind': 'check',
        'required': {
            'position_mm': required.position_mm,
            'orientation_deg': required.orientation_deg,
        },
        'accuracy': _accuracy_record(accuracy),
        'accuracy_detail': accuracy,
        'level': level,
        'geometry_si': dict(
            zip(ALL_PARAMETER_NAMES, controller.to_full_vector().tolist(), strict=True)
        ),
    }
    fitted = converged_identification(
        controller, leg_lengths, readings, row_sigmas, free=list(free), pose_guesses=commanded
    )
    moved, notes = [], []
    if fitted is None:
        reasons.append('the leg offsets could not be identified from the check (did not converge)')
    else:
        moved, why, notes = _judge_change(
            data, controller, fitted, (commanded, row_sigmas, calibration), required, level, free
        )
        reasons += why
        if reasons and not moved and not data['common_change']['alike']:
            comparison = data['change']  # name the largest w all the same
            name, entry = max(comparison['parameters'].items(), key=lambda item: abs(item[1]['w']))
            moved = [{'parameter': name, 'likely': True} | _change_entry(entry)]
    data['verdict'] = VERDICTS[1] if reasons else VERDICTS[0]
    data['reasons'] = reasons
    data['notes'] = notes
    data['moved'] = moved
    data['moved_legs'] = sorted({_leg(entry['parameter']) for entry in moved} - {None})
    return data


def _judge_change(data, controller, fitted, rows, required, level, free):
    """The change of the leg offsets since the calibration (``fitted``: the check's small
    identification; ``rows``: the commanded poses, the rows' noise and the calibration): fills
    ``data`` (``change``, ``common_change``, ``identification``) and returns ``(the legs named,
    the reasons to recalibrate, notes)``; a common change is a reason only when its effect could
    exceed the requirement (:func:`common_effect`)."""
    commanded, row_sigmas, calibration = rows
    index = [PARAMETER_INDEX[name] for name in free]
    before = controller.to_full_vector()[index]
    share = np.zeros((len(free), len(free)))
    if calibration is not None:
        share = calibration_share(controller, commanded, row_sigmas, calibration, free)
    after = drift.Calibration(free, fitted.parameters[index], fitted.covariance)
    reference = drift.Calibration(free, before, share, controller, 'controller')
    comparison = drift.compare(reference, after, level)
    change, covariance = after.estimates - before, fitted.covariance + share
    data['common_change'] = common = common_change(change, covariance, level)
    moved, reasons, notes = comparison['significant'], [], []
    if (changed := comparison['global_test']['changed']) and common['significant']:
        moved = _moved_beyond_common(change, covariance, free, level)
    if changed and common['alike']:
        moved = []  # heat grows every leg alike: no leg moved, naming one would mislead
        common['effect'] = effect = common_effect(controller, free, common, level)
        within = (
            effect['position_mm_bound'] <= required.position_mm
            and effect['orientation_deg_bound'] <= required.orientation_deg
        )
        (notes if within else reasons).append(_alike_reason(common, within))
    elif changed:
        names = ', '.join(entry['parameter'] for entry in moved) or 'no single leg offset'
        reasons.append(f'the platform has changed since its calibration ({names})')
    data['change'] = comparison
    data['identification'] = {
        'parameters': list(free),
        'estimates_si': fitted.parameters[index].tolist(),
        'covariance_si': covariance.tolist(),
    }
    return moved, reasons, notes


def common_effect(controller, names, common, level=drift.DEFAULT_LEVEL):
    """What a common change of the leg offsets ``names`` (``common``: :func:`common_change`)
    does to the pose over the workspace (``drift.effect_poses`` of ``controller``): the mean
    position (mm) and orientation (deg) change of the estimate and of its upper bound
    ``|delta| + z sigma`` (two-sided ``level``)."""
    unit = drift.pose_effect(
        controller, names, 1e-6 * np.ones(len(names)), None, drift.effect_poses(controller)
    )  # per um; the effect is linear in the change
    z = float(stats.norm.ppf(1.0 - level / 2.0))
    size, bound = abs(common['change_um']), abs(common['change_um']) + z * common['sigma_um']
    position, orientation = unit['position_mm']['mean'], unit['orientation_deg']['mean']
    return {
        'position_mm_mean': size * position,
        'position_mm_bound': bound * position,
        'orientation_deg_mean': size * orientation,
        'orientation_deg_bound': bound * orientation,
    }


def _moved_beyond_common(change, covariance, names, level):
    """The leg offsets that moved beyond a common change of all six (a thermal state unlike the
    calibration's): the iterated w-tests (``drift.localise``) with the common change as a
    nuisance parameter (its direction taken out of the weight)."""
    inverse = np.linalg.pinv(np.asarray(covariance, dtype=float))
    column = inverse @ np.ones(len(change))
    weight = inverse - np.outer(column, column) / float(column.sum())
    named, _ = drift.localise(np.asarray(change), weight, level, dof=len(change) - 1)
    return [
        {'parameter': names[i], 'change_report': 1e3 * value, 'sigma_report': 1e3 * sigma}
        | {'unit': 'mm', 'w': w}
        for i, value, sigma, w in named
    ]


def _alike_reason(common, within):
    effect = common['effect']
    head = (
        'warm up / common growth: all six leg offsets changed alike, by '
        f'{common["change_um"]:+.1f} +- {common["sigma_um"]:.1f} um, since the calibration '
        "(a thermal state unlike the calibration's, or a common re-homing); it moves the "
        f'platform by {effect["position_mm_mean"]:.4f} mm on average '
        f'(at most {effect["position_mm_bound"]:.4f} mm)'
    )
    if within:
        return f'{head}, within the required accuracy'
    return (
        f'{head}, beyond the required accuracy: check again after the same warm-up as the '
        'calibration, or recalibrate in the state the platform is used in'
    )


def common_change(change, covariance, level=drift.DEFAULT_LEVEL):
    """Whether the six leg offsets' ``change`` (m, covariance (6, 6) m^2) is one common change
    (what thermal growth does): the common part ``delta`` (weighted least squares) with its
    sigma, and the chi-square of what is left against its ``1 - level`` quantile (5 degrees of
    freedom). ``alike``: the common part is significant and the rest is not."""
    inverse = np.linalg.pinv(np.asarray(covariance, dtype=float))
    ones = np.ones(len(change))
    weight = float(ones @ inverse @ ones)
    delta = float(ones @ inverse @ change) / weight
    rest = change - delta * ones
    chi2 = float(rest @ inverse @ rest)
    sigma = 1.0 / math.sqrt(weight)
    bound = float(stats.chi2.ppf(1.0 - level, len(change) - 1))
    z = float(stats.norm.ppf(1.0 - level / 2.0))
    return {
        'change_um': 1e6 * delta,
        'sigma_um': 1e6 * sigma,
        'rest_chi2': chi2,
        'rest_chi2_bound': bound,
        'significant': bool(abs(delta) > z * sigma),
        'alike': bool(abs(delta) > z * sigma and chi2 <= bound),
    }


def _change_entry(entry):
    return {
        'change_report': entry['change_report'],
        'sigma_report': entry['conditional_sigma_report'],
        'unit': entry['unit'],
        'w': entry['w'],
    }


def _leg(name):
    """The leg (1..6) a parameter belongs to (``Loff3``, ``A3x``, ``kq3``), else None."""
    digits = [character for character in name if character.isdigit()]
    return int(digits[0]) if digits and name[0] in 'ABLk' else None


def _accuracy_record(accuracy):
    position, phi = accuracy['position_mm'], accuracy['phi_deg']
    return {
        'postures': accuracy['postures'],
        'position_mm_mean': position['mean'],
        'position_mm_sigma': position['sigma_of_mean'],
        'position_mm_p95': position['p95'],
        'orientation_deg_mean': phi['mean'],
        'orientation_deg_sigma': phi['sigma_of_mean'],
        'orientation_deg_p95': phi['p95'],
        'statistic': 'phi only (the device measures one rotation); noise removed in quadrature',
    }
