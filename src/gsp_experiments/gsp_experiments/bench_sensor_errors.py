"""The ``sensor_errors`` section of ``make bench`` (docs/sensor_errors.md): sensor-error model,
goodness of fit, noise estimates and robust fitting, on simulated calibrator runs.

A run is what the calibrator collects: the shipped real platform (with its sensor errors) driven
by the nominal controller to 60 selected postures, ``samples`` noisy samples per posture averaged
(their scatter kept for the noise estimates), then identified. Validation drives 50 other postures
with the calibrated controller and compares the reached poses with the commands (mean position
error, mm). Every figure below compares runs of the same postures and noise.
"""

import math
import statistics

import numpy as np

from gsp_kinematics import goodness
from gsp_kinematics.identification import Options, Sigmas, identify
from gsp_kinematics.kinematics import (
    Workspace,
    forward_kinematics_masked,
    sample_valid_postures,
)
from gsp_kinematics.selection import select_postures
from gsp_kinematics.validation import commanded_articular, sensor_measurements, validate

from .nominal_sets import default_true_and_nominal

SIGMAS = Sigmas()  # per-sample noise: 1 um, 0.001 deg (Table 3's first level)
POSTURES = 60
SAMPLES = 10
#: Corruptions of the outlier figure: (posture, reading column, offset); columns 0-5 are legs.
CORRUPTIONS = ((5, 2, 0.5e-3), (23, 6 + 0, math.radians(0.05)), (41, 4, -0.5e-3))


def collect(true, controller, poses, seed, samples=SAMPLES, sigmas=SIGMAS):
    """Averaged rows and within-posture std of a simulated run: ``(legs (M, 6), readings (M, 4),
    std (M, 10), reached)``; postures the real platform cannot reach are left out."""
    rng = np.random.default_rng(seed)
    reached, ok = forward_kinematics_masked(
        true, commanded_articular(true, controller, poses), poses
    )
    legs, readings = sensor_measurements(true, reached[ok])
    exact = np.concatenate([legs, readings], axis=1)
    scale = np.concatenate([np.full(6, sigmas.leg_lengths), sigmas.readings()])
    drawn = exact[:, None, :] + rng.normal(0.0, 1.0, (exact.shape[0], samples, 10)) * scale
    mean, std = drawn.mean(axis=1), drawn.std(axis=1, ddof=1)
    return mean[:, :6], mean[:, 6:], std, poses[ok]


def averaged(sigmas, samples=SAMPLES):
    factor = 1.0 / math.sqrt(samples)
    return Sigmas(
        *(
            value * factor
            for value in (sigmas.leg_lengths, sigmas.inclinometer, sigmas.encoder, sigmas.lvdt)
        )
    )


def fit(nominal, legs, readings, commanded, free, loss='linear'):
    return identify(
        nominal,
        legs,
        readings,
        averaged(SIGMAS),
        free=free,
        pose_guesses=commanded,
        options=Options(loss=loss),
    )


def position_error_mm(true, result, validation_poses):
    return validate(true, result.geometry, validation_poses)['position_mm_mean']


def run(quick=False):
    """The ``sensor_errors`` section (``quick``: fewer seeds for the acceptance rate)."""
    true, nominal = default_true_and_nominal()
    ideal_true = true.replace(sensors=nominal.sensors)  # the datum only: ideal sensors otherwise
    workspace = Workspace()
    pool = sample_valid_postures(nominal, 600, np.random.default_rng(0), workspace)
    chosen, _ = select_postures(nominal, pool, POSTURES, averaged(SIGMAS), free='extended')
    poses = pool[chosen]
    validation_poses = sample_valid_postures(nominal, 50, np.random.default_rng(1), workspace)

    # 1. The extended model on sensor errors vs the 44 on ideal sensors (same postures and noise).
    extended_mm, ideal_mm, paper_mm, paper_p, extended_p = [], [], [], [], []
    for seed in range(3 if quick else 5):
        legs, readings, _, commanded = collect(true, nominal, poses, seed)
        extended = fit(nominal, legs, readings, commanded, 'extended')
        paper = fit(nominal, legs, readings, commanded, 'paper')
        legs_i, readings_i, _, commanded_i = collect(ideal_true, nominal, poses, seed)
        ideal = fit(nominal, legs_i, readings_i, commanded_i, 'paper')
        extended_mm.append(position_error_mm(true, extended, validation_poses))
        paper_mm.append(position_error_mm(true, paper, validation_poses))
        ideal_mm.append(position_error_mm(ideal_true, ideal, validation_poses))
        paper_p.append(paper.goodness_of_fit.p_value)
        extended_p.append(extended.goodness_of_fit.p_value)
    model = {
        'seeds': len(extended_mm),
        'extended_validation_mm': statistics.median(extended_mm),
        'ideal_sensors_paper_validation_mm': statistics.median(ideal_mm),
        'extended_over_ideal': statistics.median(extended_mm) / statistics.median(ideal_mm),
        'paper_validation_mm': statistics.median(paper_mm),
        'paper_over_extended': statistics.median(paper_mm) / statistics.median(extended_mm),
        'paper_p_value_max': max(paper_p),
        'extended_p_value_median': statistics.median(extended_p),
        'before_calibration_mm': validate(true, nominal, validation_poses)['position_mm_mean'],
    }

    # 2. On ideal data, the goodness of fit accepts the default (extended) model.
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

    # 3. Noise estimates from the scatter within each posture.
    legs, readings, std, commanded = collect(true, nominal, poses, 7)
    channels = {
        'leg_lengths': SIGMAS.leg_lengths,
        'inclinometer': SIGMAS.inclinometer,
        'encoder': SIGMAS.encoder,
        'lvdt': SIGMAS.lvdt,
    }
    estimates = goodness.estimate_noise(std, np.full(len(std), SAMPLES), channels)
    noise = {
        'samples_per_posture': SAMPLES,
        'ratios': {name: entry['ratio'] for name, entry in estimates.items()},
        'worst_relative_error': max(abs(entry['ratio'] - 1.0) for entry in estimates.values()),
    }

    # 4. Outliers: 3 of 60 postures corrupted; huber vs linear vs the clean run.
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
