"""Issue 24's 'done when' through the nodes: ``platform_sim`` with the realistic effects (40 kg
on 30 N/um legs, 4 um backlash, legs warming, base joint axes 20 um apart), ``device_driver``
and the ``calibrator`` with ``free_parameters: [auto]`` and the payload given, as processes. The
run chooses the effect groups, is applied, and platform_sim's controller compensates them: the
platform lands closer to commanded postures than with the plain model identified from the same
rows, measured on platform_sim's true pose; against the simulation's truth at the instant the
geometry refers to, it is within 1.5x of the same plan, model and noise on the ideal platform
(docs/platform_effects.md#through-the-calibrator)."""

import dataclasses
import io
import json
import time
from pathlib import Path

import numpy as np
from gsp_testing import marked_environment

from gsp_calibrator.collection.approach import effect_design
from gsp_calibrator.files.run_directory import read_samples
from gsp_calibrator.recording import rebuild
from gsp_calibrator.recording.recorder import recording_parts
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.tools import demo, demo_commands, reidentify
from gsp_calibrator.tools.processes import NodeProcesses
from gsp_kinematics.estimation.identification import identify
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.effect_groups import commanded_leg_readings
from gsp_kinematics.model.effects import REALISTIC
from gsp_kinematics.model.geometry import default_geometry, geometry_to_parameters, load_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.real_pose import real_poses
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.model.validation import simulate_commands, validate

CALIBRATION_TIMEOUT_S = 600.0  # generous: the machine may be loaded
WAIT_S = 60.0
#: 60 postures (61 commanded with the reference revisit at the end), 30 samples each: about a minute of
#: platform time, enough to resolve all four groups (docs/platform_effects.md).
POSTURES = 60
PAIRS_PER_POSTURE = 30
#: Streams at 50 Hz: a loaded machine keeps up with them (at 200 Hz the device's starve).
SENSOR_RATE_HZ = 50
CHECK_POSTURES = 20


def _apply(node, geometry):
    """Set ``geometry``'s ``geometry.*`` parameters on platform_sim (its controller)."""
    from rcl_interfaces.srv import SetParametersAtomically
    from rclpy.parameter import Parameter

    client = node.create_client(SetParametersAtomically, '/platform_sim/set_parameters_atomically')
    node.spin_until(client.service_is_ready, WAIT_S, 'the parameter service of platform_sim')
    request = SetParametersAtomically.Request()
    request.parameters = [
        Parameter(name, value=value).to_parameter_msg()
        for name, value in geometry_to_parameters(geometry, all_effects=True).items()
    ]
    future = client.call_async(request)
    node.spin_until(future.done, WAIT_S, 'platform_sim to take the geometry')
    assert future.result().result.successful, future.result().result.reason


def _position_errors_mm(commanded, reached):
    both = np.all(np.isfinite(reached), axis=1)
    return 1e3 * np.linalg.norm(reached[both, :3] - commanded[both, :3], axis=1)


def _reidentified(run, free, output):
    """``gsp_reidentify`` of the run directory with ``--free free``: its run directory."""
    code, path = reidentify.reidentify(
        reidentify.build_parser().parse_args(
            [str(run), '--free', free, '--output-root', str(output), '--no-report']
        ),
        out=io.StringIO(),
    )
    assert code == 0
    return Path(path)


def _ideal_accuracy_mm(samples, checks, noise, free=('extended',), design=None):
    """The mean position error (mm) over ``checks`` of the same run's postures (``samples``'
    commanded poses, in their order) calibrated with ``free`` (and the effect ``design``) on
    the ideal platform, its rows given ``noise`` (M, 10: legs, then the device's readings)."""
    nominal, true = default_geometry('nominal'), default_geometry('true')
    poses = samples.commanded_poses
    ideal = simulate_commands(true, nominal, poses)
    result = identify(
        nominal,
        ideal.leg_readings + noise[:, :6],
        ideal.device_readings + noise[:, 6:],
        DEFAULT_SENSOR_NOISE.averaged(samples.n_samples),
        free=list(free),
        pose_guesses=poses,
        effects=design,
    )
    return validate(true, result.geometry, checks)['position_mm_mean']


def _drawn_noise(samples, seed):
    """Noise (M, 10) drawn at the default level, averaged as ``samples``' rows were."""
    sigmas = DEFAULT_SENSOR_NOISE.averaged(samples.n_samples)
    scale = np.concatenate([np.full(6, sigmas.leg_lengths), sigmas.readings()])
    return np.random.default_rng(seed).normal(size=(len(samples), 10)) * scale


