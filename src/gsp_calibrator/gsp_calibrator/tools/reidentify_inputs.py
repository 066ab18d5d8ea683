"""The inputs of a re-identification (``gsp_reidentify``): a run directory (its ``samples.csv``,
else its ``recording.mcap``), a ``samples.csv`` or a ``recording.mcap``; the run options stored
with them and the geometries they name (pure, no ROS graph)."""

import json
import math
import sys
from pathlib import Path

from gsp_calibrator.recording.recorder import ACCEPTANCE_OPTIONS
from gsp_calibrator.run.directory import SAMPLES_FILE, RunDirectoryError, read_samples
from gsp_calibrator.run.postures import DEFAULT_FREE
from gsp_calibrator.settings import DEFAULTS, check_free_parameters
from gsp_kinematics.geometry import GeometryError, default_geometry_path, load_geometry
from gsp_kinematics.goodness import LOSSES
from gsp_kinematics.identification import FORMULATIONS
from gsp_kinematics.noise_from_data import NOISE_SOURCES
from gsp_kinematics.sensors.noise import SensorNoise


class InputError(ValueError):
    """Unusable input; the message names the file (and row/column) at fault."""


#: Sigma options: (name, command-line option, metavar, what one sample is and its unit).
_SIGMA_OPTIONS = (
    ('sigma_leg_lengths', '--sigma-leg-lengths', 'M', 'leg-length sample, m'),
    ('sigma_inclinometer', '--sigma-inclinometer', 'RAD', 'inclinometer sample, rad'),
    ('sigma_encoder', '--sigma-encoder', 'RAD', 'encoder sample, rad'),
    ('sigma_lvdt', '--sigma-lvdt', 'M', 'LVDT sample, m'),
)


def free_parameters(values):
    """Names from ``--free`` (space or comma separated); InputError naming unknown ones."""
    if values is None:
        return None
    names = [n.strip() for value in values for n in value.split(',') if n.strip()]
    reason = check_free_parameters(names)
    if reason:
        raise InputError(f'--free: {reason}')
    return names


def result_json(source_dir):
    """The run directory's ``result.json`` as a dict ({} if none or unreadable)."""
    if source_dir is None or not (source_dir / 'result.json').is_file():
        return {}
    try:
        with open(source_dir / 'result.json', encoding='utf-8') as stream:
            data = json.load(stream)
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def stored_options(kind, path, source_dir):
    """Run options stored with the input: the run directory's ``result.json`` ``options``, then
    (overriding) those of the recording."""
    options = dict(result_json(source_dir).get('options') or {})
    recording_path = (
        path
        if kind == 'mcap'
        else (source_dir / 'recording.mcap' if source_dir is not None else None)
    )
    if recording_path is not None and Path(recording_path).is_file():
        from gsp_calibrator.recording.recorder import RecordingError, recording_options

        try:
            options.update(recording_options(recording_path))
        except RecordingError as error:
            if kind == 'mcap':
                raise InputError(str(error)) from error
    return options


def resolve_options(args, stored):
    """``{name: value}`` of every run option: the command line, else ``stored``, else defaults."""

    def pick(value, name):
        if value is not None:
            return value
        return stored.get(name, DEFAULTS[name])

    options = {name: pick(getattr(args, name), name) for name, *_ in _SIGMA_OPTIONS}
    for name, option, *_ in _SIGMA_OPTIONS:
        value = options[name]
        try:
            value = float(value)
        except (TypeError, ValueError):
            value = math.nan
        if not (math.isfinite(value) and value > 0.0):
            raise InputError(f'{option}: {options[name]!r} rejected, must be a finite number > 0')
        options[name] = value
    options['formulation'] = pick(args.formulation, 'formulation')
    if options['formulation'] not in FORMULATIONS:
        raise InputError(
            f'formulation {options["formulation"]!r} (stored) is not one of {list(FORMULATIONS)}'
        )
    options['noise_source'] = pick(args.noise_source, 'noise_source')
    if options['noise_source'] not in NOISE_SOURCES:
        raise InputError(
            f'noise source {options["noise_source"]!r} (stored) is not one of {list(NOISE_SOURCES)}'
        )
    for name in ACCEPTANCE_OPTIONS:  # no command-line option: the stored ones, else defaults
        options[name] = stored.get(name, DEFAULTS[name])
    options['loss'] = pick(args.loss, 'loss')
    if options['loss'] not in LOSSES:
        raise InputError(f'loss {options["loss"]!r} (stored) is not one of {list(LOSSES)}')
    if args.free is not None:
        options['free_parameters'] = free_parameters(args.free)
    elif stored.get('free_parameters'):
        options['free_parameters'] = free_parameters(list(stored['free_parameters']))
    else:
        options['free_parameters'] = list(DEFAULT_FREE)
    options['samples_per_posture'] = int(pick(args.samples_per_posture, 'samples_per_posture'))
    options['sync_tolerance'] = float(pick(args.sync_tolerance, 'sync_tolerance'))
    if options['samples_per_posture'] < 1:
        raise InputError('--samples-per-posture must be >= 1')
    if not (math.isfinite(options['sync_tolerance']) and options['sync_tolerance'] >= 0.0):
        raise InputError('--sync-tolerance must be finite and >= 0 s')
    nominal = args.nominal
    if nominal is None:
        nominal = stored.get('nominal_geometry_file')
        if not nominal or not Path(nominal).is_file():
            if nominal:
                print(
                    f"gsp_reidentify: warning: the run's nominal geometry {nominal} is not "
                    'available: using the shipped nominal',
                    file=sys.stderr,
                )
            nominal = default_geometry_path('nominal')
    options['nominal_geometry_file'] = str(nominal)
    return options


