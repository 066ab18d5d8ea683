"""Benchmark of the core (``gsp_bench``, ``make bench``): JSON on stdout and in ``results/bench.json``.

* ``identification``: median wall time of one identification (44 parameters, 60 selected postures,
  nominal set 2, the default formulation, Table 3's first noise level), and in the same run the
  same problem solved by ``scipy.optimize.least_squares(method='lm')`` with its finite-difference
  Jacobian on the noise-weighted FK-based residuals (FK of the measured legs under the parameters,
  predicted device readings) from the same start; ``speedup`` = scipy median / ours. Beside it,
  ``scipy_analytic_ms``: the peer a scipy user would write, ``least_squares(method='trf',
  tr_solver='lsmr')`` on the implicit residuals with the analytic sparse Jacobian
  (:func:`scipy_analytic_identification`); ``speedup_analytic`` = that median / ours.
* ``fk``: batched forward-kinematics throughput (postures per second).
* ``--profile``: no JSON; a cProfile summary of the ``identification`` case on stderr.
* ``identification.scaling``, ``selection`` and ``prediction``: see :mod:`.scale`
  (``--skip-scale`` leaves them out).

Other packages add sections by calling the benchmark: ``main(extra_sections={key: run})``, each
``run(quick=bool) -> dict`` giving the ``bench.json`` section ``key`` (``gsp_bench`` itself is
``gsp_bench.__main__``, which adds ``end_to_end``); each gets a ``--skip-<key>`` option. The core's
sections alone: ``python -m gsp_bench.core``. With ``--merge`` (the default) keys already in
``bench.json`` that this run does not produce are kept, so ``--only`` reruns some sections.
"""

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from gsp_kinematics.channels import PHI_READING_COLUMN
from gsp_kinematics.estimation._solver.readings import readings_jacobians
from gsp_kinematics.estimation.identification import DEFAULT_FORMULATION, identify, resolve_free
from gsp_kinematics.fileio import to_json, write_json
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import Geometry, parameter_errors
from gsp_kinematics.model.kinematics import (
    forward_kinematics_masked,
    inverse_kinematics,
    sample_valid_postures,
)
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.planning.selection import select_postures
from gsp_kinematics.rotation import wrap_angle

from .cli import experiment_parser, reexec_with_single_threaded_blas
from .nominal_sets import drawing_geometry, nominal_set
from .paper import add_noise, noise_from_levels


def build_problem(
    set_number=2, postures=60, pool_size=300, angle_noise_deg=0.001, length_noise_mm=0.001, seed=0
):
    """The benchmark problem: exact and nominal geometry, selected postures and noisy measurements."""
    exact = drawing_geometry()
    nominal = nominal_set(exact, set_number)
    rng = np.random.default_rng([seed, set_number])
    pool = sample_valid_postures(nominal, pool_size, rng)
    indices, _ = select_postures(nominal, pool, postures, DEFAULT_SENSOR_NOISE)
    poses = pool[indices]
    leg_lengths = inverse_kinematics(exact, poses)
    readings = device_readings(exact, poses)
    if angle_noise_deg or length_noise_mm:
        leg_lengths, readings = add_noise(
            leg_lengths,
            readings,
            angle_noise_deg,
            length_noise_mm,
            np.random.default_rng([seed, 99]),
        )
    sigmas = noise_from_levels(angle_noise_deg or 0.001, length_noise_mm or 0.001)
    return {
        'exact': exact,
        'nominal': nominal,
        'poses': poses,
        'leg_lengths': leg_lengths,
        'readings': readings,
        'sigmas': sigmas,
        'noise': {'angle_deg': angle_noise_deg, 'length_mm': length_noise_mm},
        'pool_size': pool_size,
        'nominal_set': set_number,
    }


