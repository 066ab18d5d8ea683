"""Reproduction of Rauf & Ryu's simulations (section 4.2-4.3): Figs. 6-8 and Table 3.

``gsp_paper`` (``make paper``):

* the paper's tables: the copy shipped in this package (:mod:`gsp_bench.tables`), or ``--tables``;
* exact geometry: :func:`~gsp_bench.nominal_sets.drawing_geometry` (D0 = 850 mm, gamma = 90 deg);
  nominal sets 1-3 from :func:`~gsp_bench.nominal_sets.nominal_set` (Tables 1 and 2);
* per nominal set, 60 postures selected (:func:`~gsp_kinematics.planning.selection.select_postures`) from a
  pool of random valid postures sampled under the nominal geometry, with the sigmas of the
  identification that uses them (the noise study selects once per noise level unless
  ``--select-once``: the best design depends on how angle and length noise compare). As in the
  paper, the selected postures are where the platform really is: the exact geometry gives the measured leg lengths
  (eq 4-5) and device readings (eq 9), and each posture is also FK's starting guess;
* noise-free: all 44 parameters identified with the default formulation; the initial and final
  error of every parameter is printed and plotted (the data of Figs. 6-8);
* noise study (nominal set 1): Gaussian noise at Table 3's four levels (angle noise on the
  inclinometer and the encoder, length noise on the legs and the LVDT), ``--seeds`` draws each,
  identified with every formulation from the same noisy data; accuracy is the mean position and
  orientation error over 50 random valid validation postures (:func:`~gsp_kinematics.model.validation.validate`
  with the calibrated geometry as the controller's), beside Table 3.

Each noise row carries the Cramér-Rao prediction beside the Monte-Carlo figure (the mean error
the identification's covariance predicts at the validation postures). ``paper_matched``
(:mod:`.paper_matched`, ``--skip-matched``): the search for a platform that reproduces the paper's
initial error, and Table 3 rerun on it.

Writes ``results/paper.json`` (its keys: docs/figures.md) and one PNG per nominal set.
"""

import concurrent.futures
import dataclasses
import math
import multiprocessing
import time

import numpy as np

from gsp_kinematics.estimation.identification import DEFAULT_FORMULATION, identify
from gsp_kinematics.estimation.prediction import predicted_errors
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import PARAMETER_NAMES, parameter_errors
from gsp_kinematics.model.kinematics import inverse_kinematics, sample_valid_postures
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoise
from gsp_kinematics.model.validation import validate
from gsp_kinematics.planning.selection import select_postures

from .nominal_sets import drawing_geometry, nominal_set
from .tables import load_tables, table3

#: Formulations of the noise study, in print order ('fk' is the noise-weighted FK-based residual).
NOISE_FORMULATIONS = ('paper', 'implicit', 'fk')


@dataclasses.dataclass(frozen=True)
class PaperConfig:
    seeds: int = 20  #: noise draws per Table 3 level
    pool_size: int = 600  #: random valid postures to select from
    postures: int = 60  #: selected postures (the paper's M)
    validation_postures: int = 50
    sets: tuple = (1, 2, 3)
    noise_set: int = 1
    formulations: tuple = NOISE_FORMULATIONS
    noise_free_formulation: str = DEFAULT_FORMULATION
    select_per_level: bool = True  #: select the noise study's postures with each level's sigmas
    seed: int = 0  #: base seed of pools, validation postures and noise draws
    jobs: int = 2


# --- simulation ---------------------------------------------------------------------------------


def measurements(exact, poses):
    """Noise-free leg lengths (M, 6) and device readings (M, 4) of the exact platform at ``poses``."""
    return inverse_kinematics(exact, poses), device_readings(exact, poses)


def noise_from_levels(angle_noise_deg, length_noise_mm):
    """Table 3's convention: one angular level (deg) and one length level (mm) on every sensor."""
    lengths, angles = length_noise_mm / 1000.0, math.radians(angle_noise_deg)
    return SensorNoise(leg_lengths=lengths, inclinometer=angles, encoder=angles, lvdt=lengths)


