"""Issue 17's scenario through the nodes and ``gsp_calibrate_client``: every device noise 3x the
defaults, the calibrator at its noise defaults (``noise_source: estimated``, default sigma_*).

platform_sim, device_driver and the calibrator spin in one process (``test_calibrator_node``'s
suite); the client runs as the user runs it, in this thread, and prints the progress and summary.
"""

import io
import json

import numpy as np
import pytest
from rclpy.parameter import Parameter
from test_calibrator_node import CALL_TIMEOUT_S, make_suite, perturbed_truth

from gsp_calibrator.report.data import validation_errors
from gsp_calibrator.run.directory import RunDirectory
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.tools import client
from gsp_calibrator.tools import reidentify as offline
from gsp_kinematics.kinematics import sample_valid_postures
from gsp_kinematics.sensors.noise import DEFAULT_SENSOR_NOISE, NOISE_FIELDS
from gsp_msgs_py import names

FACTOR = 3.0


def test_noise_3x_unconfigured_is_estimated_accepted_applied_and_validated(ros_context, tmp_path):
    truth = perturbed_truth(tmp_path / 'true.yaml')
    device_noise = [
        Parameter(f'{name}_noise_std', value=FACTOR * getattr(DEFAULT_SENSOR_NOISE, name))
        for name in ('inclinometer', 'encoder', 'lvdt')
    ]
    suite, _, platform, _ = make_suite(
        ros_context,
        tmp_path,
        tmp_path / 'true.yaml',
        # More postures than the other in-process tests: the estimate needs redundancy. A right
        # model is still rejected 1 run in 100 (the F test's level): that is the test's risk.
        {'posture_count': 24, 'pool_size': 240, 'apply_result': True, 'apply_rejected_fit': False},
        platform_overrides=[
            Parameter('leg_noise_std', value=FACTOR * DEFAULT_SENSOR_NOISE.leg_lengths)
        ],
        device_overrides=device_noise,
    )
    out, err = io.StringIO(), io.StringIO()
    try:
        args = client.build_parser().parse_args(
            ['--wait-timeout', '30', '--timeout', str(CALL_TIMEOUT_S)]
        )
        code = client.run(args, context=ros_context, out=out, err=err)
        assert code == client.EXIT_OK, out.getvalue() + err.getvalue()
        # The last progress line and the summary agree: done, succeeded.
        progress = [line for line in err.getvalue().splitlines() if line.startswith('[')]
        assert f'] 24/24 {names.PHASE_DONE}' in progress[-1], progress[-1]
        assert 'calibration succeeded' in progress[-1]
        parsed = parse_response(out.getvalue())
        run = RunDirectory(parsed.run_directory)
        calibrated = run.read_geometry()
        applied = platform.get_parameter('geometry.leg_offsets').value
        np.testing.assert_allclose(applied, calibrated.leg_offsets, rtol=0, atol=1e-15)
        data = json.loads((run.path / 'result.json').read_text())
        assert data['noise_source'] == 'estimated' and data['fit_accepted'] is True
        assert data['goodness_of_fit']['test'] == 'lack_of_fit'
        assert data['outliers'] == []
        for name in NOISE_FIELDS:
            entry = data['noise_estimates'][name]
            # 24 postures of 5 samples: the encoder's 96 within-posture dof give ~7 % (1 sd).
            true_noise = FACTOR * getattr(DEFAULT_SENSOR_NOISE, name)
            assert entry['estimated'] == pytest.approx(true_noise, rel=0.3), name
            assert entry['configured'] == getattr(DEFAULT_SENSOR_NOISE, name)
    finally:
        suite.close()
    # Validation against the truth, as gsp_demo does it: measured over predicted accuracy.
    poses = sample_valid_postures(truth, 50, np.random.default_rng(11))
    offline.refresh_report(
        run.path,
        truth=truth,
        validation_after=validation_errors(truth, calibrated, poses),
        plots=False,
    )
    refreshed = json.loads((run.path / 'result.json').read_text())
    assert refreshed['fit_accepted'] is True and refreshed['noise_source'] == 'estimated'
    ratio = refreshed['predicted_accuracy']['validation']['position_ratio']
    # One run of 8 parameters: its error along a few directions scatters like chi with few
    # degrees of freedom around the prediction; the 1.3x target is the bench's mean over seeds.
    assert ratio <= 2.5, ratio
