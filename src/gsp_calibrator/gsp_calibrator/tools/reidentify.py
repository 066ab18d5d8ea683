"""``gsp_reidentify``: re-identify a calibration offline, into a new run directory (no ROS graph).
See docs/data.md#offline-re-identification-gsp_reidentify."""

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from gsp_calibrator.files.run_directory import TRUE_GEOMETRY_FILE, RunDirectory
from gsp_calibrator.run import postures
from gsp_calibrator.run.identify import identify_from_samples, write_results
from gsp_calibrator.run.response import RUN_DIRECTORY_LABEL, outcome_summary
from gsp_calibrator.settings import (
    DEFAULTS,
    PARAMETER_SPECS,
    option_name,
    option_value,
    requirement_from_parameters,
)
from gsp_calibrator.tools.reidentify_inputs import (
    OPTION_PARAMETERS,
    InputError,
    geometry_option,
    load_input,
    recording_of,
    resolve_input,
    resolve_options,
    result_json,
    stored_options,
)
from gsp_kinematics.estimation.identification import IdentificationError, Options
from gsp_kinematics.fileio import atomic_copy
from gsp_kinematics.model.geometry import default_geometry_path
from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_msgs_py.noise_parameters import noise_from_parameters

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2

VALIDATION_POSTURES = 50


def _identify(nominal, samples, sigmas, options, noise_source):
    """``identify_from_samples`` with the run's resolved ``options`` (its workspace postures,
    ``run.postures.workspace_poses_of``, and the core's ``Options``: the loss)."""
    return identify_from_samples(
        nominal,
        samples,
        sigmas,
        options['free_parameters'],
        options['formulation'],
        noise_source=noise_source,
        requirement=requirement_from_parameters(options),
        folds=int(options['cross_validation_folds']),
        payload_mass=options['payload_mass'],
        centre_of_mass=options['payload_centre_of_mass'],
        workspace_poses=postures.workspace_poses_of(
            nominal, options.get('workspace_postures', 0), options.get('seed', 0)
        ),
        leg_mass=options['leg_mass'],
        max_posture_error=options['max_posture_error'],
        options=Options(loss=options.get('loss', DEFAULTS['loss'])),
    )


def build_parser():
    parser = argparse.ArgumentParser(
        prog='gsp_reidentify',
        description='Re-identify a Gough-Stewart platform calibration offline from a run '
        'directory, a samples.csv or a recording.mcap, into a new run directory.',
    )
    add = parser.add_argument
    add('input', help='run directory, samples.csv or recording.mcap')
    stored = 'default: as stored with the input run, else'
    add(
        '--nominal',
        default=None,
        help='nominal geometry params file (default: as stored with the input run '
        'if that file exists, else the shipped nominal, '
        f'{default_geometry_path("nominal")})',
    )
    for name in OPTION_PARAMETERS:
        default, description = DEFAULTS[name], PARAMETER_SPECS[name].description
        if isinstance(default, list):
            kind = {'nargs': '+', 'metavar': 'NAME'}
            description += f'; comma-separated lists allowed ({stored} {" ".join(default)})'
        else:
            kind = {'type': type(default)}
            description += f' ({stored} {default})'
        add(option_name(name), dest=name, default=None, help=description, **kind)
    add(
        '--output-root',
        default=DEFAULTS['output_root'],
        help='directory of the new run directory (default %(default)s)',
    )
    add(
        '--truth',
        default=None,
        help='true geometry params file, for errors against the truth and a '
        "validation in the report (default: the input run directory's "
        f'{TRUE_GEOMETRY_FILE}, if any)',
    )
    add(
        '--validation-postures',
        type=int,
        default=VALIDATION_POSTURES,
        metavar='N',
        help='random postures of the validation against the truth (default %(default)s; 0: none)',
    )
    add('--seed', type=int, default=0, help='seed of the validation postures (default %(default)s)')
    add(
        '--no-report',
        action='store_true',
        help='write samples.csv, result.yaml and result.json only',
    )
    add(
        '--no-plots',
        action='store_true',
        help="write report.md without its PNG plots (the calibrator's write_report_plots: false)",
    )
    return parser


def _truth(args, source_dir):
    """``(path, Geometry)`` of ``--truth``, else of the source run's true geometry, else None."""
    truth_path = args.truth
    if (
        truth_path is None
        and source_dir is not None
        and (source_dir / TRUE_GEOMETRY_FILE).is_file()
    ):
        truth_path = source_dir / TRUE_GEOMETRY_FILE
    truth = geometry_option(truth_path, '--truth') if truth_path is not None else None
    return truth_path, truth


def _validate(truth, nominal, outcome, args):
    """Validation errors against ``truth`` before and after (None where not measured)."""
    if truth is None or args.validation_postures <= 0:
        return None, None
    from gsp_calibrator.report.data import validation_errors
    from gsp_kinematics.model.kinematics import sample_valid_postures

    before = after = None
    rng = np.random.default_rng(args.seed)
    poses = sample_valid_postures(truth, args.validation_postures, rng)
    try:
        before = validation_errors(truth, nominal, poses)
        if outcome.success:
            after = validation_errors(truth, outcome.geometry, poses)
    except ValueError as error:
        print(f'warning: validation skipped: {error}', file=sys.stderr)
    return before, after


