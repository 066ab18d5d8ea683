"""End-to-end section of ``gsp_bench`` (``bench.json`` key ``end_to_end``; see :mod:`.__main__`).

:func:`run` drives ``gsp_demo`` (the three nodes as separate processes, loopback discovery, a
private random ``ROS_DOMAIN_ID`` per run) in child processes, each with a temporary
``--output-root``, and reads the files of the one run directory it leaves there (never the log
text):

* ``calibration_s``: wall time of the ``/gsp/calibrator/calibrate`` call of a whole calibration
  (60 postures; fewer with ``quick``), from ``summary.json``; ``total_s`` is the whole demo.
* ``max_sync_rate_hz``: the highest ``publish_rate`` of ``platform_sim`` and ``device_driver``
  (``--sensor-rate``) at which a short calibration still gets every synchronised sample: the
  demo succeeds, every posture not rejected by the platform has a ``samples.csv`` row with
  ``n_samples == pairs_per_posture``, and the calibrator's ``collection`` record (in
  ``result.json``, or copied by the demo into ``summary.json``) shows no dropped (inconsistent or
  non-finite) sample and no posture skipped for another reason than a platform rejection. Without
  that record (an older calibrator) the counts are unknown (None) and so is ``passed``.
  The rates are tried in increasing order; the sweep stops at the first one that does not pass.
"""

import contextlib
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gsp_calibrator.files.run_directory import SAMPLES_FILE, SUMMARY_FILE
from gsp_calibrator.report.write import RESULT_JSON
from gsp_calibrator.settings import DEFAULTS
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_msgs_py.ros_environment import loopback_environment

DEMO_MODULE = 'gsp_calibrator.tools.demo'
CALIBRATION_POSTURES = 60
QUICK_CALIBRATION_POSTURES = 30
SYNC_RATES_HZ = (100.0, 200.0, 400.0, 800.0, 1600.0)
QUICK_SYNC_RATES_HZ = (200.0, 800.0)
SYNC_POSTURES = 15
QUICK_SYNC_POSTURES = 12  #: 44 parameters need >= 11 postures (4 readings each)
PAIRS_PER_POSTURE = 10
DEMO_TIMEOUT_S = 90.0  #: longest wall time of one demo run before it is stopped
SETTLE_TIME_S = 0.02  #: platform_sim's settle time in every demo run (the demo's default)


def demo_environment(environ=None, rng=None, used=()):
    """A copy of ``environ`` with loopback discovery and a fresh random domain id, not in ``used``.

    The domain of ``environ`` is not kept: each demo gets its own, so that a run cannot hear a
    previous one's nodes still shutting down.
    """
    env = dict(os.environ if environ is None else environ)
    env.pop('ROS_DOMAIN_ID', None)
    env = loopback_environment(env, rng=rng, exclude=used)
    env['PYTHONUNBUFFERED'] = '1'
    env.setdefault('OPENBLAS_NUM_THREADS', '1')
    return env


def demo_command(
    output_root,
    postures,
    sensor_rate,
    pairs_per_posture=PAIRS_PER_POSTURE,
    validation_postures=1,
    seed=0,
    timeout=DEMO_TIMEOUT_S,
    settle_time=SETTLE_TIME_S,
    extra_args=(),
):
    """argv of one demo run (``gsp_demo`` from PATH, else ``python -m gsp_calibrator.tools.demo``);
    ``extra_args`` are appended (e.g. ``['--platform', 'ros2_control']``)."""
    executable = shutil.which('gsp_demo')
    prefix = [executable] if executable else [sys.executable, '-m', DEMO_MODULE]
    return prefix + [
        '--output-root',
        str(output_root),
        '--postures',
        str(int(postures)),
        '--pairs-per-posture',
        str(int(pairs_per_posture)),
        '--validation-postures',
        str(int(validation_postures)),
        '--sensor-rate',
        repr(float(sensor_rate)),
        '--seed',
        str(int(seed)),
        '--timeout',
        repr(float(timeout)),
        '--settle-time',
        repr(float(settle_time)),
        *extra_args,
    ]


def _stop(process):
    """SIGTERM the demo (it stops its nodes), then SIGKILL its process group."""
    if process.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        process.send_signal(signal.SIGTERM)
    try:
        process.wait(timeout=20.0)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=5.0)