def add_noise(leg_lengths, readings, angle_noise_deg, length_noise_mm, rng):
    """Gaussian noise: length level on legs and LVDT (mm), angle level on inclinometer and encoder (deg)."""
    length_sigma = length_noise_mm / 1000.0
    angle_sigma = math.radians(angle_noise_deg)
    noisy_legs = leg_lengths + rng.normal(0.0, length_sigma, leg_lengths.shape)
    reading_sigmas = np.array([angle_sigma, angle_sigma, angle_sigma, length_sigma])
    noisy_readings = readings + rng.normal(0.0, 1.0, readings.shape) * reading_sigmas
    return noisy_legs, noisy_readings


def select_for_set(exact, set_number, config, sigmas=DEFAULT_SENSOR_NOISE):
    """Nominal set, the selected postures (M, 6) and the selection's condition number.

    The pool depends on the set only, so selections for other sigmas pick from the same postures.
    """
    nominal = nominal_set(exact, set_number)
    rng = np.random.default_rng([config.seed, set_number])
    pool = sample_valid_postures(nominal, config.pool_size, rng)
    indices, condition = select_postures(nominal, pool, config.postures, sigmas)
    return nominal, pool[indices], condition


def _selection_task(args):
    exact, set_number, sigmas, config = args
    started = time.perf_counter()
    _, poses, condition = select_for_set(exact, set_number, config, sigmas)
    return {
        'poses': poses,
        'condition_number': float(condition),
        'selection_s': time.perf_counter() - started,
    }


def _noise_free_task(args):
    exact, set_number, selection, config, validation_poses = args
    nominal = nominal_set(exact, set_number)
    poses = selection['poses']
    leg_lengths, readings = measurements(exact, poses)
    result = identify(
        nominal,
        leg_lengths,
        readings,
        DEFAULT_SENSOR_NOISE,
        formulation=config.noise_free_formulation,
        pose_guesses=poses,
    )
    initial = parameter_errors(nominal, exact)
    final = parameter_errors(result.geometry, exact)
    accuracy = validate(exact, result.geometry, validation_poses)
    return [
        {
            'set': set_number,
            'formulation': result.formulation,
            'max_param_error_mm': float(np.max(np.abs(final[:43]))),
            'max_param_error_deg': float(abs(final[43])),
            'converged': bool(result.converged),
            'status': int(result.status),
            'message': result.message,
            'iterations': int(result.iterations),
            'identification_ms': 1000.0 * result.duration_s,
            'selection_s': selection['selection_s'],
            'condition_number': selection['condition_number'],
            'excluded_postures': list(result.excluded_postures),
            'max_initial_error_mm': float(np.max(np.abs(initial[:43]))),
            'initial_error_deg': float(abs(initial[43])),
            'validation': accuracy,
            'parameters': [
                {'name': name, 'initial_error': float(a), 'final_error': float(b)}
                for name, a, b in zip(PARAMETER_NAMES, initial, final, strict=True)
            ],
        }
    ]


def _task(args):
    kind, payload = args
    return _noise_free_task(payload) if kind == 'noise_free' else _noise_task(payload)


def _noise_task(args):
    exact, nominal, poses, level, level_index, seed, config, validation_poses = args
    rng = np.random.default_rng([config.seed, 7919, level_index, seed])
    leg_lengths, readings = measurements(exact, poses)
    leg_lengths, readings = add_noise(
        leg_lengths, readings, level['angle_noise_deg'], level['length_noise_mm'], rng
    )
    sigmas = noise_from_levels(level['angle_noise_deg'], level['length_noise_mm'])
    rows = []
    for formulation in config.formulations:
        result = identify(
            nominal, leg_lengths, readings, sigmas, formulation=formulation, pose_guesses=poses
        )
        accuracy = validate(exact, result.geometry, validation_poses)
        predicted = cramer_rao_errors(result, validation_poses)
        rows.append(
            {
                'cramer_rao_position_mm': predicted[0],
                'cramer_rao_orientation_deg': predicted[1],
                'level': level_index,
                'seed': seed,
                'formulation': formulation,
                'position_mm': accuracy['position_mm_mean'],
                'orientation_deg': accuracy['orientation_deg_mean'],
                'position_mm_max': accuracy['position_mm_max'],
                'orientation_deg_max': accuracy['orientation_deg_max'],
                'max_param_error_mm': float(
                    np.max(np.abs(parameter_errors(result.geometry, exact)[:43]))
                ),
                'converged': bool(result.converged),
                'iterations': int(result.iterations),
                'excluded': len(result.excluded_postures),
                'unreachable': int(accuracy.get('unreachable', 0)),
                'identification_ms': 1000.0 * result.duration_s,
            }
        )
    return rows


