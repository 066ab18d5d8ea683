"""The ``sensor_errors`` section of ``make bench`` (docs/sensor_errors.md): sensor-error model,
goodness of fit, noise estimates and robust fitting, on simulated calibrator runs.

A run is what the calibrator collects: the shipped real platform (with its sensor errors) driven
by the nominal controller to 60 selected postures, ``samples`` noisy pairs per posture averaged
(their scatter kept for the noise estimates), then identified. Validation drives 50 other postures
with the calibrated controller and compares the reached poses with the commands (mean position
error, mm). Every figure below compares runs of the same postures and noise. The model figure
comes with its Cramer-Rao prediction (``gsp_kinematics.estimation.prediction``) and the spread over seeds.
"""

import math
import statistics

import numpy as np

from gsp_kinematics.estimation import goodness
from gsp_kinematics.estimation.identifiability import posture_factors, posture_information
from gsp_kinematics.estimation.identification import (
    DEFAULT_FORMULATION,
    Options,
    identify,
    resolve_free,
)
from gsp_kinematics.estimation.prediction import pose_sensitivities, predicted_errors
from gsp_kinematics.model.kinematics import (
    Workspace,
    forward_kinematics_masked,
    sample_valid_postures,
)
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.model.validation import commanded_articular, sensor_measurements, validate
from gsp_kinematics.planning.selection import select_postures

from .nominal_sets import default_true_and_nominal

SIGMAS = DEFAULT_SENSOR_NOISE  # per-sample noise: 1 um, 0.001 deg (Table 3's first level)
POSTURES = 60
SAMPLES = 10
#: Seeds of the model figure: one seed's validation error scatters widely, so a ratio of medians
#: over a few seeds is noise (docs/sensor_errors.md gives its bootstrap interval).
MODEL_SEEDS = 200
#: Corruptions of the outlier figure: (posture, reading column, offset); columns 0-5 are legs.
CORRUPTIONS = ((5, 2, 0.5e-3), (23, 6 + 0, math.radians(0.05)), (41, 4, -0.5e-3))


def reachable(true, controller, poses):
    """Mask (M,) of the ``poses`` the real platform reaches when ``controller`` drives them."""
    _, ok = forward_kinematics_masked(true, commanded_articular(true, controller, poses), poses)
    return ok