def fk_residual_function(nominal, leg_lengths, readings, sigmas, pose_guesses, counters=None):
    """Weighted FK-based residuals ``(measured - predicted readings) / sigma`` of the 44-vector u.

    Every call runs FK from ``pose_guesses`` (a pure function of u, as finite differences need).
    A posture whose FK fails under u contributes zero residuals (its readings cannot be predicted),
    which is how the core's FK formulation leaves such postures out too. ``counters`` (a dict)
    counts ``calls`` and ``calls_with_fk_failures``.
    """
    weights = 1.0 / sigmas.readings()
    limits = nominal.limits
    counters = {} if counters is None else counters
    counters.setdefault('calls', 0)
    counters.setdefault('calls_with_fk_failures', 0)

    def residuals(u):
        geometry = Geometry.from_vector(u, limits)
        poses, converged = forward_kinematics_masked(geometry, leg_lengths, pose_guesses)
        difference = readings - device_readings(geometry, poses)
        difference[:, PHI_READING_COLUMN] = wrap_angle(difference[:, PHI_READING_COLUMN])
        difference[~converged] = 0.0
        counters['calls'] += 1
        counters['calls_with_fk_failures'] += int(not converged.all())
        return (difference * weights).ravel()

    return residuals


def scipy_fd_identification(nominal, leg_lengths, readings, sigmas, pose_guesses):
    """The baseline: ``least_squares(method='lm')`` with its finite-difference Jacobian on
    :func:`fk_residual_function`, from the nominal parameters. Returns ``(solution, counters)``."""
    counters = {}
    function = fk_residual_function(nominal, leg_lengths, readings, sigmas, pose_guesses, counters)
    return least_squares(function, nominal.to_vector(), method='lm'), counters


def scipy_analytic_identification(nominal, leg_lengths, readings, sigmas, pose_guesses):
    """The peer a scipy user would write: ``least_squares(method='trf', tr_solver='lsmr')`` on the
    implicit residuals (legs and device readings, every posture's pose unknown with the 44
    parameters) with the analytic Jacobian as a sparse matrix (each posture's rows touch the 44
    and its own 6 pose columns). Returns ``(solution, counters)``."""
    free = resolve_free(None)
    full = nominal.to_full_vector()
    count, size = len(pose_guesses), int(free.sum())
    weights = np.concatenate([np.full(6, 1.0 / sigmas.leg_lengths), 1.0 / sigmas.readings()])
    measured = np.concatenate([leg_lengths, readings], axis=1)
    # The sparsity pattern: row 10k + i holds the 44 columns and the pose columns of posture k.
    pose_columns = size + 6 * np.arange(count)[:, None] + np.arange(6)[None, :]
    columns = np.concatenate(
        [np.broadcast_to(np.arange(size), (count, size)), pose_columns], axis=1
    )[:, None, :].repeat(10, axis=1)
    rows = np.broadcast_to(np.arange(10 * count).reshape(count, 10, 1), columns.shape)
    shape = (10 * count, size + 6 * count)
    counters = {'calls': 0, 'jacobians': 0}
    cache = {}

    def evaluate(x):
        key = x.tobytes()
        if cache.get('key') != key:
            vector = full.copy()
            vector[free] = x[:size]
            geometry = Geometry.from_full_vector(vector, nominal.limits)
            cache.update(key=key, value=readings_jacobians(geometry, x[size:].reshape(count, 6)))
        return cache['value']

    def residuals(x):
        counters['calls'] += 1
        predicted = evaluate(x)[0]
        difference = predicted - measured
        difference[:, 8] = wrap_angle(difference[:, 8])
        return (difference * weights).ravel()

    def jacobian(x):
        counters['jacobians'] += 1
        _, d_pose, d_u = evaluate(x)
        data = np.concatenate([d_u[:, :, free], d_pose], axis=2) * weights[None, :, None]
        return csr_matrix((data.ravel(), (rows.ravel(), columns.ravel())), shape=shape)

    start = np.concatenate([full[free], np.asarray(pose_guesses, dtype=float).ravel()])
    solution = least_squares(
        residuals, start, jac=jacobian, method='trf', tr_solver='lsmr', x_scale='jac'
    )
    return solution, counters