def geometry_option(path, option):
    try:
        return load_geometry(path)
    except (GeometryError, OSError) as error:
        raise InputError(f'{option} {path}: {error}') from error


def recover_unfinished_recordings(run_path):
    """Finalise the ``recording*.mcap.tmp`` a killed calibrator left in ``run_path`` (never one a
    live calibrator is still writing: see its ``state.json``)."""
    from gsp_calibrator.recording.recorder import RecordingError, recover_recordings
    from gsp_calibrator.run import state as run_state

    if not any(p.name.endswith('.mcap.tmp') for p in run_path.iterdir()):
        return
    try:
        state = run_state.read_state(run_path)
    except run_state.ResumeRefused:
        state = None
    if state is not None and not run_state.resumable(state) and state.phase != 'done':
        return  # still being written
    try:
        for recovered in recover_recordings(run_path):
            print(
                f'gsp_reidentify: recovered {recovered["message_count"]} messages into '
                f'{recovered["path"]}',
                file=sys.stderr,
            )
    except (RecordingError, OSError) as error:
        raise InputError(f'{run_path}: cannot recover the recording ({error})') from error


def resolve_input(path):
    """``(kind, path, run_directory or None)``: kind ``'csv'`` or ``'mcap'``."""
    path = Path(path)
    if path.is_dir():
        recover_unfinished_recordings(path)
        if (path / SAMPLES_FILE).is_file():
            return 'csv', path / SAMPLES_FILE, path
        from gsp_calibrator.recording.recorder import RECORDING_FILE

        if (path / RECORDING_FILE).is_file():
            return 'mcap', path / RECORDING_FILE, path
        raise InputError(f'{path}: run directory without {SAMPLES_FILE} or recording.mcap')
    if not path.exists():
        raise InputError(f'{path}: no such file or directory')
    if path.suffix.lower() == '.mcap':
        return 'mcap', path, None
    if path.suffix.lower() == '.csv':
        return 'csv', path, None
    raise InputError(f'{path}: expected a run directory, a samples.csv or a recording.mcap')


def load_input(kind, path, options):
    """The posture rows (``Samples``) of a samples.csv, or rebuilt from a recording.mcap."""
    if kind == 'csv':
        try:
            samples = read_samples(path)
        except RunDirectoryError as error:
            raise InputError(str(error)) from error
    else:
        from gsp_calibrator.recording.rebuild import samples_from_recording
        from gsp_calibrator.recording.recorder import (
            RECORDING_FILE,
            RecordingError,
            recording_parts,
        )

        # A resumed run recorded into recording.mcap, recording-2.mcap ...: read every part.
        parts = recording_parts(Path(path).parent) if Path(path).name == RECORDING_FILE else []

        noise_std = SensorNoise.from_parameters(options).channel_std()
        try:
            samples = samples_from_recording(
                parts or path, options['sync_tolerance'], options['samples_per_posture'], noise_std
            )
        except RecordingError as error:
            raise InputError(str(error)) from error
    if len(samples) == 0:
        raise InputError(
            f'{path}: no posture rows'
            + (' (no posture completed in the recording)' if kind == 'mcap' else '')
        )
    return samples
