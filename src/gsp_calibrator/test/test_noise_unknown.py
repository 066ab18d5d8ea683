"""Issue 17's scenario through the nodes and ``gsp_calibrate_client``: every device noise 3x the
defaults, the calibrator at its noise defaults (``noise_source: estimated``, default sigma_*).

platform_sim, device_driver and the calibrator spin in one process (``test_calibrator_node``'s
suite); the client runs as the user runs it, in this thread, and prints the progress and summary.
"""

import io
import json

import numpy as np
import pytest
from calibrator_suite import CALL_TIMEOUT_S, make_suite, perturbed_truth
from rclpy.parameter import Parameter

from gsp_calibrator.collection.synchroniser import SampleCollector, seconds_to_ns
from gsp_calibrator.files.run_directory import Rows, RunDirectory
from gsp_calibrator.recording import rebuild
from gsp_calibrator.report.data import validation_errors
from gsp_calibrator.run.identify import identify_from_samples
from gsp_calibrator.run.postures import choose_postures
from gsp_calibrator.run.response import outcome_summary, parse_response
from gsp_calibrator.tools import client
from gsp_calibrator.tools.reidentify import refresh_report
from gsp_kinematics.estimation.noise_estimate import ar1_std_of_mean
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, NOISE_FIELDS
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
        {'posture_count': 24, 'pool_size': 240, 'apply_result': True},
        platform_overrides=[
            Parameter('leg_lengths_noise_std', value=FACTOR * DEFAULT_SENSOR_NOISE.leg_lengths)
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
    refresh_report(
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


def test_correlated_inclinometer_noise_through_the_nodes_is_accepted(ros_context, tmp_path):
    """The device's inclinometer noise is correlated over 0.03 s (a real part's filtered output);
    1.5 s windows (150 samples at 100 Hz, about 25 effective): the effective sample count gives
    the inclinometer's row noise within postures, it agrees with the between-posture residuals
    (the noise of the averaged rows, whatever the timers' jitter did to the correlation), the
    fit is accepted, and the run directory (samples.csv) and its recording carry what the
    estimate came from."""
    samples = 150
    perturbed_truth(tmp_path / 'true.yaml')
    suite, _, _, _ = make_suite(
        ros_context,
        tmp_path,
        tmp_path / 'true.yaml',
        {'posture_count': 16, 'pool_size': 160, 'pairs_per_posture': samples},
        # Not 0.05 s (15 effective): a CI run under load estimated 9.5 there, below the 10 under
        # which the estimate is only a lower bound (noise_estimate.MIN_N_EFF).
        device_overrides=[Parameter('inclinometer_noise_correlation_time', value=0.03)],
    )
    try:
        response = suite.wait(suite.call())
    finally:
        suite.close()
    assert response.success, response.message
    run = RunDirectory(parse_response(response.message).run_directory)
    data = json.loads((run.path / 'result.json').read_text())
    assert data['noise_source'] == 'estimated' and data['fit_accepted'] is True, data[
        'fit_diagnosis'
    ]
    assert data['goodness_of_fit']['test'] == 'lack_of_fit'
    inclinometer = data['noise_estimates']['inclinometer']
    assert not inclinometer['within_lower_bound'] and inclinometer['source'] == 'pooled'
    # The white formula s / sqrt(n) would be far too small: n_eff is well below n.
    assert inclinometer['within_n_eff'] < samples / 3
    # gsp_reidentify of the run directory has the same within-posture estimate (samples.csv
    # keeps each row's lag sums), and so has the rebuild of its recording.
    rows = run.read_samples()
    assert np.isfinite(rows.lag_sums[:, :, : samples // 2 + 1]).all()
    again = refresh_report(run.path, plots=False)
    assert again.noise_estimates['inclinometer']['row_std'] == pytest.approx(
        inclinometer['row_std'], rel=1e-9
    )
    rebuilt = rebuild.samples_from_recording(run.path / 'recording.mcap')
    np.testing.assert_allclose(rebuilt.lag_sums, rows.lag_sums, rtol=1e-9, atol=0.0)


def offline_run(poses, samples, rate_hz, correlation_time, seed):
    """The collection protocol's rows without ROS: platform_sim's simulator (nominal
    controller, the shipped truth, default leg noise) and device_driver's ``sim`` backend
    (default noise, the inclinometer's correlated over ``correlation_time`` s) sampled at
    ``rate_hz`` on one clock, ``samples`` pairs averaged a posture by the collector (its
    consistency and settle checks at their defaults)."""
    from gsp_device_driver.backends import SimDeviceBackend
    from gsp_platform_sim.simulator import PlatformSimulator

    true = default_geometry('true')
    rng = np.random.default_rng(seed)
    platform = PlatformSimulator(
        true, default_geometry('nominal'), DEFAULT_SENSOR_NOISE.leg_lengths, rng
    )
    device = SimDeviceBackend(
        true.device_length,
        true.inclinometer_axes_angle,
        DEFAULT_SENSOR_NOISE,
        rng=rng,
        sensors=true.sensors,
        correlation_times=(correlation_time, 0.0, 0.0),
    )
    collector = SampleCollector(
        0.25 / rate_hz, samples, noise_std=DEFAULT_SENSOR_NOISE.channel_std()
    )
    rows, step = Rows.empty(), 0
    for posture, pose in enumerate(poses, 1):
        assert platform.command(pose).accepted
        device.observe_true_pose(platform.true_pose)
        collector.start(seconds_to_ns(step / rate_hz))
        chunk = samples
        while not collector.ready():  # as the protocol: until a window passes its checks
            for _ in range(chunk):
                stamp = seconds_to_ns(step / rate_hz)
                reading = device.read(step / rate_hz)
                collector.add_leg_lengths(stamp, platform.measured_leg_lengths())
                collector.add_inclinometer(stamp, reading.alpha, reading.beta)
                collector.add_encoder(stamp, reading.phi)
                collector.add_lvdt(stamp, reading.d_m)
                step += 1
            chunk = max(samples // 10, 1)
        row = collector.take_posture()
        rows.append(posture, pose, row.leg_lengths, row.readings, samples, row.stamp, row.lag_sums)
    return rows


@pytest.mark.parametrize(
    'postures, samples, lower_bound',
    [(60, 10, True), (30, 300, False)],  # 0.05 s and 1.5 s windows at 200 Hz
)
def test_correlated_device_noise_offline_is_estimated_and_accepted(postures, samples, lower_bound):
    """The realistic inclinometer (noise correlated over 0.05 s, 200 Hz): with the default
    10-sample windows the within estimate is only a lower bound (n_eff ~ 3), the row noise comes
    from the residuals between postures and the inclinometer is left out of the F test; with
    1.5 s windows the effective sample count gives it within postures. Either way the right
    model is accepted and the row noise is the AR(1) truth within 15 %."""
    rate_hz, correlation_time = 200.0, 0.05
    nominal = default_geometry('nominal')
    poses = choose_postures(nominal, postures, 10 * postures, seed=5).poses
    rows = offline_run(poses, samples, rate_hz, correlation_time, seed=postures)
    outcome = identify_from_samples(nominal, rows, DEFAULT_SENSOR_NOISE)
    assert outcome.success and outcome.fit_accepted, outcome.fit_diagnosis
    assert outcome.result.goodness_of_fit.test == 'lack_of_fit'
    inclinometer = outcome.noise_estimates['inclinometer']
    assert inclinometer['within_lower_bound'] is lower_bound
    assert inclinometer['source'] == ('between' if lower_bound else 'pooled')
    # The summary says so on the inclinometer's line.
    lines = outcome_summary(outcome).splitlines()
    noted = [line for line in lines if 'within: lower bound' in line]
    assert noted == (
        [next(x for x in lines if x.startswith('sensor noise inclinometer'))] if lower_bound else []
    )
    rho = np.exp(-1.0 / (rate_hz * correlation_time))
    true_row = ar1_std_of_mean(DEFAULT_SENSOR_NOISE.inclinometer, rho, samples)
    assert inclinometer['row_std'] == pytest.approx(true_row, rel=0.15)
    # s / sqrt(n) would be less than 0.4x the truth: the correlation matters.
    assert DEFAULT_SENSOR_NOISE.inclinometer / np.sqrt(samples) < 0.4 * true_row
    for channel in ('leg_lengths', 'encoder', 'lvdt'):  # white: s / sqrt(n)
        truth = getattr(DEFAULT_SENSOR_NOISE, channel) / np.sqrt(samples)
        assert outcome.noise_estimates[channel]['row_std'] == pytest.approx(truth, rel=0.15)
