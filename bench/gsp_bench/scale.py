"""Benchmark sections on scale and on the predicted accuracy (see :mod:`.core`).

* ``identification.scaling`` (:func:`identification_scaling`): wall time of one identification
  for 60, 600 and 6000 postures (random reachable postures, as logged along a trajectory; nominal
  set 2, Table 3's first noise level) and the exponent of a power-law fit ``ms ~ postures^k``.
  A size whose predicted time (from the smaller ones) exceeds a budget is not run: it is listed
  in ``skipped`` with its prediction.
* ``selection`` (:func:`bench_selection`): wall time of ``select_postures`` (60 of a pool of 600,
  and of 6000) and the condition numbers.
* ``prediction`` (:func:`bench_prediction`): over 20 noise seeds, the measured validation means of
  the calibrated platform over the means the parameter covariance predicts at the same postures
  (``position_ratio``, ``orientation_ratio``: 1 when the Cramér-Rao prediction holds).
"""

import math
import statistics
import time

import numpy as np

from gsp_kinematics.estimation.identification import identify
from gsp_kinematics.estimation.prediction import predicted_errors
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import (
    forward_kinematics_masked,
    inverse_kinematics,
    sample_valid_postures,
)
from gsp_kinematics.model.validation import commanded_articular, sensor_measurements, validate
from gsp_kinematics.planning.selection import select_postures

from .nominal_sets import drawing_geometry, nominal_set
from .paper import add_noise, noise_from_levels

SCALING_POSTURES = (60, 600, 6000)
SCALING_BUDGET_S = 60.0  #: a size predicted to take longer than this is skipped
REPEATED_UP_TO = 6000  #: sizes up to this many postures are timed ``repeats`` times, others once
#: Parameters the prediction benchmark identifies: the calibrator's default.
FREE = 'extended'


def _scaling_problem(postures, seed=0):
    exact = drawing_geometry()
    nominal = nominal_set(exact, 2)
    rng = np.random.default_rng([seed, postures])
    poses = sample_valid_postures(nominal, postures, rng)
    leg_lengths, readings = add_noise(
        inverse_kinematics(exact, poses), device_readings(exact, poses), 0.001, 0.001, rng
    )
    return nominal, leg_lengths, readings, poses


def _fit_exponent(postures, milliseconds):
    if len(postures) < 2:
        return None
    return float(np.polyfit(np.log(postures), np.log(milliseconds), 1)[0])


def identification_scaling(sizes=SCALING_POSTURES, repeats=3, budget_s=SCALING_BUDGET_S):
    """``{postures, ms, exponent, cpu_ms, cpu_exponent, iterations, skipped, budget_s}``: median
    of ``repeats`` runs (one above :data:`REPEATED_UP_TO` postures) after one untimed warm-up run.

    A size is skipped when its time predicted from the last size run, at least linear in the
    postures whatever the fit says (timing noise can make the fit flat), exceeds ``budget_s``
    (wall time)."""
    sigmas = noise_from_levels(0.001, 0.001)
    done, milliseconds, cpu_milliseconds, iterations, skipped = [], [], [], [], []
    warm = False
    for size in sizes:
        if len(done) >= 2:
            exponent = max(1.0, _fit_exponent(done, milliseconds))
            predicted_s = milliseconds[-1] / 1000.0 * (size / done[-1]) ** exponent
            if predicted_s > budget_s:
                skipped.append({'postures': size, 'predicted_s': predicted_s})
                continue
        nominal, leg_lengths, readings, poses = _scaling_problem(size)
        if not warm:  # the first call in a process pays for imports and caches
            identify(nominal, leg_lengths, readings, sigmas, pose_guesses=poses)
            warm = True
        times, cpu_times = [], []
        for _ in range(repeats if size <= REPEATED_UP_TO else 1):
            started, started_cpu = time.perf_counter(), time.process_time()
            result = identify(nominal, leg_lengths, readings, sigmas, pose_guesses=poses)
            times.append(1000.0 * (time.perf_counter() - started))
            cpu_times.append(1000.0 * (time.process_time() - started_cpu))
        done.append(size)
        milliseconds.append(statistics.median(times))
        cpu_milliseconds.append(statistics.median(cpu_times))
        iterations.append(int(result.iterations))
    return {
        'postures': done,
        'ms': milliseconds,
        'exponent': _fit_exponent(done, milliseconds),
        'cpu_ms': cpu_milliseconds,
        'cpu_exponent': _fit_exponent(done, cpu_milliseconds),
        'iterations': iterations,
        'skipped': skipped,
        'budget_s': budget_s,
    }


