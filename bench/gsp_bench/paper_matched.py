"""A like-for-like comparison with the paper: search a platform that reproduces its initial error.

The paper does not publish its platform. Our drawing (:func:`.nominal_sets.drawing_geometry`)
amplifies Table 1's parameter errors into pose errors far more than the paper's (Table 3's initial
row: 1.344 mm / 0.345 deg with nominal set 1). :func:`search` looks, within a bounded number of
evaluations and from fixed starts (deterministic), for a symmetric 6-6 platform of the same family
(base and platform radii, the half-angles of the joint pairs, the leg offset) with D0 = 850 mm
whose initial error under nominal set 1 (drawn with the same seed and Table 1's statistics from
the candidate, validated over the paper's workspace exactly as ``gsp_paper`` does) matches the
paper's within 10% in position and orientation. The candidate must reach at least
:data:`MIN_REACHABLE` of the paper's workspace box. :func:`run` reports the search, the closest
candidate under sets 1-3, a lower bound that explains a failure, and Table 3 rerun on the
candidate (with the Cramér-Rao prediction beside each Monte-Carlo figure).

The lower bound (expected over random leg directions, so a particular draw may fall below it): a
posture's position error is ``dp = [J^-1 dL]_p`` with ``J``'s position rows the
unit leg directions ``n_i``; whatever the platform, ``E|dp|^2 >= sigma_L^2 tr((sum n n^T)^-1) >=
1.5 sigma_L^2`` (the trace of ``sum n n^T`` is 6), where ``sigma_L^2 = mean(|dA|^2 + |dB|^2)/3 +
mean(dLoff^2)`` is the leg-length error the joint errors cause (random directions). For a
Gaussian error the mean is at least ``sqrt(2/pi)`` of the RMS.
"""

import math
import time

import numpy as np
from scipy.optimize import minimize

from gsp_kinematics.model.kinematics import (
    Workspace,
    inverse_kinematics,
    reachable_mask,
    sample_postures,
)
from gsp_kinematics.model.validation import validate

from .nominal_sets import drawing_geometry, nominal_set

#: Search box: base radius (m), platform radius (m), base and platform half-angles (deg), leg
#: offset (m). Radii of real hexapods carrying a 1 m workspace; pairs that do not overlap.
BOUNDS = np.array([[0.5, 1.5], [0.3, 1.2], [3.0, 40.0], [3.0, 40.0], [0.3, 1.0]])
NAMES = (
    'base_radius_m',
    'platform_radius_m',
    'base_half_angle_deg',
    'platform_half_angle_deg',
    'leg_offset_m',
)
STARTS = (
    (1.0, 0.8, 15.0, 15.0, 0.6),  # the drawing
    (1.2, 0.5, 15.0, 15.0, 0.6),
    (1.0, 0.5, 25.0, 10.0, 0.6),
    (1.4, 0.9, 8.0, 30.0, 0.8),
)
MIN_REACHABLE = 0.3  #: fraction of the paper's workspace box the candidate must reach
TOLERANCE = 0.10  #: relative, in position and in orientation
MAX_EVALUATIONS = 120  #: per start


def candidate_geometry(parameters):
    base_radius, platform_radius, base_half, platform_half, leg_offset = parameters
    return drawing_geometry(
        base_radius=base_radius,
        platform_radius=platform_radius,
        base_half_angle_deg=base_half,
        platform_half_angle_deg=platform_half,
        leg_offset=leg_offset,
    )


def _validation_poses(exact, batch, count=50):
    ok = reachable_mask(exact, batch, Workspace().max_condition)
    return batch[ok][:count], float(ok.mean())


def initial_errors(exact, batch, sets=(1,)):
    """``{set: (position_mm, orientation_deg)}`` of the nominal sets as controllers, and the
    reachable fraction of ``batch``; None values where nothing is reachable."""
    poses, reachable = _validation_poses(exact, batch)
    errors = {}
    for number in sets:
        errors[number] = None
        if len(poses) >= 10:
            try:
                summary = validate(exact, nominal_set(exact, number), poses)
                errors[number] = (summary['position_mm_mean'], summary['orientation_deg_mean'])
            except ValueError:
                pass
    return errors, reachable


def leg_error_bound(exact, number):
    """The lower bound of the mean position error (mm) that Table 1's set ``number`` allows on any
    6-leg platform, and the leg-length error sigma_L (mm) it causes (module docstring)."""
    errors = (nominal_set(exact, number).to_vector() - exact.to_vector())[:42] * 1000.0
    joints = errors[:36].reshape(12, 3)
    sigma_leg = math.sqrt(np.mean(np.sum(joints**2, axis=1)) * 2 / 3 + np.mean(errors[36:42] ** 2))
    return math.sqrt(2 / math.pi) * math.sqrt(1.5) * sigma_leg, sigma_leg


def _objective(errors, reachable, target):
    if errors is None:
        return 50.0 + 10.0 * (1.0 - reachable)
    position, orientation = errors
    shortfall = max(0.0, MIN_REACHABLE - reachable)
    return (
        math.log(position / target[0]) ** 2
        + math.log(orientation / target[1]) ** 2
        + (20.0 * shortfall) ** 2
    )


