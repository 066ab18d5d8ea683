"""The inputs of a re-identification (``gsp_reidentify``): a run directory (its ``samples.csv``,
else its ``recording.mcap``), a ``samples.csv`` or a ``recording.mcap``; the run options stored
with them and the geometries they name (pure, no ROS graph)."""

import contextlib
import json
import sys
from pathlib import Path

from gsp_calibrator.files.run_directory import SAMPLES_FILE, RunDirectoryError, read_samples
from gsp_calibrator.recording.mcap_format import RecordingError
from gsp_calibrator.recording.mcap_io import recording_options, recover_recordings
from gsp_calibrator.settings import DEFAULTS, REIDENTIFY_COMMAND_LINE, names_in, option_value
from gsp_kinematics.model.geometry import GeometryError, default_geometry_path, load_geometry
from gsp_msgs_py.noise_parameters import noise_from_parameters


class InputError(ValueError):
    """Unusable input; the message names the file (and row/column) at fault."""


#: The options ``gsp_reidentify`` takes of the calibrator's parameters (its ``--nominal`` aside).
OPTION_PARAMETERS = names_in(REIDENTIFY_COMMAND_LINE)


def result_json(source_dir):
    """The run directory's ``result.json`` as a dict ({} if none or unreadable)."""
    if source_dir is not None:
        with contextlib.suppress(OSError, ValueError):
            data = json.loads((source_dir / 'result.json').read_text(encoding='utf-8'))
            return data if isinstance(data, dict) else {}
    return {}


def recording_of(kind, path, source_dir):
    """The input's recording: ``path`` itself, else its run directory's (None if none)."""
    if kind == 'mcap':
        return path
    if source_dir is not None and (source_dir / 'recording.mcap').is_file():
        return source_dir / 'recording.mcap'
    return None


def stored_options(kind, path, source_dir):
    """Run options stored with the input: the run directory's ``result.json`` ``options``, then
    (overriding) those of the recording."""
    options = dict(result_json(source_dir).get('options') or {})
    recording_path = recording_of(kind, path, source_dir)
    if recording_path is not None:
        try:
            options.update(recording_options(recording_path))
        except RecordingError as error:
            if kind == 'mcap':
                raise InputError(str(error)) from error
    return options


def resolve_options(args, stored):
    """``{name: value}`` of every run option: the command line, else ``stored``, else defaults;
    each checked by the calibrator parameter's own check (InputError naming the option)."""
    options = {}
    for name in OPTION_PARAMETERS:
        given = getattr(args, name)
        value = given if given is not None else stored.get(name)
        if value is None or value == []:
            value = DEFAULTS[name]
        try:
            options[name] = option_value(name, value)
        except ValueError as error:
            raise InputError(f'{error}{"" if given is not None else " (stored)"}') from None
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
    # Stored only (not options), for the compliance: where the payload's mass sits, the legs'.
    for name, count in (('payload_centre_of_mass', 3), ('leg_mass', 6)):
        value = stored.get(name) or DEFAULTS[name]
        try:
            options[name] = [float(v) for v in value]
        except (TypeError, ValueError):
            raise InputError(f'{name}: {value!r} (stored) is not {count} numbers') from None
    return options


def geometry_option(path, option):
    try:
        return load_geometry(path)
    except (GeometryError, OSError) as error:
        raise InputError(f'{option} {path}: {error}') from error


def recover_unfinished_recordings(run_path):
    """Finalise the ``recording*.mcap.tmp`` a killed calibrator left in ``run_path`` (never one a
    live calibrator is still writing: see its ``state.json``)."""
    from gsp_calibrator.run.record import ResumeRefused, read_state, resumable

    if not any(p.name.endswith('.mcap.tmp') for p in run_path.iterdir()):
        return
    try:
        state = read_state(run_path)
    except ResumeRefused:
        state = None
    if state is not None and not resumable(state) and state.phase != 'done':
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
        if (path / 'recording.mcap').is_file():
            return 'mcap', path / 'recording.mcap', path
        raise InputError(f'{path}: run directory without {SAMPLES_FILE} or recording.mcap')
    if not path.exists():
        raise InputError(f'{path}: no such file or directory')
    if path.suffix.lower() == '.mcap':
        return 'mcap', path, None
    if path.suffix.lower() == '.csv':
        return 'csv', path, None
    raise InputError(f'{path}: expected a run directory, a samples.csv or a recording.mcap')


def load_input(kind, path, options):
    """The posture rows (``Rows``) of a samples.csv, or rebuilt from a recording.mcap."""
    if kind == 'csv':
        try:
            samples = read_samples(path)
        except RunDirectoryError as error:
            raise InputError(str(error)) from error
    else:
        from gsp_calibrator.recording.rebuild import samples_from_recording
        from gsp_calibrator.recording.recorder import RECORDING_FILE, recording_parts

        # A resumed run recorded into recording.mcap, recording-2.mcap ...: read every part.
        parts = recording_parts(Path(path).parent) if Path(path).name == RECORDING_FILE else []

        noise_std = noise_from_parameters(options).channel_std()
        try:
            samples = samples_from_recording(
                parts or path,
                options['sync_tolerance'],
                options['pairs_per_posture'],
                noise_std,
                nominal=geometry_option(options['nominal_geometry_file'], '--nominal'),
            )
        except RecordingError as error:
            raise InputError(str(error)) from error
    if len(samples) == 0:
        raise InputError(
            f'{path}: no posture rows'
            + (' (no posture completed in the recording)' if kind == 'mcap' else '')
        )
    return samples