def _median_ms(function, repeats, cpu=None):
    """Median wall time (ms) of ``repeats`` calls, all wall times, and the last value.

    ``cpu``, a list, receives the median process CPU time (ms): steadier on a loaded machine.
    """
    times, cpu_times, value = [], [], None
    for _ in range(repeats):
        started, started_cpu = time.perf_counter(), time.process_time()
        value = function()
        times.append(1000.0 * (time.perf_counter() - started))
        cpu_times.append(1000.0 * (time.process_time() - started_cpu))
    if cpu is not None:
        cpu.append(statistics.median(cpu_times))
    return statistics.median(times), times, value


def bench_identification(problem, repeats=7, scipy_repeats=3, formulation=DEFAULT_FORMULATION):
    nominal, exact = problem['nominal'], problem['exact']
    arguments = (nominal, problem['leg_lengths'], problem['readings'], problem['sigmas'])

    def ours():
        return identify(*arguments, formulation=formulation, pose_guesses=problem['poses'])

    ours()  # warm-up (imports, caches)
    cpu = []
    median_ms, times, result = _median_ms(ours, repeats, cpu)
    fk_median_ms, _, fk_result = _median_ms(
        lambda: identify(*arguments, formulation='fk', pose_guesses=problem['poses']),
        max(3, repeats // 2),
    )
    scipy_ms, scipy_times, (solution, counters) = _median_ms(
        lambda: scipy_fd_identification(*arguments, problem['poses']), scipy_repeats, cpu
    )
    scipy_geometry = Geometry.from_vector(solution.x, nominal.limits)
    analytic_ms, analytic_times, (analytic, analytic_counters) = _median_ms(
        lambda: scipy_analytic_identification(*arguments, problem['poses']), scipy_repeats, cpu
    )
    analytic_vector = nominal.to_full_vector()
    analytic_vector[resolve_free(None)] = analytic.x[: int(resolve_free(None).sum())]
    analytic_geometry = Geometry.from_full_vector(analytic_vector, nominal.limits)

    def max_error(geometry):
        return float(np.max(np.abs(parameter_errors(geometry, exact)[:43])))

    return {
        'postures': int(problem['poses'].shape[0]),
        'parameters': int(result.free.sum()),
        'formulation': result.formulation,
        'median_ms': median_ms,
        'scipy_fd_median_ms': scipy_ms,
        'speedup': scipy_ms / median_ms,
        'median_cpu_ms': cpu[0],
        'scipy_fd_median_cpu_ms': cpu[1],
        'speedup_cpu': cpu[1] / cpu[0],
        'repeats': repeats,
        'scipy_repeats': scipy_repeats,
        'times_ms': times,
        'scipy_times_ms': scipy_times,
        'iterations': int(result.iterations),
        'converged': bool(result.converged),
        'max_param_error_mm': max_error(result.geometry),
        'fk_formulation_median_ms': fk_median_ms,
        'fk_formulation_max_param_error_mm': max_error(fk_result.geometry),
        'fk_formulation_cost': float(fk_result.cost),
        'scipy_fd_cost': float(solution.cost),
        'scipy_fd_function_calls': counters['calls'],
        'scipy_fd_calls_with_fk_failures': counters['calls_with_fk_failures'],
        'scipy_fd_status': int(solution.status),
        'scipy_fd_max_param_error_mm': max_error(scipy_geometry),
        'scipy_analytic_ms': analytic_ms,
        'speedup_analytic': analytic_ms / median_ms,
        'scipy_analytic_cpu_ms': cpu[2],
        'speedup_analytic_cpu': cpu[2] / cpu[0],
        'scipy_analytic_times_ms': analytic_times,
        'scipy_analytic_cost': float(analytic.cost),
        'scipy_analytic_function_calls': analytic_counters['calls'],
        'scipy_analytic_status': int(analytic.status),
        'scipy_analytic_max_param_error_mm': max_error(analytic_geometry),
        'noise': problem['noise'],
        'nominal_set': problem['nominal_set'],
        'pool_size': problem['pool_size'],
    }


def profile_identification(problem, repeats=20, top=25, stream=None):
    """Print a cProfile summary of ``repeats`` identifications of ``problem`` (after a warm-up):
    the ``top`` functions by cumulative time, to ``stream`` (default stderr)."""
    import cProfile
    import pstats

    arguments = (problem['nominal'], problem['leg_lengths'], problem['readings'], problem['sigmas'])
    identify(*arguments, pose_guesses=problem['poses'])
    profiler = cProfile.Profile()
    profiler.enable()
    for _ in range(repeats):
        identify(*arguments, pose_guesses=problem['poses'])
    profiler.disable()
    stats = pstats.Stats(profiler, stream=stream or sys.stderr)
    stats.sort_stats('cumulative').print_stats(top)


def bench_fk(count=10000, repeats=5, seed=1):
    """FK of ``count`` postures from guesses perturbed by ~2 mm and ~0.2 deg (several Newton steps)."""
    exact = drawing_geometry()
    rng = np.random.default_rng(seed)
    poses = sample_valid_postures(exact, count, rng)
    leg_lengths = inverse_kinematics(exact, poses)
    perturbation = np.concatenate(
        [rng.normal(0.0, 0.002, (count, 3)), rng.normal(0.0, math.radians(0.2), (count, 3))], axis=1
    )
    guesses = poses + perturbation
    median_ms, _, (solved, converged) = _median_ms(
        lambda: forward_kinematics_masked(exact, leg_lengths, guesses), repeats
    )
    return {
        'postures': count,
        'postures_per_s': count / (median_ms / 1000.0),
        'median_ms': median_ms,
        'repeats': repeats,
        'converged_fraction': float(np.mean(converged)),
        'max_position_error_m': float(np.max(np.abs(solved[converged, :3] - poses[converged, :3]))),
        'guess_perturbation': {'position_mm': 2.0, 'angle_deg': 0.2},
    }


def scale_sections(identification, quick=False, log=print):
    """Adds ``scaling`` to the ``identification`` section; returns ``selection`` and
    ``prediction`` (:mod:`.scale`)."""
    from . import scale

    sizes = scale.SCALING_POSTURES[:2] if quick else scale.SCALING_POSTURES
    log(f'gsp_bench: identification scaling over {sizes} postures ...')
    identification['scaling'] = scale.identification_scaling(sizes)
    log('gsp_bench: posture selection from pools of 600 and 6000 ...')
    selection = scale.bench_selection(repeats=1 if quick else 3)
    log('gsp_bench: predicted against measured accuracy ...')
    prediction = scale.bench_prediction(seeds=4 if quick else 20)
    return {'selection': selection, 'prediction': prediction}


def run_extra_sections(extra_sections, skip=(), quick=False, log=print):
    """``{key: run(quick=quick)}`` of ``extra_sections`` not in ``skip``; a failure is recorded
    as ``{'error': ...}`` (another package's benchmark must not lose the core's sections)."""
    sections = {}
    for key, run in extra_sections.items():
        if key in skip:
            continue
        try:
            sections[key] = run(quick=quick)
        except Exception as error:  # noqa: BLE001 (recorded in the section)
            log(f'gsp_bench: section {key!r} failed: {error!r}')
            sections[key] = {'error': repr(error)}
    return sections


def skip_option(key):
    """The command-line option that skips section ``key`` (``end_to_end``: ``--skip-end-to-end``)."""
    return '--skip-' + key.replace('_', '-')


def merge_sections(path, sections, merge=True):
    """Write ``sections`` into the JSON file at ``path``, keeping its other keys when ``merge``."""
    path = Path(path)
    document = {}
    if merge and path.is_file():
        try:
            with open(path, encoding='utf-8') as stream:
                existing = json.load(stream)
            if isinstance(existing, dict):
                document = existing
        except (OSError, ValueError):
            document = {}
    document.update(sections)
    write_json(path, document)
    return document


def _parser(extra_sections):
    """The command line of ``gsp_bench`` with a skip option per extra section."""
    parser = experiment_parser(
        'gsp_bench', __doc__, 'results/bench.json', 'fewer repeats and postures (a smoke run)'
    )
    parser.add_argument(
        '--merge',
        action=argparse.BooleanOptionalAction,
        default=True,
        help='keep keys of an existing output file that this run does not produce (default on)',
    )
    parser.add_argument(
        '--repeats', type=int, default=7, help='timed identifications (>= 5; default 7)'
    )
    parser.add_argument(
        '--scipy-repeats', type=int, default=3, help='timed scipy solves (>= 3; default 3)'
    )
    parser.add_argument(
        '--fk-postures', type=int, default=10000, help='postures of the FK throughput test'
    )
    parser.add_argument(
        '--noise-free', action='store_true', help='noise-free data instead of Table 3 level 1'
    )
    parser.add_argument(
        '--skip-scale',
        action='store_true',
        help='skip identification.scaling, selection and prediction',
    )
    parser.add_argument(
        '--profile',
        action='store_true',
        help='print a cProfile summary of the standard identification to stderr and exit',
    )
    parser.add_argument(
        '--only',
        default=None,
        help='comma-separated sections to run (identification, fk, scale, '
        + ', '.join(extra_sections)
        + '); the others keep their values in the output file',
    )
    for key in extra_sections:
        parser.add_argument(
            skip_option(key),
            dest=f'skip_{key}',
            action='store_true',
            help=f'skip the {key} section',
        )
    return parser


def main(argv=None, extra_sections=None):
    """``gsp_bench``: the core's sections, then ``extra_sections`` (``{key: run(quick=bool)}``)."""
    if argv is None:
        reexec_with_single_threaded_blas()
    extra_sections = dict(extra_sections or {})
    parser = _parser(extra_sections)
    args = parser.parse_args(argv)
    repeats, scipy_repeats, fk_count = (
        max(5, args.repeats),
        max(3, args.scipy_repeats),
        args.fk_postures,
    )
    if args.quick:
        repeats, scipy_repeats, fk_count = 5, 3, min(fk_count, 2000)

    def log(text):
        print(text, file=sys.stderr, flush=True)

    only = None if args.only is None else {key.strip() for key in args.only.split(',')}
    unknown = (only or set()) - {'identification', 'fk', 'scale', *extra_sections}
    if unknown:
        parser.error(f'--only: unknown sections {sorted(unknown)}')

    def wanted(key):
        return only is None or key in only

    sections = {}
    if wanted('identification') or args.profile:
        log('gsp_bench: building the problem (nominal set 2, 60 selected postures) ...')
        noise = (0.0, 0.0) if args.noise_free else (0.001, 0.001)
        problem = build_problem(angle_noise_deg=noise[0], length_noise_mm=noise[1])
        if args.profile:
            profile_identification(problem)
            return 0
        log('gsp_bench: timing identification and the scipy baselines ...')
        sections['identification'] = bench_identification(problem, repeats, scipy_repeats)
        sections['identification']['blas_threads'] = os.environ.get(
            'OPENBLAS_NUM_THREADS', 'default'
        )
    if wanted('fk'):
        log('gsp_bench: timing batched FK ...')
        sections['fk'] = bench_fk(fk_count, repeats=5)
    # The scaling belongs to the identification section: run with it.
    if not args.skip_scale and wanted('scale') and 'identification' in sections:
        sections.update(scale_sections(sections['identification'], args.quick, log))
    skip = {key for key in extra_sections if getattr(args, f'skip_{key}') or not wanted(key)}
    sections.update(run_extra_sections(extra_sections, skip=skip, quick=args.quick, log=log))
    document = merge_sections(args.output, sections, merge=args.merge)
    sys.stdout.write(to_json(document))
    return 0


if __name__ == '__main__':
    sys.exit(main())