def reidentify(args, out=None):
    """Run the re-identification for parsed ``args``; returns ``(exit code, run directory)``."""
    out = sys.stdout if out is None else out
    try:  # a bad name is reported before anything is read
        option_value('free_parameters', args.free_parameters or DEFAULTS['free_parameters'])
    except ValueError as error:
        raise InputError(str(error)) from None
    kind, path, source_dir = resolve_input(args.input)
    options = resolve_options(args, stored_options(kind, path, source_dir))
    nominal = geometry_option(options['nominal_geometry_file'], '--nominal')
    truth_path, truth = _truth(args, source_dir)
    if args.validation_postures < 0:
        raise InputError('--validation-postures must be >= 0')
    samples = load_input(kind, path, options)

    try:
        sigmas = noise_from_parameters(options)
        outcome = _identify(nominal, samples, sigmas, options, options['noise_source'])
    except (IdentificationError, postures.CalibrationError) as error:
        raise InputError(str(error)) from error

    run = RunDirectory.create(args.output_root)
    run.write_samples(samples)
    recording = recording_of(kind, path, source_dir)
    if recording is not None:
        atomic_copy(recording, run.file('recording.mcap'))
    if truth is not None:
        run.write_geometry(truth, name=TRUE_GEOMETRY_FILE, comment='true geometry (given)')
    if outcome.success:
        write_results(run, outcome, f'calibrated offline by gsp_reidentify from {path}')

    validation_before = validation_after = None
    if outcome.result is not None:
        validation_before, validation_after = _validate(truth, nominal, outcome, args)
        run_options = dict(
            options,
            source=str(path),
            source_kind=kind,
            truth_geometry_file=str(truth_path) if truth_path else None,
        )
        _write_result(
            run,
            outcome,
            nominal,
            run_options,
            (validation_before, validation_after, truth),
            None if args.no_report else 'Offline re-identification',
            not args.no_plots,
            tool='gsp_reidentify',
        )

    print(outcome_summary(outcome, reference=truth), file=out)
    for when, validation in (('before', validation_before), ('after', validation_after)):
        if validation is not None:  # mm, deg
            print(
                f'validation {when}: position mean {validation["position_mm_mean"]:.4g} mm, '
                f'max {validation["position_mm_max"]:.4g} mm; orientation mean '
                f'{validation["orientation_deg_mean"]:.4g} deg, max '
                f'{validation["orientation_deg_max"]:.4g} deg',
                file=out,
            )
    print(f'{RUN_DIRECTORY_LABEL}{run.path}', file=out)
    return (EXIT_OK if outcome.success else EXIT_FAILED), run.path


def stored_weights(stored, options, samples):
    """``(sigmas, noise_source, keys of result.json to keep)`` that identify a run again from
    its ``samples.csv`` exactly: ``stored`` is its ``result.json``, ``options`` its options."""
    source = options.get('noise_source', DEFAULTS['noise_source'])
    sigmas, kept = noise_from_parameters(options), ('collection', 'noise_estimates')
    if np.isfinite(samples.lag_sums).any():
        return sigmas, source, ('collection',)
    if source == stored.get('noise_source') == 'estimated' and stored.get('sigmas'):
        rows = SensorNoise.from_channels(stored['sigmas'])
        root = float(np.sqrt(np.median(samples.n_samples))) if len(samples) else 1.0
        sigmas = SensorNoise.from_channels({k: v * root for k, v in rows.channels().items()})
        return (
            sigmas,
            'configured',
            kept + ('noise_source', 'goodness_of_fit', 'fit_diagnosis', 'fit_accepted'),
        )
    return sigmas, source, kept


def _write_result(run, outcome, nominal, options, validation, title, plots, **extra):
    """Write ``result.json`` of ``outcome`` into ``run`` and, unless ``title`` is None, its report
    (with its PNGs if ``plots``); ``validation``: ``(before, after, truth)``, ``extra``: more keys
    of ``result.json``."""
    from gsp_calibrator.report.write import outcome_inputs, write_report, write_result_json

    before, after, truth = validation
    inputs = dataclasses.replace(
        outcome_inputs(outcome, nominal, options, **extra),
        validation_before=before,
        validation_after=after,
        truth=truth,
    ).completed(outcome.result)
    write_result_json(run, outcome.result, inputs)
    if title is not None:
        write_report(run, outcome.result, inputs, title, plots)


def refresh_report(run_dir, truth=None, validation_before=None, validation_after=None, plots=True):
    """Rewrite ``result.json`` and ``report.md`` (with its PNGs unless ``plots`` is false) of an
    existing run directory, identifying its samples again with its stored options (which gives
    its result exactly), e.g. once the truth is known and the calibrated geometry validated.
    ``validation_*``: :func:`gsp_calibrator.report.data.validation_errors` dicts. Returns the
    ``CalibrationOutcome``; :class:`InputError` if the directory is unusable."""
    source_dir = Path(run_dir)
    kind, path, _ = resolve_input(source_dir)
    args = build_parser().parse_args([str(source_dir)])
    options = resolve_options(args, stored_options(kind, path, source_dir))
    nominal = geometry_option(options['nominal_geometry_file'], 'nominal_geometry_file')
    samples = load_input(kind, path, options)
    stored = result_json(source_dir)
    sigmas, source, kept_keys = stored_weights(stored, options, samples)
    outcome = _identify(nominal, samples, sigmas, options, source)
    if outcome.result is None:
        raise InputError(f'{source_dir}: {outcome.message}')
    # The calibrator's own record of the collection (skips, drops) is kept as it was.
    kept = {key: value for key, value in stored.items() if key in kept_keys}
    options = dict(options, source=str(path), source_kind=kind)
    validation = (validation_before, validation_after, truth)
    _write_result(
        source_dir, outcome, nominal, options, validation, 'Calibration report', plots, **kept
    )
    return outcome


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        code, _ = reidentify(args)
    except InputError as error:
        print(f'gsp_reidentify: error: {error}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130
    return code


if __name__ == '__main__':
    sys.exit(main())
