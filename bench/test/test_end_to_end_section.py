"""Pure parts of gsp_bench.end_to_end (no processes started) and gsp_bench's wiring."""

import json
import random

import pytest

import gsp_bench.end_to_end

PLATFORM_REJECTION = {
    'posture': 2,
    'reason': 'rejected by the platform: singular',
    'rejected_by_platform': True,
}
NO_DROPS = {'leg_lengths': 0, 'inclinometer': 0, 'encoder': 0, 'lvdt': 0}


def _collection(skipped=(PLATFORM_REJECTION,), inconsistent=0, non_finite=None):
    return {
        'skipped': list(skipped),
        'inconsistent_dropped': inconsistent,
        'non_finite_dropped': dict(NO_DROPS, **(non_finite or {})),
    }


def _run(samples, collection=None, exit_code=0, where='result'):
    run = {'exit_code': exit_code, 'samples': samples, 'result': None, 'summary': None}
    if collection is not None:
        run[where] = {'collection': collection}
    return run


def test_environment_is_loopback_with_a_fresh_domain():
    env = gsp_bench.end_to_end.demo_environment(
        {'ROS_DOMAIN_ID': '7'}, rng=random.Random(0), used=range(1, 51)
    )
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 51 <= int(env['ROS_DOMAIN_ID']) <= 101
    assert env['PYTHONUNBUFFERED'] == '1' and env['OPENBLAS_NUM_THREADS'] == '1'
    assert (
        gsp_bench.end_to_end.demo_environment({'OPENBLAS_NUM_THREADS': '2'})['OPENBLAS_NUM_THREADS']
        == '2'
    )


def test_command_passes_rate_and_postures():
    argv = gsp_bench.end_to_end.demo_command('/tmp/x', 12, 400.0)
    assert argv[argv.index('--sensor-rate') + 1] == '400.0'
    assert argv[argv.index('--postures') + 1] == '12'
    assert argv[argv.index('--output-root') + 1] == '/tmp/x'


def test_the_run_directory_is_found_under_the_output_root_and_read(tmp_path):
    assert gsp_bench.end_to_end.find_run_directory(tmp_path / 'absent') is None
    assert gsp_bench.end_to_end.find_run_directory(tmp_path) is None
    run_directory = tmp_path / '20250101T120000Z'
    run_directory.mkdir()
    (tmp_path / 'stray.txt').write_text('not a run')
    assert gsp_bench.end_to_end.find_run_directory(tmp_path) == run_directory
    assert gsp_bench.end_to_end.read_run_directory(run_directory) == {
        'summary': None,
        'samples': None,
        'result': None,
        'sample_stamps': None,
    }
    (run_directory / 'samples.csv').write_text('posture,n_samples,stamp\n1,10,0.5\n3,9,0.7\n')
    (run_directory / 'summary.json').write_text(json.dumps({'calibration_s': 12.5}))
    (run_directory / 'result.json').write_text(json.dumps({'collection': _collection()}))
    read = gsp_bench.end_to_end.read_run_directory(run_directory)
    assert read['samples'] == [(1, 10), (3, 9)] and read['summary'] == {'calibration_s': 12.5}
    assert read['sample_stamps'] == [(1, 0.5), (3, 0.7)]
    assert read['result']['collection'] == _collection()


def test_collection_overhead_from_the_sample_stamps():
    # Postures 1..5 (4 rejected by the platform) one 0.0875 s cycle apart; minimum 0.02 + 10/200.
    stamps = [(p, 100.0 + 0.0875 * (p - 1)) for p in (1, 2, 3, 5)]
    overhead = gsp_bench.end_to_end.collection_overhead(stamps, 0.02, 10, 200.0)
    assert overhead['posture_cycle_s'] == pytest.approx(0.0875)
    assert overhead['overhead_ratio'] == pytest.approx(1.25)
    assert overhead['physical_minimum_s'] == pytest.approx(4 * 0.07)
    assert gsp_bench.end_to_end.collection_overhead([(1, 3.0)], 0.02) is None
    assert gsp_bench.end_to_end.collection_overhead(None, 0.02) is None
    argv = gsp_bench.end_to_end.demo_command('/tmp/x', 12, 400.0)
    assert argv[argv.index('--settle-time') + 1] == repr(gsp_bench.end_to_end.SETTLE_TIME_S)


def test_sync_check_passes_with_full_samples_and_platform_rejections():
    for where in ('result', 'summary'):  # the demo keeps a copy of the record in summary.json
        check = gsp_bench.end_to_end.sync_check(
            _run([(1, 10), (3, 10)], _collection(), where=where), 3
        )
        assert check['passed'] is True and check['postures_rejected_by_platform'] == 1
        assert check['dropped_samples'] == 0 and check['non_finite_dropped'] == 0