def search(target, max_evaluations=MAX_EVALUATIONS, seed=0, log=print):
    """Nelder-Mead from :data:`STARTS` in a logistic map of :data:`BOUNDS`; ``{best, evaluations,
    starts, duration_s}`` (deterministic: fixed workspace samples and nominal-set seeds)."""
    started = time.perf_counter()
    batch = sample_postures(np.random.default_rng([seed, 50]), 3000, Workspace())
    low, high = BOUNDS[:, 0], BOUNDS[:, 1]
    best = {'score': math.inf}
    evaluations = 0

    def unpack(z):
        return low + (high - low) / (1.0 + np.exp(-np.clip(z, -30, 30)))

    def score(z):
        nonlocal evaluations, best
        evaluations += 1
        parameters = unpack(z)
        try:
            errors, reachable = initial_errors(candidate_geometry(parameters), batch)
        except (ValueError, RuntimeError):
            return 100.0
        value = _objective(errors[1], reachable, target)
        if value < best['score']:
            best = {
                'score': value,
                'parameters': parameters.tolist(),
                'set_1': errors[1],
                'reachable_fraction': reachable,
            }
        return value

    for start in STARTS:
        start = np.asarray(start, dtype=float)
        z0 = -np.log((high - low) / (start - low) - 1.0)
        minimize(
            score,
            z0,
            method='Nelder-Mead',
            options={'maxfev': max_evaluations, 'xatol': 1e-3, 'fatol': 1e-6},
        )
        log(f'paper_matched: start {start.tolist()}: best so far {best.get("set_1")}')
    return {
        'best': best,
        'evaluations': evaluations,
        'starts': [list(start) for start in STARTS],
        'max_evaluations_per_start': max_evaluations,
        'duration_s': time.perf_counter() - started,
        'batch': batch,
    }


def describe(exact, batch, parameters):
    """The candidate under sets 1-3, its reachable fraction, leg lengths and the bounds."""
    errors, reachable = initial_errors(exact, batch, sets=(1, 2, 3))
    poses, _ = _validation_poses(exact, batch, count=len(batch))
    strokes = inverse_kinematics(exact, poses) if len(poses) else np.zeros((1, 6))
    return {
        'parameters': dict(zip(NAMES, parameters, strict=True)),
        'device_length_m': exact.device_length,
        'reachable_fraction_of_paper_workspace': reachable,
        'stroke_used_m': [float(strokes.min()), float(strokes.max())],
        'leg_offset_m': float(exact.leg_offsets[0]),
        'initial_error': {
            f'set_{number}': None
            if value is None
            else {'position_mm': value[0], 'orientation_deg': value[1]}
            for number, value in errors.items()
        },
        'position_mean_lower_bound_mm': {
            f'set_{number}': leg_error_bound(exact, number)[0] for number in (1, 2, 3)
        },
        'leg_length_error_sigma_mm': {
            f'set_{number}': leg_error_bound(exact, number)[1] for number in (1, 2, 3)
        },
    }


def _within(errors, target):
    return errors is not None and all(
        abs(value / goal - 1.0) <= TOLERANCE for value, goal in zip(errors, target, strict=True)
    )


def run(config, rerun_table3, paper_initial, log=print, max_evaluations=MAX_EVALUATIONS):
    """The ``paper_matched`` section of ``results/paper.json``.

    ``config``: the :class:`.paper.PaperConfig` of the default run; ``rerun_table3(exact)``:
    Table 3 rerun on the candidate geometry ``exact`` (the caller's ``paper.run``, nominal set 1
    only); ``paper_initial``: Table 3's initial row.
    """
    target = (paper_initial['position_mm'], paper_initial['orientation_deg'])
    log(f'paper_matched: searching a platform with initial error {target} (mm, deg) ...')
    found = search(target, max_evaluations, seed=config.seed, log=log)
    batch = found.pop('batch')
    best = found['best']
    drawing = describe(drawing_geometry(), batch, STARTS[0])
    candidate = describe(candidate_geometry(best['parameters']), batch, best['parameters'])
    matched = _within(best.get('set_1'), target)
    bound = candidate['position_mean_lower_bound_mm']['set_1']
    why = (
        None
        if matched
        else (
            f'no candidate within {TOLERANCE:.0%}: the closest gives '
            f"{best['set_1'][0]:.3f} mm / {best['set_1'][1]:.3f} deg against the paper's "
            f"{target[0]:.3f} mm / {target[1]:.3f} deg. Set 1's joint and offset errors change "
            f'each leg length by sigma_L = {candidate["leg_length_error_sigma_mm"]["set_1"]:.2f} '
            f'mm; over random leg directions that puts the mean position error of any 6-leg '
            f'platform at about {bound:.2f} mm or more (module docstring of '
            "gsp_bench.paper_matched): the paper's initial position error is about half "
            "what independent errors with Table 1's statistics give on any platform"
        )
    )
    log(
        f'paper_matched: {"matched" if matched else "no match"}; rerunning Table 3 on the candidate'
    )
    table3 = rerun_table3(candidate_geometry(best['parameters']))
    return {
        'target': {'position_mm': target[0], 'orientation_deg': target[1], 'tolerance': TOLERANCE},
        'matched': matched,
        'why_not': why,
        'search': {
            **found,
            'bounds': dict(zip(NAMES, BOUNDS.tolist(), strict=True)),
            'min_reachable_fraction': MIN_REACHABLE,
        },
        'default_platform': drawing,
        'candidate': candidate,
        'candidate_table3': {
            'initial': table3['initial'],
            'noise': table3['noise'],
            'noise_free': [
                {key: row[key] for key in row if key != 'parameters'}
                for row in table3['noise_free']
            ],
            'duration_s': table3['duration_s'],
        },
    }