def collect(
    true, controller, poses, seed, samples=SAMPLES, sigmas=SIGMAS, keep=None, correlation=None
):
    """Averaged rows and the windows of a simulated run: ``(legs (M, 6), readings (M, 4),
    windows (M, samples, 10), reached)``; postures the real platform cannot reach, or not in the
    mask ``keep``, are left out. Posture m's noise depends on the seed and m only, so runs of two
    truths on the same postures and seed see the same noise. ``correlation`` (10,): the lag-1
    correlation of each channel's samples (stationary AR(1); None: white)."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, 1.0, (len(poses), samples, 10))
    if correlation is not None:
        rho = np.asarray(correlation, dtype=float)
        for i in range(1, samples):  # AR(1) along the window, unit stationary variance
            noise[:, i] = rho * noise[:, i - 1] + np.sqrt(1.0 - rho**2) * noise[:, i]
    reached, ok = forward_kinematics_masked(
        true, commanded_articular(true, controller, poses), poses
    )
    if keep is not None:
        ok = ok & keep
    legs, readings = sensor_measurements(true, reached[ok])
    exact = np.concatenate([legs, readings], axis=1)
    scale = np.concatenate([np.full(6, sigmas.leg_lengths), sigmas.readings()])
    drawn = exact[:, None, :] + noise[ok] * scale
    mean = drawn.mean(axis=1)
    return mean[:, :6], mean[:, 6:], drawn, poses[ok]


def fit(nominal, legs, readings, commanded, free, loss='linear'):
    return identify(
        nominal,
        legs,
        readings,
        SIGMAS.averaged([SAMPLES]),
        free=free,
        pose_guesses=commanded,
        options=Options(loss=loss),
    )


def position_error_mm(true, result, validation_poses):
    return validate(true, result.geometry, validation_poses)['position_mm_mean']


def design_position_error_mm(geometry, poses, free, validation_poses):
    """Cramer-Rao prediction of the validation's mean position error (mm) of fitting ``free`` on
    ``poses``: the covariance is the inverse information of the design (selection's factors)."""
    mask = resolve_free(free)
    information = posture_information(geometry, poses, SIGMAS.averaged([SAMPLES]), mask).sum(axis=0)
    position, _ = predicted_errors(geometry, np.linalg.inv(information), validation_poses, mask)
    return float(position.mean())


def spread(values):
    """Median and the 5th, 25th, 75th and 95th percentiles of ``values``."""
    p5, p25, median, p75, p95 = np.percentile(values, [5, 25, 50, 75, 95])
    return {'median': median, 'p5': p5, 'p25': p25, 'p75': p75, 'p95': p95}


def _model_runs(true, ideal_true, nominal, poses, both, seeds, validation_poses):
    """Per seed: the fits' validation errors (mm), their predicted means and their p-values."""
    runs = {key: [] for key in ('extended', 'ideal', 'paper', 'extended_ideal_sensors')}
    predicted = {'extended': [], 'ideal': []}
    paper_p, extended_p = [], []
    for seed in range(seeds):
        legs, readings, _, commanded = collect(true, nominal, poses, seed, keep=both)
        extended = fit(nominal, legs, readings, commanded, 'extended')
        paper = fit(nominal, legs, readings, commanded, 'paper')
        # Same noise draws (same seed), ideal sensors: the 44 and, for the bias, the extended.
        legs_i, readings_i, _, commanded_i = collect(ideal_true, nominal, poses, seed, keep=both)
        ideal = fit(nominal, legs_i, readings_i, commanded_i, 'paper')
        extended_ideal = fit(nominal, legs_i, readings_i, commanded_i, 'extended')
        runs['extended'].append(position_error_mm(true, extended, validation_poses))
        runs['paper'].append(position_error_mm(true, paper, validation_poses))
        runs['ideal'].append(position_error_mm(ideal_true, ideal, validation_poses))
        runs['extended_ideal_sensors'].append(
            position_error_mm(ideal_true, extended_ideal, validation_poses)
        )
        for key, result in (('extended', extended), ('ideal', ideal)):
            position, _ = predicted_errors(
                result.geometry, result.covariance, validation_poses, result.free
            )
            predicted[key].append(float(position.mean()))
        paper_p.append(paper.goodness_of_fit.p_value)
        extended_p.append(extended.goodness_of_fit.p_value)
    return runs, predicted, paper_p, extended_p


def _excess_sources(true, nominal, pool, chosen, validation_poses):
    """Where the predicted excess over the 44 comes from: each group of sensor errors freed
    alone, postures selected for the 44 instead, and the best a selection for the validation
    could do (predicted validation error over the 44's)."""
    poses = pool[chosen]

    def cost(free, on=poses):
        paper_mm = design_position_error_mm(true, on, 'paper', validation_poses)
        return design_position_error_mm(true, on, free, validation_poses) / paper_mm

    paper_chosen, _ = select_postures(
        nominal, pool, POSTURES, SIGMAS.averaged([SAMPLES]), free='paper'
    )
    targets = sample_valid_postures(nominal, 200, np.random.default_rng(2), Workspace())
    best = exchange_for_pose_error(
        nominal, pool, chosen, targets, SIGMAS.averaged([SAMPLES]), 'extended', passes=3
    )
    gains = [f'kq{leg}' for leg in range(1, 7)]
    return {
        'kq1_to_kq6': cost(['paper', *gains]),
        'alpha0': cost(['paper', 'alpha0']),
        'extended': cost('extended'),
        'extended_on_postures_selected_for_paper': cost('extended', pool[paper_chosen]),
        'extended_on_postures_selected_for_validation': cost('extended', pool[best]),
    }


def model_section(true, nominal, pool, chosen, validation_poses, quick=False):
    """The ``extended`` fit on sensor-error data against the ``paper`` fit on the same postures
    and noise with ideal sensors, over many seeds, with its Cramer-Rao diagnosis."""
    ideal_true = true.replace(sensors=nominal.sensors)  # the datum only: ideal sensors otherwise
    poses = pool[chosen]
    # The same postures in both runs: those the real platform reaches with and without its
    # sensor errors (a posture at the edge can fail in one of them).
    both = reachable(true, nominal, poses) & reachable(ideal_true, nominal, poses)
    seeds = 20 if quick else MODEL_SEEDS
    runs, predicted, paper_p, extended_p = _model_runs(
        true, ideal_true, nominal, poses, both, seeds, validation_poses
    )
    runs = {key: np.asarray(values) for key, values in runs.items()}
    median = {key: float(np.median(values)) for key, values in runs.items()}
    rng = np.random.default_rng(0)
    resampled = rng.integers(0, seeds, (2000, seeds))
    bootstrap = np.median(runs['extended'][resampled], axis=1) / np.median(
        runs['ideal'][resampled], axis=1
    )
    predicted_extended, predicted_ideal = (
        np.mean(predicted['extended']),
        np.mean(predicted['ideal']),
    )

    return {
        'seeds': seeds,
        'postures': int(both.sum()),
        'extended_validation_mm': median['extended'],
        'ideal_sensors_paper_validation_mm': median['ideal'],
        'extended_over_ideal': median['extended'] / median['ideal'],
        'extended_over_ideal_bootstrap_p5_p95': np.percentile(bootstrap, [5, 95]).tolist(),
        'extended_over_ideal_per_seed': spread(runs['extended'] / runs['ideal']),
        'extended_over_ideal_of_means': float(runs['extended'].mean() / runs['ideal'].mean()),
        'predicted_extended_validation_mm': float(predicted_extended),
        'predicted_ideal_sensors_paper_validation_mm': float(predicted_ideal),
        'predicted_extended_over_ideal': float(predicted_extended / predicted_ideal),
        'measured_over_predicted': {
            'extended': float(runs['extended'].mean() / predicted_extended),
            'ideal_sensors_paper': float(runs['ideal'].mean() / predicted_ideal),
        },
        'extended_ideal_sensors_validation_mm': median['extended_ideal_sensors'],
        'sensor_error_bias_mm_max': float(
            np.max(np.abs(runs['extended'] - runs['extended_ideal_sensors']))
        ),
        'predicted_over_paper': _excess_sources(true, nominal, pool, chosen, validation_poses),
        'paper_validation_mm': median['paper'],
        'paper_over_extended': median['paper'] / median['extended'],
        'paper_p_value_max': max(paper_p),
        'extended_p_value_median': statistics.median(extended_p),
        'before_calibration_mm': validate(true, nominal, validation_poses)['position_mm_mean'],
    }


def _good_model_section(ideal_true, nominal, poses, validation_poses, quick):
    """On ideal data, the goodness of fit accepts the default (extended) model."""
    seeds = 10 if quick else 40
    accepted, paper_same = 0, []
    for seed in range(100, 100 + seeds):
        legs, readings, _, commanded = collect(ideal_true, nominal, poses, seed)
        extended = fit(nominal, legs, readings, commanded, 'extended')
        accepted += bool(extended.goodness_of_fit.p_value > goodness.DEFAULT_SIGNIFICANCE)
        if seed < 103:
            paper = fit(nominal, legs, readings, commanded, 'paper')
            paper_same.append(
                (
                    position_error_mm(ideal_true, extended, validation_poses),
                    position_error_mm(ideal_true, paper, validation_poses),
                )
            )
    good = {
        'seeds': seeds,
        'acceptance_rate': accepted / seeds,
        'extended_vs_paper_validation_mm': paper_same,
    }

    return good


def _noise_section(std):
    """Noise estimates from the scatter ``std`` within each posture."""
    channels = {
        'leg_lengths': SIGMAS.leg_lengths,
        'inclinometer': SIGMAS.inclinometer,
        'encoder': SIGMAS.encoder,
        'lvdt': SIGMAS.lvdt,
    }
    estimates = estimate_noise(std, np.full(len(std), SAMPLES), channels)
    noise = {
        'pairs_per_posture': SAMPLES,
        'ratios': {name: entry['ratio'] for name, entry in estimates.items()},
        'worst_relative_error': max(abs(entry['ratio'] - 1.0) for entry in estimates.values()),
    }

    return noise


def _outlier_section(true, nominal, legs, readings, commanded, validation_poses):
    """Outliers: 3 of 60 postures corrupted; huber vs linear vs the clean run."""
    clean = fit(nominal, legs, readings, commanded, 'extended')
    corrupted_legs, corrupted_readings = legs.copy(), readings.copy()
    for posture, column, offset in CORRUPTIONS:
        if column < 6:
            corrupted_legs[posture, column] += offset
        else:
            corrupted_readings[posture, column - 6] += offset
    runs = {
        loss: fit(nominal, corrupted_legs, corrupted_readings, commanded, 'extended', loss)
        for loss in ('linear', 'huber')
    }
    clean_mm = position_error_mm(true, clean, validation_poses)
    corrupted = sorted(posture for posture, _, _ in CORRUPTIONS)
    outliers = {
        'corrupted_postures': corrupted,
        'clean_validation_mm': clean_mm,
        'clean_p_value': clean.goodness_of_fit.p_value,
    }
    for loss, result in runs.items():
        named = sorted(entry['posture'] for entry in result.outliers)
        outliers[f'{loss}_validation_mm'] = position_error_mm(true, result, validation_poses)
        outliers[f'{loss}_over_clean'] = outliers[f'{loss}_validation_mm'] / clean_mm
        outliers[f'{loss}_named_outliers'] = named
        outliers[f'{loss}_names_all_corrupted'] = set(corrupted) <= set(named)
    outliers['huber_down_weighted'] = runs['huber'].down_weighted[:10]
    return outliers


def calibrator_design():
    """``(true, nominal, pool, chosen, validation_poses)``: the shipped pair, a pool of 600, the
    postures the calibrator selects from it for its default free set (``extended``) with its
    default sigmas, and 50 validation postures."""
    true, nominal = default_true_and_nominal()
    workspace = Workspace()
    pool = sample_valid_postures(nominal, 600, np.random.default_rng(0), workspace)
    chosen, _ = select_postures(
        nominal, pool, POSTURES, SIGMAS.averaged([SAMPLES]), free='extended'
    )
    validation_poses = sample_valid_postures(nominal, 50, np.random.default_rng(1), workspace)
    return true, nominal, pool, chosen, validation_poses


def run(quick=False):
    """The ``sensor_errors`` section (``quick``: fewer seeds for the model and the acceptance)."""
    true, nominal, pool, chosen, validation_poses = calibrator_design()
    ideal_true = true.replace(sensors=nominal.sensors)  # the datum only: ideal sensors otherwise
    poses = pool[chosen]

    # The extended model on sensor errors vs the 44 on ideal sensors (same postures and noise);
    # the goodness of fit, the noise estimates and the outliers.
    model = model_section(true, nominal, pool, chosen, validation_poses, quick)

    good = _good_model_section(ideal_true, nominal, poses, validation_poses, quick)
    legs, readings, windows, commanded = collect(true, nominal, poses, 7)
    noise = _noise_section(windows.std(axis=1, ddof=1))
    outliers = _outlier_section(true, nominal, legs, readings, commanded, validation_poses)
    return {
        'description': (
            'shipped real platform with sensor errors (leg gains, alpha0, LVDT gain datum), 60 '
            'selected postures, 10 samples each, 1 um / 0.001 deg noise, implicit formulation; '
            'validation: mean position error over 50 postures (mm)'
        ),
        'model': model,
        'good_model': good,
        'noise_estimates': noise,
        'outliers': outliers,
    }


def within_posture_noise(sample_std, n_samples):
    """Per-sample noise of each channel from the scatter within each posture,
    ``{channel: (sigma, dof)}`` (channels with data): ``sample_std`` (M, 10) per posture (ddof 1)
    of the 6 legs and 4 readings over ``n_samples`` (M,), pooled in the variance."""
    sample_std = np.asarray(sample_std, dtype=float).reshape(-1, 10)
    degrees = np.clip(np.asarray(n_samples, dtype=float).reshape(-1) - 1.0, 0.0, None)
    estimates = {}
    for channel, columns in goodness.NOISE_CHANNELS.items():
        values = sample_std[:, columns]
        usable = np.all(np.isfinite(values), axis=1) & (degrees > 0)
        if not usable.any():
            continue
        dof = float(np.sum(degrees[usable]) * values.shape[1])
        variance = np.sum(degrees[usable, None] * values[usable] ** 2) / dof
        estimates[channel] = (math.sqrt(variance), dof)
    return estimates


def estimate_noise(sample_std, n_samples, configured):
    """Per-sample noise of each sensor from the scatter within each posture
    (:func:`within_posture_noise`) beside the ``configured`` ``{channel: sigma}``:
    ``{channel: {'configured', 'estimated', 'ratio', 'warning'}}``."""
    estimates = {}
    for channel, (estimated, _) in within_posture_noise(sample_std, n_samples).items():
        sigma = float(configured[channel])
        ratio, warning = goodness.noise_warning(estimated, sigma)
        estimates[channel] = {
            'configured': sigma,
            'estimated': estimated,
            'ratio': ratio,
            'warning': warning,
        }
    return estimates


def position_weight(geometry, targets, free=None):
    """``W`` (n, n): the Gram matrix of the position sensitivities at ``targets`` (M, 6), so that
    ``trace(W C)`` is the summed predicted squared position error (m^2) under a covariance C."""
    sensitivity = pose_sensitivities(geometry, targets, resolve_free(free))[:, :3]
    return np.einsum('tai,taj->ij', sensitivity, sensitivity)


def exchange_for_pose_error(
    geometry,
    pool,
    chosen,
    targets,
    sigmas=DEFAULT_SENSOR_NOISE,
    free=None,
    formulation=DEFAULT_FORMULATION,
    passes=1,
):
    """Indices of ``pool`` from ``chosen`` by exchange, minimising the predicted position error at
    ``targets`` (``trace(W T^-1)``, :func:`position_weight`, T the information of the chosen
    postures) instead of the condition number: a design for the validation error itself.

    Each sweep replaces each chosen posture by the candidate that lowers the objective most, if
    any (exact for every candidate through the Woodbury identity on its low-rank factor).
    """
    pool = np.asarray(pool, dtype=float)
    factors = posture_factors(geometry, pool, sigmas, free, formulation)  # (N, r, n)
    weight = position_weight(geometry, targets, free)
    information = np.einsum('mri,mrj->mij', factors, factors)
    chosen = [int(index) for index in chosen]
    total = information[chosen].sum(axis=0)
    identity = np.eye(factors.shape[1])

    def decrease(indices, inverse):
        # trace(W B^-1) - trace(W (B + G^T G)^-1) = trace((I + G B^-1 G^T)^-1 G B^-1 W B^-1 G^T)
        projected = factors[indices] @ inverse
        inner = identity + projected @ np.swapaxes(factors[indices], -1, -2)
        weighted = projected @ weight @ np.swapaxes(projected, -1, -2)
        return np.einsum('...ij,...ji->...', np.linalg.inv(inner), weighted)

    for _ in range(passes):
        improved = False
        for position in range(len(chosen)):
            base = total - information[chosen[position]]
            inverse = np.linalg.inv(base)
            candidates = np.setdiff1d(np.arange(len(pool)), chosen)
            gains = decrease(candidates, inverse)
            best = int(np.argmax(gains))
            if gains[best] > decrease(chosen[position], inverse) * (1.0 + 1e-9):
                chosen[position] = int(candidates[best])
                total = base + information[chosen[position]]
                improved = True
        if not improved:
            break
    return np.array(chosen)
