"""The main job end to end: ``gsp_demo`` starts the three nodes as processes, calibrates,
applies, validates, and leaves nothing running."""

import json
import re
import time
from pathlib import Path

import numpy as np
import pytest
from gsp_testing import marked_environment, marked_processes, run_demo, wait_until

from gsp_calibrator.report.data import VALIDATION_KEYS
from gsp_kinematics.model.geometry import load_geometry, parameter_errors

#: Keys every summary.json has (the demo writes more: the run directory, the fit, ...).
SUMMARY_KEYS = {'validation', 'max_param_error_mm', 'max_param_error_deg'} | {
    'identification_ms',
    'calibration_s',
    'total_s',
}


#: Postures the run selects (the default is 60).
POSTURES = 30


def test_main_job_calibrates_and_improves_accuracy(tmp_path):
    env, marker = marked_environment()
    # The demo keeps this run's ROS_DOMAIN_ID (make test sets one): a domain the demo drew at
    # random (test_demo covers the draw) could be another concurrent run's. 30 postures, half
    # the default (test_defaults_apply runs the defaults): what this test checks does not
    # depend on the count, and the calibrated errors stay 5x inside its bounds.
    started = time.monotonic()
    completed, output = run_demo(
        ['--output-root', str(tmp_path / 'runs')]
        + ['--postures', str(POSTURES), '--validation-postures', '30'],
        env,
    )
    elapsed = time.monotonic() - started
    assert completed.returncode == 0, output

    # No node is left behind.
    # (a child the demo stopped may take a moment to be reaped; the wait only bounds a failure)
    wait_until(lambda: not marked_processes(marker), 30.0)
    assert marked_processes(marker) == [], output

    assert re.search(r'ROS_DOMAIN_ID=\d+ \(loopback only\)', output)
    # Progress shown: the selected postures and the default auto's reference revisit.
    assert f'[done] {POSTURES + 1}/{POSTURES + 1}' in output
    run = Path(re.findall(r'^run directory: (.+)$', completed.stdout, re.MULTILINE)[-1])
    assert run.parent == tmp_path / 'runs' and run.is_dir()
    for name in (
        'samples.csv',
        'result.yaml',
        'true_geometry.yaml',
        'summary.json',
        'calibrator.log',
        'platform_sim.log',
        'device_driver.log',
    ):
        assert (run / name).is_file(), name

    summary = json.loads((run / 'summary.json').read_text())
    assert SUMMARY_KEYS <= set(summary)
    # The calibrator's collection record (result.json 'collection', copied by the demo).
    collection = summary['collection']
    assert set(collection) == {
        'skipped',
        'inconsistent_dropped',
        'settling_dropped',
        'non_finite_dropped',
        'replacements',
        'settle',
        'processing_lag',
        'route_additions',
    }
    # auto (the default): the route revisits its first posture at the end (thermal growth).
    assert collection['route_additions']['reference_revisits'] == 1
    assert collection['settle']['rows'] >= 1 and collection['settle']['max_s'] >= 0.0
    # Each posture the platform rejected was replaced (the pool of 600 has plenty left).
    rejected = {s['posture'] for s in collection['skipped'] if s['rejected_by_platform']}
    assert {r['rejected'] for r in collection['replacements']} == rejected
    assert set(collection['non_finite_dropped']) == {
        'leg_lengths',
        'inclinometer',
        'encoder',
        'lvdt',
    }
    before, after = summary['validation']['before'], summary['validation']['after']
    assert set(before) == set(after) == set(VALIDATION_KEYS)
    # Accuracy improves by orders of magnitude (nominal: mm; calibrated: micrometres).
    assert after['position_mm_mean'] < 0.1 * before['position_mm_mean']
    assert after['position_mm_max'] < 0.05
    assert after['orientation_deg_max'] < 0.01 < before['orientation_deg_max']
    assert summary['identification_ms'] > 0 and summary['calibration_s'] > 0
    assert summary['total_s'] <= elapsed

    # The calibrated geometry is close to the truth the simulator was given.
    calibrated = load_geometry(run / 'result.yaml')
    truth = load_geometry(run / 'true_geometry.yaml')
    errors = parameter_errors(calibrated, truth)
    assert np.max(np.abs(errors[:43])) < 0.05 and abs(errors[43]) < 0.005  # mm, deg
    assert summary['max_param_error_mm'] == pytest.approx(np.max(np.abs(errors[:43])))
    rows = (run / 'samples.csv').read_text().strip().splitlines()
    assert POSTURES - 4 <= len(rows) - 1 <= POSTURES + 1

    # The report against the truth, with its plots: the demo draws them once it has validated
    # (its calibrator runs with write_report_plots false).
    report = (run / 'report.md').read_text(encoding='utf-8')
    assert 'Errors against the true geometry' in report and '## Validation' in report
    for name in ('parameter_errors', 'chain_errors', 'residuals', 'validation', 'accuracy_map'):
        assert f']({name}.png)' in report and (run / f'{name}.png').stat().st_size > 10_000, name
