"""Pure parts of gsp_calibrator.bench_end_to_end (no processes started)."""

import random

from gsp_calibrator import bench_end_to_end as bench

LOG_OK = '[WARN] [1.0] [calibrator]: posture 2/3 skipped: rejected by the platform: singular\n'


def _run(samples, log=LOG_OK, exit_code=0):
    return {'exit_code': exit_code, 'samples': samples, 'calibrator_log': log}


def test_environment_is_loopback_with_a_fresh_domain():
    env = bench.demo_environment({'ROS_DOMAIN_ID': '7'}, rng=random.Random(0), used=range(1, 101))
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert env['ROS_DOMAIN_ID'] == '101'


def test_command_passes_rate_and_postures():
    argv = bench.demo_command('/tmp/x', 12, 400.0)
    assert argv[argv.index('--sensor-rate') + 1] == '400.0'
    assert argv[argv.index('--postures') + 1] == '12'
    assert argv[argv.index('--output-root') + 1] == '/tmp/x'


def test_sync_check_passes_with_full_samples_and_platform_rejections():
    check = bench.sync_check(_run([(1, 10), (3, 10)]), 3)
    assert check['passed'] and check['postures_rejected_by_platform'] == 1


def test_sync_check_fails_on_drops_short_rows_missing_postures_or_failure():
    dropped = LOG_OK + 'posture 1/3: dropped 2 synchronised sample(s) inconsistent\n'
    assert bench.sync_check(_run([(1, 10), (3, 10)], dropped), 3)['dropped_samples'] == 2
    assert not bench.sync_check(_run([(1, 10), (3, 10)], dropped), 3)['passed']
    assert not bench.sync_check(_run([(1, 9), (3, 10)]), 3)['passed']
    assert not bench.sync_check(_run([(1, 10)]), 3)['passed']
    assert not bench.sync_check(_run([(1, 10), (3, 10)], exit_code=1), 3)['passed']