def _run_noise(samples, times_s):
    """The noise the run's rows had (M, 10): each row less what the realistic platform reads,
    noise free, at its commanded posture, approach directions and time (``times_s``, s on
    platform_sim's clock: a second off shifts every leg alike, which the leg offsets absorb)."""
    nominal, true = default_geometry('nominal'), default_geometry('true')
    poses = samples.commanded_poses
    legs = commanded_leg_readings(nominal, poses)
    reached, ok = real_poses(true, REALISTIC, legs, poses, samples.directions, times_s)
    assert ok.all()
    device = true.sensors.device_readings(device_readings(true, reached))
    return np.concatenate([samples.leg_lengths - legs, samples.readings - device], axis=1)


def _calibrate_and_check(node, checks):
    """Calibrate through the service (applied), then command ``checks`` with the applied
    geometry: ``(run directory, reached poses)``."""
    node.wait_for_system(WAIT_S)
    response = node.calibrate(CALIBRATION_TIMEOUT_S)
    parsed = parse_response(response.message)
    assert response.success, response.message
    assert 'applied to /platform_sim' in response.message, response.message
    reached = node.run_postures(checks, 30.0, WAIT_S)
    return Path(parsed.run_directory), reached


def test_auto_chooses_the_effects_and_the_controller_compensates_them(tmp_path, ros_context):
    from rclpy.executors import SingleThreadedExecutor

    from gsp_calibrator.tools import demo_node

    env, _ = marked_environment()
    args = demo.parse_arguments(
        ['--platform-effects', 'realistic', '--postures', str(POSTURES), '--free', 'auto']
        + ['--sensor-rate', str(SENSOR_RATE_HZ), '--output-root', str(tmp_path / 'runs')]
        + ['--pairs-per-posture', str(PAIRS_PER_POSTURE)]
    )
    commands = demo_commands.node_commands(args, str(tmp_path / 'runs'))
    assert 'payload_mass:=40.0' in commands['calibrator']  # the user knows the load
    # A loaded machine (2 cores, other suites) starves a stream for seconds at times: the run
    # waits that out instead of failing (a run failed at 2 s with no device sample).
    commands['calibrator'] += ['-p', 'topic_timeout:=10.0']
    nominal = default_geometry('nominal')
    checks = sample_valid_postures(nominal, CHECK_POSTURES, np.random.default_rng(7))
    nodes = NodeProcesses(commands, env, tmp_path)
    node = demo_node.DemoNode(nodes, context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    wall_started = time.time()  # platform_sim's clock (its thermal growth) starts about here
    nodes.start()
    try:
        run, reached_auto = _calibrate_and_check(node, checks)
        # The plain model from the same rows, by the same code (gsp_reidentify), applied.
        plain_run = _reidentified(run, 'extended', tmp_path / 'plain')
        plain = load_geometry(plain_run / 'result.yaml')
        _apply(node, plain)
        reached_plain = node.run_postures(checks, 30.0, WAIT_S)
    finally:
        executor.shutdown()
        node.destroy_node()
        nodes.stop()

    data = json.loads((run / 'result.json').read_text())
    assert data['accepted'] is True
    choice = data['effects']['model_choice']
    # What this run identifies (docs/platform_effects.md#through-the-calibrator): all four
    # groups. The compliance (tens of um) and the backlash (4 um against 0.3-0.5 um Cramer-Rao
    # per leg); the legs' growth during the run (about 3 um a minute at first) against the
    # postures' own times and the reference revisit at the end; the joint offsets (20 um) once the plan resolves them: with 10 samples
    # a posture their chi-square drop in the last round was 12-32 (p 0.01 or below in half the
    # simulated runs), with 30 it is 54-91. The held-out guard takes each held-out posture's
    # leverage out: raw, it left the joint offsets out in 1 node run of 12 (and 1-4 % of
    # simulated draws; test_effects_run.py's test at this plan).
    assert set(choice['groups']) == {'compliance', 'backlash', 'thermal', 'joint_offsets'}, choice
    # The run commanded the route's addition: the reference revisit at the end, its own posture.
    additions = data['collection']['route_additions']
    assert additions['groups'] == ['backlash', 'thermal'] and additions['reference_revisits'] == 1
    # Their time predicted at the rate the calibrator heard the streams at (at most the 50 Hz
    # asked; a loaded machine's platform_sim publishes its legs at 20 Hz), never gsp_plan's
    # 200 Hz: the run hears its streams before it plans the route (docs/data.md,
    # route_additions).
    assert 0.0 < additions['sample_rate_hz'] < 1.2 * SENSOR_RATE_HZ, additions
    calibrated = load_geometry(run / 'result.yaml')
    assert set(calibrated.effects.groups()) == set(choice['groups'])
    assert calibrated.effects.payload_mass == REALISTIC.payload_mass
    assert data['effects']['thermal'] is None or data['effects']['thermal']['drift_um_per_min']

    # gsp_reidentify on the run directory: the same choice, by the same code path.
    again = json.loads((_reidentified(run, 'auto', tmp_path / 'again') / 'result.json').read_text())
    assert again['effects']['model_choice']['groups'] == choice['groups']

    # samples.csv and the rebuild from the recording give each row the same approach directions.
    samples = read_samples(run / 'samples.csv')
    revisits = [m + 1 for m, kind in enumerate(additions['kind']) if kind == 'reference']
    assert revisits == [len(additions['kind'])]  # the last posture commanded
    rebuilt = rebuild.samples_from_recording(recording_parts(run))
    common = sorted(set(samples.posture) & set(rebuilt.posture))
    assert len(common) >= 0.8 * len(samples)
    online = {int(k): d for k, d in zip(samples.posture, samples.directions, strict=True)}
    offline = {int(k): d for k, d in zip(rebuilt.posture, rebuilt.directions, strict=True)}
    for k in common:
        np.testing.assert_array_equal(online[k], offline[k])
    assert np.all(np.abs(samples.directions) == 1.0)

    # Through platform_sim: the compensating controller lands closer to the commanded postures.
    auto_mm = float(np.mean(_position_errors_mm(checks, reached_auto)))
    plain_mm = float(np.mean(_position_errors_mm(checks, reached_plain)))
    truth = _truth(samples, data, (calibrated, plain), checks, wall_started)
    print(f'through platform_sim: auto {auto_mm:.4f} mm, plain {plain_mm:.4f} mm')
    print(f'groups {choice["groups"]}; truth at the reference instant: {truth}')
    # The run's noise, recovered from its rows, is the device's and the legs' (the recovery holds).
    assert 0.6 < truth['noise_rms_over_sigma'] < 1.6, truth
    # The figure: within 1.5x of the same plan on the ideal platform, there with the
    # same model and the same noise draw: the effects cost no more than if the platform had
    # none. Measured 0.85-1.14x in ten runs, 0.96-1.08x in pure simulations of this plan;
    # against the plain model's median on the ideal platform the ratio moves with the noise
    # draw (one draw of the ideal platform alone spans 0.5-1.5x of its median), and the six
    # thermal rates of a one-minute run double the variance: docs/platform_effects.md.
    # Against the plain model on the ideal platform (printed, not asserted) a run measured
    # 0.8-2.8x of its median: the six thermal rates of a one-minute run cost up to 2.7x.
    assert truth['auto_mm'] < 1.5 * truth['ideal_same_model_mm'], truth
    # Bound at 1.5x: a run that loses postures to a loaded machine keeps a margin, and the
    # plain model (the compliance pushed into the geometry) stays well above it.
    assert auto_mm < plain_mm / 1.5, (auto_mm, plain_mm)
    assert truth['auto_mm'] < truth['plain_mm'] / 1.5, truth


def _truth(samples, data, geometries, checks, wall_started, ideal_draws=5):
    """The simulation's truth over ``checks`` at the instant the calibrated geometry refers to
    (``data``: result.json): the mean position error (mm) with the calibrated and the plain
    geometry (``geometries``), and of the same plan on the ideal platform with the same model
    and the run's own noise, with the plain model and that noise, and with the plain model,
    the median over ``ideal_draws`` drawn noises. ``wall_started``: when platform_sim started
    (s, wall time): its clock, that the thermal growth follows."""
    true = default_geometry('true')
    thermal = data['effects']['thermal']
    reference = thermal['reference_stamp_s'] if thermal else float(samples.stamps[-1])
    at = np.full(len(checks), reference - wall_started)
    noise = _run_noise(samples, np.asarray(samples.stamps) - wall_started)
    sigmas = DEFAULT_SENSOR_NOISE.averaged(samples.n_samples)
    scale = np.concatenate([np.full(6, sigmas.leg_lengths), sigmas.readings()])
    choice = data['effects']['model_choice']
    design = dataclasses.replace(
        effect_design(samples, REALISTIC.payload_mass, REALISTIC.centre_of_mass),
        thermal_time_constant_s=choice['thermal_time_constant_s'],
    )
    model = ['extended', *choice['groups']]
    plain_draws = [
        _ideal_accuracy_mm(samples, checks, _drawn_noise(samples, seed))
        for seed in range(ideal_draws)
    ]
    calibrated, plain = geometries
    return {
        'auto_mm': validate(true, calibrated, checks, REALISTIC, at)['position_mm_mean'],
        'plain_mm': validate(true, plain, checks, REALISTIC, at)['position_mm_mean'],
        'ideal_same_model_mm': _ideal_accuracy_mm(samples, checks, noise, model, design),
        'ideal_plain_same_noise_mm': _ideal_accuracy_mm(samples, checks, noise),
        'ideal_plain_median_mm': float(np.median(plain_draws)),
        # Less each channel's mean: a second off platform_sim's clock shifts a leg's growth.
        'noise_rms_over_sigma': float(np.sqrt(np.mean(((noise - noise.mean(0)) / scale) ** 2))),
    }