def test_sync_check_fails_on_drops_skips_short_rows_missing_postures_or_failure():
    full = [(1, 10), (3, 10)]
    dropped = gsp_bench.end_to_end.sync_check(_run(full, _collection(inconsistent=2)), 3)
    assert dropped['dropped_samples'] == 2 and dropped['passed'] is False
    non_finite = gsp_bench.end_to_end.sync_check(
        _run(full, _collection(non_finite={'encoder': 1})), 3
    )
    assert non_finite['non_finite_dropped'] == 1 and non_finite['passed'] is False
    other = dict(PLATFORM_REJECTION, reason='no synchronised sample', rejected_by_platform=False)
    skipped = gsp_bench.end_to_end.sync_check(_run(full, _collection(skipped=[other])), 3)
    assert skipped['postures_skipped_other'] == 1 and skipped['passed'] is False
    assert (
        gsp_bench.end_to_end.sync_check(_run([(1, 9), (3, 10)], _collection()), 3)['passed']
        is False
    )
    missing = gsp_bench.end_to_end.sync_check(_run([(1, 10)], _collection()), 3)
    assert missing['postures_missing'] == 1 and missing['passed'] is False
    assert (
        gsp_bench.end_to_end.sync_check(_run(full, _collection(), exit_code=1), 3)['passed']
        is False
    )


def test_sync_check_without_a_collection_record_is_unknown_not_a_crash():
    check = gsp_bench.end_to_end.sync_check(_run([(1, 10), (3, 10)]), 3)
    assert check['passed'] is None and check['dropped_samples'] is None
    assert check['postures_collected'] == 2 and check['postures_short'] == 0
    assert (
        gsp_bench.end_to_end.sync_check(_run([(1, 10), (3, 10)], exit_code=1), 3)['passed'] is False
    )


def test_gsp_bench_adds_the_end_to_end_section(monkeypatch):
    import gsp_bench.__main__

    calls = []
    monkeypatch.setattr(
        gsp_bench.__main__.core,
        'main',
        lambda argv, extra_sections: calls.append((argv, extra_sections)) or 0,
    )
    assert gsp_bench.__main__.main(['--skip-end-to-end']) == 0
    from gsp_bench import (
        collection_rate,
        effects,
        model_choice_cpu,
        noise_unknown,
        physics,
        platform_time,
        rigid_fold,
        run_to_requirement,
        run_to_requirement_levers,
        sensor_dynamics,
        sensor_errors,
        settle_ringing,
        upkeep,
        upkeep_realistic,
        verdict,
    )

    assert calls == [
        (
            ['--skip-end-to-end'],
            {
                'end_to_end': gsp_bench.end_to_end.run,
                'sensor_errors': sensor_errors.run,
                'noise_unknown': noise_unknown.run,
                'platform_time': platform_time.run,
                'sensor_dynamics': sensor_dynamics.run,
                'settle_ringing': settle_ringing.run,
                'collection_rate': collection_rate.run,
                'verdict': verdict.run,
                'upkeep': upkeep.run,
                'upkeep_realistic': upkeep_realistic.run,
                'effects': effects.run,
                'model_choice_cpu': model_choice_cpu.run,
                'rigid_fold': rigid_fold.run,
                'physics': physics.run,
                'run_to_requirement': run_to_requirement.run,
                'run_to_requirement_levers': run_to_requirement_levers.run,
            },
        )
    ]


def test_the_core_alone_simulates_the_truth_as_the_node_suite_does():
    # The shipped truth has sensor errors (leg gains, inclinometer zero); a simulation that left
    # them out while validating against them reported 0.45 mm instead of a few micrometres.
    core = gsp_bench.end_to_end.core_alone_validation(60, 20, seeds=1)
    assert core['postures'] == 60
    assert core['position_mm_mean'] < 0.02 and core['orientation_deg_mean'] < 0.002, core


def test_the_levers_section_measures_auto_as_the_effects_section_does():
    """The ``run_to_requirement_levers`` section's ``auto`` lever measures through the
    ``effects`` section's own ``measured`` (the calibrator's folds and corrections). It called a
    helper the effects section had since dropped, so ``make bench`` failed in that section
    while every test passed; one seed of the plan, no prefixes (about 10 s)."""
    import math

    from gsp_bench import run_to_requirement_levers

    runs = run_to_requirement_levers.auto_runs(0, budget=0.0)
    plan = runs['plan']
    assert 'failure' not in plan, plan
    assert set(plan['groups']) == {'compliance', 'backlash', 'thermal', 'joint_offsets'}, plan
    figures = plan['auto']
    # The realistic platform's auto plan: cross-validated and true errors of about 0.01 mm.
    assert 0.001 < figures['cv_mm'] < 0.05 and 0.001 < figures['true_mm'] < 0.05, figures
    assert math.isfinite(figures['bound_mm']) and figures['bound_mm'] >= figures['cv_mm']


def test_the_bench_runs_each_hardware_path_with_its_demo_options(tmp_path):
    assert gsp_bench.end_to_end.HARDWARE_PATHS == {
        'serial': ('--device', 'serial'),
        'ros2_control': ('--platform', 'ros2_control'),
    }
    argv = gsp_bench.end_to_end.demo_command(tmp_path, 30, 200.0, extra_args=('--device', 'serial'))
    assert argv[-2:] == ['--device', 'serial']


def test_a_demo_process_gives_its_exit_code_and_output_or_is_stopped_past_its_limit():
    """The one runner of the end-to-end and physics sections' demos: a child's exit code and
    output; one still running past the wall limit is stopped (SIGTERM), not waited for."""
    import sys

    from gsp_bench.end_to_end import run_demo_process

    quick = [sys.executable, '-c', 'print("calibrated"); raise SystemExit(3)']
    assert run_demo_process(quick, None, 60.0) == (3, 'calibrated\n')
    endless = [sys.executable, '-c', 'import time; time.sleep(600)']
    assert run_demo_process(endless, None, 0.5)[0] == -15  # SIGTERM