def cramer_rao_errors(result, poses):
    """Mean predicted (mm, deg) error at ``poses`` from the identification's covariance (NaN
    when it did not converge): the Cramér-Rao prediction beside a Monte-Carlo figure."""
    covariance = np.asarray(result.covariance, dtype=float)
    if not result.converged or not np.all(np.isfinite(covariance)):
        return float('nan'), float('nan')
    position, orientation = predicted_errors(result.geometry, covariance, poses, result.free)
    return float(np.mean(position)), float(np.mean(orientation))


def _map(function, tasks, jobs):
    if jobs <= 1 or len(tasks) <= 1:
        return [function(task) for task in tasks]
    context = multiprocessing.get_context(
        'fork' if 'fork' in multiprocessing.get_all_start_methods() else None
    )
    with concurrent.futures.ProcessPoolExecutor(max_workers=jobs, mp_context=context) as executor:
        return list(executor.map(function, tasks, chunksize=max(1, len(tasks) // (4 * jobs))))


def _select(exact, config, paper_levels, log):
    """The posture selections of a run: ``(level_sigmas, {(nominal set, sigmas): selection})``.

    Postures are selected with the sigmas they are identified with: the noise-free studies with
    the default (Table 3's first level), each noise level with its own."""
    level_sigmas = [
        noise_from_levels(level['angle_noise_deg'], level['length_noise_mm'])
        if config.select_per_level
        else DEFAULT_SENSOR_NOISE
        for level in paper_levels
    ]
    keys = [(k, DEFAULT_SENSOR_NOISE) for k in config.sets] + [
        (config.noise_set, sigmas) for sigmas in level_sigmas
    ]
    keys = list(dict.fromkeys(keys))
    log(
        f'selecting {config.postures} of {config.pool_size} postures ({len(keys)} selections: nominal sets '
        f'{list(config.sets)}, noise levels{" each" if config.select_per_level else ""}) ...'
    )
    selected = _map(
        _selection_task, [(exact, k, sigmas, config) for k, sigmas in keys], config.jobs
    )
    selections = dict(zip(keys, selected, strict=True))

    return level_sigmas, selections


def _identify_all(exact, config, paper_levels, level_sigmas, selections, validation_poses, log):
    """Every identification of a run, in ``config.jobs`` processes: ``(noise-free rows, noise
    rows)``."""
    log(
        f'identifying: nominal sets {list(config.sets)} noise-free ({config.noise_free_formulation}); '
        f'noise study on nominal set {config.noise_set}: {len(paper_levels)} levels x {config.seeds} seeds '
        f'x {len(config.formulations)} formulations ...'
    )
    nominal = nominal_set(exact, config.noise_set)
    tasks = [
        ('noise_free', (exact, k, selections[(k, DEFAULT_SENSOR_NOISE)], config, validation_poses))
        for k in config.sets
    ]
    tasks += [
        (
            'noise',
            (
                exact,
                nominal,
                selections[(config.noise_set, level_sigmas[index])]['poses'],
                level,
                index,
                seed,
                config,
                validation_poses,
            ),
        )
        for index, level in enumerate(paper_levels)
        for seed in range(config.seeds)
    ]
    outputs = _map(_task, tasks, config.jobs)
    noise_free = [
        row
        for output, task in zip(outputs, tasks, strict=True)
        if task[0] == 'noise_free'
        for row in output
    ]
    rows = [
        row
        for output, task in zip(outputs, tasks, strict=True)
        if task[0] == 'noise'
        for row in output
    ]
    return noise_free, rows


def _noise_summary(level, formulation, rows, condition_number):
    """One row of Table 3 reproduced: the noise ``level``'s ``rows`` (one per seed) with
    ``formulation``, against the paper's figures; ``condition_number``: the selection's."""
    position = np.array([row['position_mm'] for row in rows])
    orientation = np.array([row['orientation_deg'] for row in rows])
    return {
        'angle_noise_deg': level['angle_noise_deg'],
        'length_noise_mm': level['length_noise_mm'],
        'formulation': formulation,
        'seeds': len(rows),
        'position_mm': float(position.mean()),
        'orientation_deg': float(orientation.mean()),
        'paper_position_mm': level['position_mm'],
        'paper_orientation_deg': level['orientation_deg'],
        'selection_condition_number': condition_number,
        'position_ratio_to_paper': float(position.mean() / level['position_mm']),
        'orientation_ratio_to_paper': float(orientation.mean() / level['orientation_deg']),
        'cramer_rao_position_mm': float(np.mean([row['cramer_rao_position_mm'] for row in rows])),
        'cramer_rao_orientation_deg': float(
            np.mean([row['cramer_rao_orientation_deg'] for row in rows])
        ),
        'position_mm_std_over_seeds': float(position.std()),
        'orientation_deg_std_over_seeds': float(orientation.std()),
        'position_mm_max': float(max(row['position_mm_max'] for row in rows)),
        'orientation_deg_max': float(max(row['orientation_deg_max'] for row in rows)),
        'max_param_error_mm_mean': float(np.mean([row['max_param_error_mm'] for row in rows])),
        'converged': int(sum(row['converged'] for row in rows)),
        'excluded_postures_total': int(sum(row['excluded'] for row in rows)),
        'unreachable_validation_postures_total': int(sum(row['unreachable'] for row in rows)),
        'iterations_mean': float(np.mean([row['iterations'] for row in rows])),
        'identification_ms_median': float(np.median([row['identification_ms'] for row in rows])),
    }


def run(config=PaperConfig(), tables=None, log=print, exact=None):
    """Run the reproduction; returns the JSON-ready document (see the module docstring).

    ``exact``: the real platform (default :func:`drawing_geometry`); its nominal sets are drawn
    from it with Table 1's statistics (see :mod:`.paper_matched`)."""
    if tables is None:
        tables, tables_source = load_tables()
    else:
        tables_source = 'given'
    paper_initial, paper_levels = table3(tables)
    started = time.perf_counter()
    exact_description = 'nominal_sets.drawing_geometry()' if exact is None else 'given'
    exact = drawing_geometry() if exact is None else exact
    validation_poses = sample_valid_postures(
        exact, config.validation_postures, np.random.default_rng([config.seed, 50])
    )
    initial = validate(exact, nominal_set(exact, config.noise_set), validation_poses)

    level_sigmas, selections = _select(exact, config, paper_levels, log)
    noise_free, rows = _identify_all(
        exact, config, paper_levels, level_sigmas, selections, validation_poses, log
    )
    noise = []
    for index, level in enumerate(paper_levels):
        condition = selections[(config.noise_set, level_sigmas[index])]['condition_number']
        for formulation in config.formulations:
            mine = [
                row for row in rows if row['level'] == index and row['formulation'] == formulation
            ]
            noise.append(_noise_summary(level, formulation, mine, condition))
    return {
        'initial': {
            'position_mm': initial['position_mm_mean'],
            'orientation_deg': initial['orientation_deg_mean'],
            'position_mm_max': initial['position_mm_max'],
            'orientation_deg_max': initial['orientation_deg_max'],
            'paper_position_mm': paper_initial['position_mm'],
            'paper_orientation_deg': paper_initial['orientation_deg'],
            'nominal_set': config.noise_set,
            'validation_postures': config.validation_postures,
            'unreachable_validation_postures': int(initial.get('unreachable', 0)),
        },
        'noise_free': noise_free,
        'noise': noise,
        'config': {
            **{
                key: (list(value) if isinstance(value, tuple) else value)
                for key, value in dataclasses.asdict(config).items()
            },
            'exact_geometry': exact_description,
            'validation': 'validate(true=exact, controller=calibrated) over random valid postures',
            'noise_model': 'N(0, angle level) on alpha, beta, phi; N(0, length level) on the six legs and d_m',
        },
        'tables_source': tables_source,
        'duration_s': time.perf_counter() - started,
    }