def bench_selection(pools=(600, 6000), count=60, repeats=3, seed=0):
    """``{pool_600_s, pool_6000_s, pool_600_cpu_s, ..., condition_600, ...}``: median wall (and
    process CPU) time of
    :func:`select_postures` (the information factors included; the pool's sampling not)."""
    nominal = default_geometry('nominal')
    section = {'postures': count, 'repeats': repeats}
    for size in pools:
        pool = sample_valid_postures(nominal, size, np.random.default_rng([seed, size]))
        times, cpu_times = [], []
        for _ in range(repeats):
            started, started_cpu = time.perf_counter(), time.process_time()
            _, condition = select_postures(nominal, pool, count)
            times.append(time.perf_counter() - started)
            cpu_times.append(time.process_time() - started_cpu)
        section[f'pool_{size}_s'] = statistics.median(times)
        # CPU time: steadier than wall time on a machine shared with other jobs.
        section[f'pool_{size}_cpu_s'] = statistics.median(cpu_times)
        section[f'condition_{size}'] = condition
    return section


def bench_prediction(seeds=20, postures=60, pairs_per_posture=10, validation_postures=200):
    """Measured over predicted mean validation errors of the shipped platform (true and nominal
    geometry files, sensor errors included), as the calibrator runs it: 60 selected postures,
    each row the mean of 10 samples at Table 3's first level, commanded with the nominal
    geometry, the calibrator's default ``extended`` parameters identified."""
    true, nominal = default_geometry('true'), default_geometry('nominal')
    factor = 1.0 / math.sqrt(pairs_per_posture)
    sigmas = noise_from_levels(0.001 * factor, 0.001 * factor)
    pool = sample_valid_postures(nominal, 600, np.random.default_rng(0))
    indices, _ = select_postures(nominal, pool, postures, sigmas, free=FREE)
    poses = pool[indices]
    # What the calibrator collects: the real platform (with its sensor errors) driven by the
    # nominal controller, read by the real sensors.
    reached, ok = forward_kinematics_masked(true, commanded_articular(true, nominal, poses), poses)
    poses = poses[ok]
    legs, readings = sensor_measurements(true, reached[ok])
    validation = sample_valid_postures(nominal, validation_postures, np.random.default_rng(1))
    measured, predicted = [], []
    for seed in range(seeds):
        rng = np.random.default_rng(100 + seed)
        result = identify(
            nominal,
            legs + rng.normal(0.0, sigmas.leg_lengths, legs.shape),
            readings + rng.normal(0.0, 1.0, (len(legs), 4)) * sigmas.readings(),
            sigmas,
            free=FREE,
            pose_guesses=poses,
        )
        errors = validate(true, result.geometry, validation)
        position, orientation = predicted_errors(
            result.geometry, result.covariance, validation, result.free
        )
        measured.append((errors['position_mm_mean'], errors['orientation_deg_mean']))
        predicted.append((float(position.mean()), float(orientation.mean())))
    measured_mean = np.mean(measured, axis=0)
    predicted_mean = np.mean(predicted, axis=0)
    per_seed = np.asarray(measured) / np.asarray(predicted)
    return {
        'position_ratio': float(measured_mean[0] / predicted_mean[0]),
        'orientation_ratio': float(measured_mean[1] / predicted_mean[1]),
        'seeds': seeds,
        'measured_position_mm_mean': float(measured_mean[0]),
        'predicted_position_mm_mean': float(predicted_mean[0]),
        'measured_orientation_deg_mean': float(measured_mean[1]),
        'predicted_orientation_deg_mean': float(predicted_mean[1]),
        'position_ratio_per_seed_p5_p95': np.percentile(per_seed[:, 0], [5, 95]).tolist(),
        'orientation_ratio_per_seed_p5_p95': np.percentile(per_seed[:, 1], [5, 95]).tolist(),
        'postures': int(len(legs)),
        'pairs_per_posture': pairs_per_posture,
        'validation_postures': validation_postures,
    }
