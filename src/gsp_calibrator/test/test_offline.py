"""gsp_reidentify: offline equals the pipeline the node runs; bad input exits 2 with a reason."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from synthetic import synthetic_samples as make_samples

from gsp_calibrator.files.run_directory import read_samples, write_samples
from gsp_calibrator.recording import mcap_io, rebuild
from gsp_calibrator.report.write import PLOTS_SKIPPED_NOTE
from gsp_calibrator.run.identify import identify_from_samples
from gsp_calibrator.run.response import RUN_DIRECTORY_LABEL
from gsp_calibrator.settings import option_value
from gsp_calibrator.tools.reidentify import main, refresh_report
from gsp_kinematics.model.geometry import (
    PARAMETER_NAMES,
    default_geometry,
    default_geometry_path,
    load_geometry,
)
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_msgs_py import conversions, names

MS = 1_000_000


def synthetic_samples(count=30, seed=11, n_samples=4):
    """Rows with 4 samples each and epoch-like stamps."""
    return make_samples(count, seed, n_samples=n_samples, first_stamp=1.7e9)


def _run_directory(output):
    lines = [line for line in output.splitlines() if line.startswith(RUN_DIRECTORY_LABEL)]
    assert lines, output
    return lines[-1][len(RUN_DIRECTORY_LABEL) :].strip()


def _json_parameters(run_dir):
    with open(f'{run_dir}/result.json', encoding='utf-8') as stream:
        data = json.load(stream)
    return np.array([data['estimates']['si'][name] for name in PARAMETER_NAMES])


def test_offline_equals_the_pipeline(tmp_path, capsys):
    samples = synthetic_samples()
    csv_path = tmp_path / 'samples.csv'
    write_samples(csv_path, samples)
    free = ['A1x', 'A1y', 'B2z', 'Loff3', 'D0', 'gamma']
    # What the calibrator node runs on its collected samples (nominal, sigmas, free, formulation).
    direct = identify_from_samples(
        load_geometry(default_geometry_path('nominal')), samples, SensorNoise(), free, 'implicit'
    )
    assert direct.success, direct.message

    code = main(
        [
            str(csv_path),
            '--output-root',
            str(tmp_path / 'runs'),
            '--free',
            'A1x,A1y',
            'B2z',
            'Loff3',
            'D0',
            'gamma',
            '--no-report',
        ]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    run_dir = _run_directory(out)
    # Six free parameters leave the rest of the geometry's errors: the verdict, as the pipeline's.
    assert out.startswith('calibration NOT ACCEPTED') and not direct.accepted
    calibrated = load_geometry(f'{run_dir}/result.yaml')
    np.testing.assert_allclose(
        calibrated.to_full_vector(), direct.result.parameters, rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        _json_parameters(run_dir), direct.result.parameters[:44], rtol=0, atol=1e-12
    )
    again = read_samples(f'{run_dir}/samples.csv')
    np.testing.assert_array_equal(again.leg_lengths, samples.leg_lengths)
    with open(f'{run_dir}/result.json', encoding='utf-8') as stream:
        data = json.load(stream)
    assert data['free_parameters'] == free
    assert data['options']['source_kind'] == 'csv'


def test_offline_from_run_directory_with_truth_and_report(tmp_path, capsys):
    samples = synthetic_samples(count=30, seed=12)
    source = tmp_path / 'source_run'
    source.mkdir()
    write_samples(source / 'samples.csv', samples)
    (source / 'true_geometry.yaml').write_text(
        open(default_geometry_path('true'), encoding='utf-8').read(), encoding='utf-8'
    )
    code = main(
        [str(source), '--output-root', str(tmp_path / 'runs'), '--validation-postures', '10']
    )
    out = capsys.readouterr().out
    assert code == 0, out
    run_dir = _run_directory(out)
    for name in (
        'samples.csv',
        'result.yaml',
        'result.json',
        'report.md',
        'true_geometry.yaml',
        'parameter_errors.png',
        'chain_errors.png',
        'residuals.png',
        'validation.png',
    ):
        assert (tmp_path / 'runs').joinpath(run_dir, name).exists(), name
    assert 'validation after' in out and 'parameter errors vs reference' in out
    direct = identify_from_samples(default_geometry('nominal'), samples, SensorNoise())
    np.testing.assert_allclose(
        _json_parameters(run_dir), direct.result.parameters[:44], rtol=0, atol=1e-12
    )


def _write_recording(path, samples, per_posture):
    """A recorded run that gives ``samples`` (each row repeated ``per_posture`` times)."""
    with mcap_io.McapRecorder(path) as writer:
        writer.add_metadata(
            mcap_io.RUN_METADATA_NAME,
            {
                'sync_tolerance': '0.0025',
                'pairs_per_posture': str(per_posture),
                'sigma_lvdt': '2e-06',
                'formulation': '"implicit"',
            },
        )
        t = 1_700_000_000 * 1_000_000_000
        for m in range(len(samples)):
            command = conversions.pose_to_pose_stamped(samples.commanded_poses[m], t / 1e9)
            command_id = conversions.command_id_from_stamp(command.header.stamp)
            writer.write(names.TOPIC_POSE_COMMAND, command, t)
            writer.write(
                names.TOPIC_PLATFORM_STATUS,
                conversions.make_status(command_id, names.STATE_SETTLED),
                t + MS,
            )
            r = samples.readings[m]
            for j in range(per_posture + 1):
                stamp = t + 2 * MS + 5 * MS * j
                writer.write(
                    names.TOPIC_LEG_LENGTHS,
                    conversions.leg_lengths_to_msg(samples.leg_lengths[m], stamp / 1e9),
                    stamp + 100,
                )
                for topic, msg in (
                    (names.TOPIC_INCLINOMETER, conversions.inclinometer_to_msg(r[0], r[1])),
                    (names.TOPIC_ENCODER, conversions.encoder_to_msg(r[2])),
                    (names.TOPIC_LVDT, conversions.lvdt_to_msg(r[3])),
                ):
                    msg.header.stamp = conversions.seconds_to_stamp(stamp / 1e9)
                    writer.write(topic, msg, stamp + 200)
            t += 100 * MS


def test_offline_from_recording(tmp_path, capsys):
    samples = synthetic_samples(count=30, seed=13)
    mcap = tmp_path / 'recording.mcap'
    _write_recording(mcap, samples, per_posture=2)
    rebuilt = rebuild.samples_from_recording(mcap)
    assert len(rebuilt) == len(samples)
    np.testing.assert_allclose(rebuilt.leg_lengths, samples.leg_lengths, rtol=0, atol=1e-15)
    np.testing.assert_allclose(rebuilt.readings, samples.readings, rtol=0, atol=1e-15)
    code = main([str(mcap), '--output-root', str(tmp_path / 'runs'), '--no-report'])
    out = capsys.readouterr().out
    assert code == 0, out
    run_dir = _run_directory(out)
    assert (tmp_path / 'runs').joinpath(run_dir, 'recording.mcap').exists()
    # The options stored in the recording (here sigma_lvdt) are the run's: used when not given.
    direct = identify_from_samples(default_geometry('nominal'), rebuilt, SensorNoise(lvdt=2e-6))
    np.testing.assert_allclose(
        _json_parameters(run_dir), direct.result.parameters[:44], rtol=0, atol=1e-12
    )
    with open(f'{run_dir}/result.json', encoding='utf-8') as stream:
        options = json.load(stream)['options']
    assert options['pairs_per_posture'] == 2 and options['sync_tolerance'] == 0.0025
    assert options['sigma_lvdt'] == 2e-6 and options['source_kind'] == 'mcap'
    # ... and the new run directory re-identifies to the same result with the same options;
    # --no-plots: its report.md without PNGs.
    code = main([run_dir, '--output-root', str(tmp_path / 'runs'), '--no-plots'])
    out = capsys.readouterr().out
    assert code == 0, out
    again = Path(_run_directory(out))
    np.testing.assert_allclose(
        _json_parameters(again), direct.result.parameters[:44], rtol=0, atol=1e-12
    )
    assert PLOTS_SKIPPED_NOTE in (again / 'report.md').read_text(encoding='utf-8')
    assert not list(again.glob('*.png'))


@pytest.mark.parametrize(
    'mutate, expected',
    [
        (lambda text: text.replace('leg_3', 'leg_three', 1), 'columns'),
        (lambda text: text.splitlines()[0] + '\n', 'no posture rows'),
        (
            lambda text: (
                '\n'.join(
                    text.splitlines()[:2]
                    + [text.splitlines()[2].replace(text.splitlines()[2].split(',')[9], 'abc')]
                )
                + '\n'
            ),
            ':3: column leg_3',
        ),
        (lambda text: '', 'empty file'),
    ],
)
def test_bad_csv_exits_2_naming_the_fault(tmp_path, capsys, mutate, expected):
    csv_path = tmp_path / 'samples.csv'
    write_samples(csv_path, synthetic_samples(count=3))
    csv_path.write_text(mutate(csv_path.read_text(encoding='utf-8')), encoding='utf-8')
    code = main([str(csv_path), '--output-root', str(tmp_path / 'runs')])
    err = capsys.readouterr().err
    assert code == 2
    assert 'samples.csv' in err and expected in err, err
    assert not (tmp_path / 'runs').exists()


@pytest.mark.parametrize(
    'arguments, expected',
    [
        (['--free', 'A1x', 'Z9'], "unknown parameter name(s) ['Z9']"),
        (['--free', 'extended,kq9'], "unknown parameter name(s) ['kq9']"),
        (['--sigma-lvdt', '-1'], '--sigma-lvdt'),
        (['--nominal', 'missing.yaml'], 'missing.yaml'),
    ],
)
def test_bad_options_exit_2(tmp_path, capsys, arguments, expected):
    csv_path = tmp_path / 'samples.csv'
    write_samples(csv_path, synthetic_samples(count=3))
    code = main([str(csv_path), *arguments, '--output-root', str(tmp_path / 'runs')])
    assert code == 2
    assert expected in capsys.readouterr().err


def test_free_accepts_groups_and_sensor_error_names():
    # gsp_reidentify's --free is checked and split as the calibrator's parameter.
    assert option_value('free_parameters', ['paper,kq1', 'alpha0']) == ['paper', 'kq1', 'alpha0']
    assert option_value('free_parameters', ['extended']) == ['extended']


def test_missing_input_and_failed_identification(tmp_path, capsys):
    assert main([str(tmp_path / 'nothing.csv')]) == 2
    assert 'nothing.csv' in capsys.readouterr().err
    (tmp_path / 'empty_run').mkdir()
    assert main([str(tmp_path / 'empty_run')]) == 2
    assert 'empty_run' in capsys.readouterr().err
    # Two postures cannot identify 44 parameters: exit 1, the reason printed, no result.yaml.
    csv_path = tmp_path / 'samples.csv'
    write_samples(csv_path, synthetic_samples(count=2))
    code = main([str(csv_path), '--output-root', str(tmp_path / 'runs'), '--no-report'])
    out = capsys.readouterr().out
    assert code == 1
    assert 'calibration FAILED' in out
    run_dir = _run_directory(out)
    assert (tmp_path / 'runs').joinpath(run_dir, 'samples.csv').exists()
    assert not (tmp_path / 'runs').joinpath(run_dir, 'result.yaml').exists()


def test_refresh_report_adds_truth_and_validation(tmp_path):
    samples = synthetic_samples(count=25, seed=14)
    run_dir = tmp_path / 'run'
    run_dir.mkdir()
    write_samples(run_dir / 'samples.csv', samples)
    truth, nominal = default_geometry('true'), default_geometry('nominal')
    poses = sample_valid_postures(truth, 10, np.random.default_rng(3))
    from gsp_calibrator.report.data import validation_errors

    before = validation_errors(truth, nominal, poses)
    # The calibrator's collection record survives the rewrite.
    collection = {
        'skipped': [{'posture': 3, 'reason': 'x', 'rejected_by_platform': True}],
        'inconsistent_dropped': 2,
        'non_finite_dropped': {'leg_lengths': 1},
    }
    (run_dir / 'result.json').write_text(json.dumps({'collection': collection}))
    outcome = refresh_report(run_dir, truth=truth, validation_before=before, plots=False)
    assert outcome.success
    with open(run_dir / 'result.json', encoding='utf-8') as stream:
        data = json.load(stream)
    assert PLOTS_SKIPPED_NOTE in (run_dir / 'report.md').read_text(encoding='utf-8')
    assert not list(run_dir.glob('*.png'))
    assert data['collection'] == collection
    assert data['parameter_errors']['reference'] == 'truth'
    validated = data['validation']['before']
    assert validated['postures'] + validated['unreachable'] == 10 and validated['postures'] >= 9
    direct = identify_from_samples(nominal, samples, SensorNoise())
    np.testing.assert_allclose(
        _json_parameters(run_dir), direct.result.parameters[:44], rtol=0, atol=1e-12
    )


@pytest.mark.parametrize('source, test', [('estimated', 'none'), ('configured', 'chi2')])
def test_reidentify_takes_either_noise_source(tmp_path, capsys, source, test):
    csv_path = tmp_path / 'samples.csv'
    write_samples(csv_path, make_samples(count=30, seed=4))
    code = main(
        [str(csv_path), '--output-root', str(tmp_path / 'runs'), '--noise-source', source]
        + ['--no-report']
    )
    out = capsys.readouterr().out
    assert code == 0, out
    with open(f'{_run_directory(out)}/result.json', encoding='utf-8') as stream:
        data = json.load(stream)
    assert data['noise_source'] == source and data['options']['noise_source'] == source
    assert data['goodness_of_fit']['test'] == test
    if source == 'estimated':
        # A samples.csv has no within-posture scatter: between postures only, and said so.
        assert {entry['source'] for entry in data['noise_estimates'].values()} == {'between'}
        assert 'not testable' in data['fit_diagnosis']


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason='one core: BLAS starts one thread anyway')
def test_a_console_script_runs_blas_on_one_thread_unless_told_otherwise():
    """numpy's OpenBLAS starts a thread per core when it loads; the package sets one first
    (gsp_calibrator/__init__.py), and a count the user set stays."""
    probe = (
        'import gsp_calibrator.tools.reidentify, ctypes, glob, os, numpy; '
        "libs = os.path.join(os.path.dirname(numpy.__file__), '..', 'numpy.libs'); "
        "lib = ctypes.CDLL(glob.glob(os.path.join(libs, 'libscipy_openblas*'))[0]); "
        'print(lib.scipy_openblas_get_num_threads64_())'
    )
    environment = {
        name: value
        for name, value in os.environ.items()
        if name not in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')
    }
    threads = subprocess.run(
        [sys.executable, '-c', probe], env=environment, capture_output=True, text=True, check=True
    ).stdout.split()[-1]
    assert threads == '1'
    environment['OPENBLAS_NUM_THREADS'] = '2'
    threads = subprocess.run(
        [sys.executable, '-c', probe], env=environment, capture_output=True, text=True, check=True
    ).stdout.split()[-1]
    assert threads == '2'