def run_demo_process(argv, env, wall_limit_s):
    """Run a demo's ``argv`` in a session of its own: ``(exit code, its output as text)``;
    stopped (:func:`_stop`) after ``wall_limit_s`` or when this process is interrupted."""
    process = subprocess.Popen(
        argv,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        output, _ = process.communicate(timeout=wall_limit_s)
    except subprocess.TimeoutExpired:
        _stop(process)
        output, _ = process.communicate()
    except BaseException:
        _stop(process)
        raise
    return process.returncode, output.decode(errors='replace')


def run_demo(postures, sensor_rate, used_domains=(), **options):
    """One demo run in a child process; ``{'exit_code', 'wall_s', 'domain_id', 'run_directory',
    'summary', 'samples', 'result', 'output'}`` (the files read before the temporary output root
    is removed; missing ones None). ``options``: the other keywords of :func:`demo_command`."""
    timeout = options.get('timeout', DEMO_TIMEOUT_S)
    env = demo_environment(used=used_domains)
    output_root = Path(tempfile.mkdtemp(prefix='gsp_bench_e2e_'))
    argv = demo_command(output_root, postures, sensor_rate, **options)
    started = time.monotonic()
    try:
        exit_code, output = run_demo_process(argv, env, timeout + 60.0)
        result = {
            'exit_code': exit_code,
            'wall_s': time.monotonic() - started,
            'domain_id': int(env['ROS_DOMAIN_ID']),
            'output': output,
            'run_directory': None,
            'summary': None,
            'samples': None,
            'result': None,
        }
        directory = find_run_directory(output_root)
        if directory is not None:
            result['run_directory'] = str(directory)
            result.update(read_run_directory(directory))
        return result
    finally:
        shutil.rmtree(output_root, ignore_errors=True)


def find_run_directory(output_root):
    """The run directory the demo left under its own ``output_root`` (None if there is none).

    The calibrator names it by UTC timestamp; one demo makes one, so the latest is the one.
    """
    with contextlib.suppress(OSError):
        directories = sorted(path for path in Path(output_root).iterdir() if path.is_dir())
        if directories:
            return directories[-1]
    return None


def read_run_directory(directory):
    """``{'summary', 'samples', 'result'}`` of a demo run directory (None where missing):
    ``summary.json`` and ``result.json`` as dicts, ``samples.csv`` as ``[(posture, n_samples)]``
    and ``sample_stamps`` ``[(posture, mean stamp in s)]``."""
    directory = Path(directory)
    read = {'summary': None, 'samples': None, 'result': None, 'sample_stamps': None}
    for key, name in (('summary', SUMMARY_FILE), ('result', RESULT_JSON)):
        with contextlib.suppress(OSError, ValueError):
            read[key] = json.loads((directory / name).read_text())
    with contextlib.suppress(OSError, ValueError, KeyError):
        with open(directory / SAMPLES_FILE, newline='') as stream:
            rows = list(csv.DictReader(stream))
        read['samples'] = [(int(row['posture']), int(row['n_samples'])) for row in rows]
        read['sample_stamps'] = [(int(row['posture']), float(row['stamp'])) for row in rows]
    return read


def collection_record(run):
    """The calibrator's ``collection`` record of ``run``: from ``result.json``, else the copy the
    demo keeps in ``summary.json``; None when neither has one (an older calibrator)."""
    for document in (run.get('result'), run.get('summary')):
        record = (document or {}).get('collection')
        if isinstance(record, dict):
            return record
    return None


def collection_overhead(
    sample_stamps, settle_s, pairs_per_posture=PAIRS_PER_POSTURE, sensor_rate_hz=200.0
):
    """The collection's time per posture against its physical minimum, from ``samples.csv``.

    Each row's stamp is the mean stamp of its samples, so consecutive rows are one posture cycle
    apart (command, motion, settle, sampling, bookkeeping); the cycle is the slope of the stamps
    over the posture numbers (postures the platform rejected leave gaps, not errors). The minimum
    is ``settle + samples / rate``. ``overhead_ratio`` = cycle / minimum: the collection phase
    over ``postures x (settle + samples / rate)``. None with fewer than two rows.
    """
    if not sample_stamps or len(sample_stamps) < 2:
        return None
    postures, stamps = (list(column) for column in zip(*sorted(sample_stamps), strict=True))
    span = postures[-1] - postures[0]
    if span <= 0:
        return None
    cycle_s = (stamps[-1] - stamps[0]) / span
    minimum_s = settle_s + pairs_per_posture / sensor_rate_hz
    return {
        'posture_cycle_s': cycle_s,
        'physical_minimum_per_posture_s': minimum_s,
        'collection_s': cycle_s * len(postures),
        'physical_minimum_s': minimum_s * len(postures),
        'overhead_ratio': cycle_s / minimum_s,
        'settle_s': settle_s,
    }


def sync_check(run, postures, pairs_per_posture=PAIRS_PER_POSTURE):
    """Whether ``run`` (of :func:`run_demo`) got every synchronised sample, and its counts.

    ``passed`` is None (and so are the counts from the ``collection`` record) when the run
    succeeded but says nothing about skipped postures and dropped samples.
    """
    samples = run.get('samples') or []
    short = [p for p, n in samples if n != pairs_per_posture]
    collected = {p for p, _ in samples}
    check = {
        'passed': False,
        'exit_code': run.get('exit_code'),
        'postures_collected': len(samples),
        'postures_short': len(short),
        'min_n_samples': min((n for _, n in samples), default=0),
        'postures_rejected_by_platform': None,
        'postures_missing': None,
        'postures_skipped_other': None,
        'dropped_samples': None,
        'non_finite_dropped': None,
    }
    failed = run.get('exit_code') != 0 or not samples or bool(short)
    record = collection_record(run)
    if record is None:
        check['passed'] = False if failed else None
        return check
    skipped = record.get('skipped') or []
    rejected = {int(entry['posture']) for entry in skipped if entry.get('rejected_by_platform')}
    other_skips = [
        int(entry['posture']) for entry in skipped if not entry.get('rejected_by_platform')
    ]
    missing = sorted(set(range(1, postures + 1)) - collected - rejected)
    dropped = int(record.get('inconsistent_dropped') or 0)
    non_finite = sum(int(n) for n in (record.get('non_finite_dropped') or {}).values())
    check.update(
        {
            'passed': not (failed or missing or other_skips or dropped or non_finite),
            'postures_rejected_by_platform': len(rejected),
            'postures_missing': len(missing),
            'postures_skipped_other': len(other_skips),
            'dropped_samples': dropped,
            'non_finite_dropped': non_finite,
        }
    )
    return check


#: Validation postures of the timed calibration run (the validation is not part of calibration_s).
VALIDATION_POSTURES = {False: 50, True: 10}


def core_alone_validation(postures, validation_postures, seeds=5, seed=0):
    """What the core alone reaches on the node suite's noise: same geometry files, same posture
    selection, same free parameters, Table 3's first level averaged over ``PAIRS_PER_POSTURE``
    pairs per posture (as the calibrator does), then validated like the demo. The truth is
    simulated as ``platform_sim`` and the ``sim`` device do, its sensor errors included. Means
    over ``seeds`` noise draws."""
    import numpy as np

    from gsp_calibrator.run.postures import DEFAULT_FREE, choose_postures
    from gsp_kinematics.estimation.identification import identify, resolve_free
    from gsp_kinematics.model.device import device_readings
    from gsp_kinematics.model.geometry import default_geometry
    from gsp_kinematics.model.kinematics import (
        forward_kinematics_masked,
        inverse_kinematics,
        sample_valid_postures,
    )
    from gsp_kinematics.model.validation import validate

    true, nominal = default_geometry('true'), default_geometry('nominal')
    averaged = DEFAULT_SENSOR_NOISE.averaged(np.full(postures, PAIRS_PER_POSTURE))
    poses = choose_postures(nominal, postures, DEFAULTS['pool_size'], seed, averaged).poses
    # As in the node suite: the controller drives the legs to the nominal IK's sensor readings,
    # the real platform settles at FK of its true articular variables (postures it cannot reach
    # are skipped) and the real device reads it with its own sensor errors.
    legs = nominal.sensors.leg_readings(inverse_kinematics(nominal, poses))
    reached, ok = forward_kinematics_masked(true, true.sensors.true_leg_lengths(legs), poses)
    poses, legs, reached = poses[ok], legs[ok], reached[ok]
    exact_readings = true.sensors.device_readings(device_readings(true, reached))
    validation = sample_valid_postures(
        nominal, validation_postures, np.random.default_rng(seed + 1_000_003)
    )
    free = resolve_free(DEFAULT_FREE)
    position, orientation = [], []
    for draw in range(seeds):
        rng = np.random.default_rng(10_000 + draw)
        measured_legs = legs + rng.normal(0.0, averaged.leg_lengths, legs.shape)
        readings = exact_readings + rng.normal(0.0, 1.0, (len(legs), 4)) * averaged.readings()
        result = identify(nominal, measured_legs, readings, averaged, free=free, pose_guesses=poses)
        errors = validate(true, result.geometry, validation)
        position.append(errors['position_mm_mean'])
        orientation.append(errors['orientation_deg_mean'])
    return {
        'position_mm_mean': float(np.mean(position)),
        'orientation_deg_mean': float(np.mean(orientation)),
        'postures': int(len(legs)),
        'seeds': seeds,
    }


#: The hardware paths run like the direct calibration (``gsp_demo`` options).
HARDWARE_PATHS = {
    'serial': ('--device', 'serial'),
    'ros2_control': ('--platform', 'ros2_control'),
}


def hardware_path_run(postures, validation_postures, extra_args, direct_after, used):
    """One calibration through a hardware path (emulated device on a pty, or the ros2_control
    bridge), laid out like the direct run, with its ratio to the direct run's validation."""
    run = run_demo(
        postures,
        200.0,
        validation_postures=validation_postures,
        used_domains=used,
        extra_args=extra_args,
        timeout=2 * DEMO_TIMEOUT_S,  # the emulated legs take time to move
    )
    used.append(run['domain_id'])
    summary = run['summary'] or {}
    after = (summary.get('validation') or {}).get('after') or {}
    result = {
        'calibration_s': summary.get('calibration_s'),
        'postures': postures,
        'postures_collected': len(run['samples'] or []),
        'max_param_error_mm': summary.get('max_param_error_mm'),
        'validation_after': {
            key: after.get(key) for key in ('position_mm_mean', 'orientation_deg_mean')
        },
    }
    direct = (direct_after or {}).get('position_mm_mean')
    if after.get('position_mm_mean') is not None and direct:
        result['position_ratio_to_direct'] = after['position_mm_mean'] / direct
    if run['exit_code'] != 0:
        result['calibration_error'] = (
            f'gsp_demo exited with {run["exit_code"]}: ' + run['output'][-800:]
        )
    return result


def run(quick=False, log=None):
    """The section: ``{'calibration_s', 'postures', 'max_sync_rate_hz', ...}``."""
    if log is None:

        def log(message):
            print(message, file=sys.stderr, flush=True)

    used = []
    postures = QUICK_CALIBRATION_POSTURES if quick else CALIBRATION_POSTURES
    log(f'gsp_bench: end_to_end: {postures}-posture calibration through the nodes ...')
    calibration = run_demo(
        postures, 200.0, validation_postures=VALIDATION_POSTURES[quick], used_domains=used
    )
    used.append(calibration['domain_id'])
    summary = calibration['summary'] or {}
    section = {
        'calibration_s': summary.get('calibration_s'),
        'postures': postures,
        'postures_collected': len(calibration['samples'] or []),
        'pairs_per_posture': PAIRS_PER_POSTURE,
        'sensor_rate_hz': 200.0,
        'identification_ms': summary.get('identification_ms'),
        'demo_total_s': summary.get('total_s'),
        'max_param_error_mm': summary.get('max_param_error_mm'),
    }
    overhead = collection_overhead(
        calibration.get('sample_stamps'), SETTLE_TIME_S, PAIRS_PER_POSTURE, 200.0
    )
    if overhead is not None:
        section['overhead_ratio'] = overhead['overhead_ratio']
        section['collection'] = overhead
    after = (summary.get('validation') or {}).get('after') or {}
    if after.get('position_mm_mean') is not None:
        log('gsp_bench: end_to_end: the core alone on the same noise ...')
        core = core_alone_validation(postures, VALIDATION_POSTURES[quick], seeds=2 if quick else 5)
        section['validation_after'] = {
            key: after.get(key) for key in ('position_mm_mean', 'orientation_deg_mean')
        }
        section['core_alone'] = core
        section['position_ratio_to_core'] = after['position_mm_mean'] / core['position_mm_mean']
    if calibration['exit_code'] != 0:
        section['calibration_error'] = (
            f'gsp_demo exited with {calibration["exit_code"]}: ' + calibration['output'][-800:]
        )

    for mode, extra_args in HARDWARE_PATHS.items():
        log(f'gsp_bench: end_to_end: {postures}-posture calibration through the {mode} path ...')
        section[mode] = hardware_path_run(
            postures, VALIDATION_POSTURES[quick], extra_args, after, used
        )

    rates = QUICK_SYNC_RATES_HZ if quick else SYNC_RATES_HZ
    sync_postures = QUICK_SYNC_POSTURES if quick else SYNC_POSTURES
    best, details = None, {}
    for rate in rates:
        log(f'gsp_bench: end_to_end: {sync_postures} postures at {rate:g} Hz ...')
        attempt = run_demo(sync_postures, rate, used_domains=used)
        used.append(attempt['domain_id'])
        check = sync_check(attempt, sync_postures)
        check['calibration_s'] = (attempt['summary'] or {}).get('calibration_s')
        check['wall_s'] = round(attempt['wall_s'], 3)
        if attempt['exit_code'] != 0:
            check['output_tail'] = attempt['output'][-600:]
        details[f'{rate:g}'] = check
        if check['passed'] is not True:  # failed, or unknown: the rate is not established
            break
        best = rate
    section.update(
        {
            'max_sync_rate_hz': best,
            'sync_rates_tried_hz': [float(r) for r in rates if f'{r:g}' in details],
            'sync_postures': sync_postures,
            'sync_by_rate': details,
        }
    )
    return section


if __name__ == '__main__':
    print(json.dumps(run(quick='--quick' in sys.argv[1:]), indent=2))
