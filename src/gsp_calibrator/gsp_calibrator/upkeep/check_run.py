"""A check of the platform as the calibrator runs it (pure, no rclpy; docs/upkeep.md)."""

import dataclasses
import math
from pathlib import Path

from gsp_calibrator.files import history
from gsp_calibrator.files.calibration_files import (
    CHECK_JSON,
    RESULT_JSON,
    CalibrationFileError,
    calibration_from_result,
    read_json,
)
from gsp_calibrator.files.run_directory import RESULT_FILE
from gsp_calibrator.run.postures import posture_pool
from gsp_kinematics.model.geometry import GeometryError, load_geometry
from gsp_kinematics.model.sensor_noise import NOISE_FIELDS, SensorNoise
from gsp_kinematics.upkeep import check


class CheckError(RuntimeError):
    """A check cannot run; the message says why."""


@dataclasses.dataclass(frozen=True)
class CheckReference:
    """What a check compares the platform with."""

    geometry: object  #: the Geometry the controller runs
    source: str  #: where it came from (a result.yaml path)
    calibration: object = None  #: its drift.Calibration (covariance), None if unknown
    noise: SensorNoise | None = None  #: per-sample noise the calibration estimated
    unmodelled: SensorNoise | None = None  #: per-row error its model left unexplained
    run_dir: str = ''  #: the calibration's run directory ('' if unknown)


def _noise_of(data, key):
    """A SensorNoise of result.json's ``noise_estimates[channel][key]`` (None if absent)."""
    estimates = data.get('noise_estimates') or {}
    values = {channel: (estimates.get(channel) or {}).get(key) for channel in NOISE_FIELDS}
    if any(value is None for value in values.values()):
        return None
    return SensorNoise(**{channel: float(value) for channel, value in values.items()})


def reference_from_run(run_dir):
    """The :class:`CheckReference` of a calibration's run directory (its result.yaml and
    result.json)."""
    run_dir = Path(run_dir)
    try:
        geometry = load_geometry(run_dir / RESULT_FILE)
    except (OSError, GeometryError) as error:
        raise CheckError(f'{run_dir}: no usable {RESULT_FILE} to check ({error})') from None
    calibration, noise, unmodelled = None, None, None
    if (run_dir / RESULT_JSON).is_file():
        try:
            data = read_json(run_dir / RESULT_JSON)
            calibration = calibration_from_result(data, run_dir / RESULT_JSON)
        except (CalibrationFileError, ValueError):
            data = {}
        noise = _noise_of(data, 'estimated')
        unmodelled = _noise_of(data, 'unmodelled')
    return CheckReference(
        geometry, str(run_dir / RESULT_FILE), calibration, noise, unmodelled, str(run_dir)
    )


def latest_calibration(output_root, platform):
    """The run directory of ``platform``'s latest applied calibration: from the history under
    ``output_root``, else the newest run directory there with a ``result.yaml`` and no
    ``check.json``; None if there is none."""
    database = history.database_path(output_root)
    if database.is_file():
        found = history.runs(database, platform, 'calibration')
        applied = [entry for entry in found if entry['success'] and Path(entry['run_dir']).is_dir()]
        if applied:
            return Path(applied[-1]['run_dir'])
    root = Path(output_root)
    if not root.is_dir():
        return None
    candidates = [
        path
        for path in sorted(root.iterdir())
        if (path / RESULT_FILE).is_file() and not (path / CHECK_JSON).exists()
    ]
    return candidates[-1] if candidates else None


def check_reference(output_root, platform, geometry_file=''):
    """What to check: ``geometry_file`` (a calibration's ``result.yaml``; its run directory's
    result.json gives the covariance and noise) or ``platform``'s latest calibration."""
    if geometry_file:
        path = Path(geometry_file)
        if path.name == RESULT_FILE and (path.parent / RESULT_JSON).is_file():
            return reference_from_run(path.parent)
        try:
            return CheckReference(load_geometry(path), str(path))
        except (OSError, GeometryError) as error:
            raise CheckError(f'check_geometry_file: {error}') from None
    run_dir = latest_calibration(output_root, platform)
    if run_dir is None:
        raise CheckError(
            f'no calibration of platform {platform!r} under {output_root} to check: run a '
            'calibration first, or give check_geometry_file'
        )
    return reference_from_run(run_dir)


def check_plan(reference, start_pose, pool_size, seed, sigmas, samples, limits):
    """The check's postures (``gsp_kinematics.upkeep.check.CheckPlan``) from a pool of ``pool_size``
    postures (``seed``) reachable under the checked geometry, from ``start_pose``."""
    pool = posture_pool(reference.geometry, pool_size, seed)
    return check.choose_check_postures(
        reference.geometry, pool, start_pose, sigmas.averaged([samples]), samples, limits=limits
    )


def row_noise(reference, sigmas, n_samples):
    """The noise of the check's rows: the calibration's estimated per-sample noise (else
    ``sigmas``) averaged over ``n_samples``, and the unmodelled error it found added in
    quadrature (averaging does not reduce it)."""
    per_sample = reference.noise or sigmas
    rows = per_sample.averaged(n_samples).channels()
    if reference.unmodelled is not None:
        extra = reference.unmodelled.channels()
        rows = {name: math.hypot(value, extra[name]) for name, value in rows.items()}
    return SensorNoise(**rows)


def evaluate_check(reference, samples, sigmas, required, platform, planned_s=None):
    """The check's verdict (a JSON-ready dict, ``check.json``) from the collected ``samples``
    (``files.run_directory.Rows``) with the per-sample noise ``sigmas`` and the
    ``check.Requirement`` ``required``."""
    if len(samples) < 2:
        raise CheckError(f'a check needs at least 2 postures, {len(samples)} collected')
    rows = row_noise(reference, sigmas, samples.n_samples)
    data = check.check_platform(
        reference.geometry,
        samples.leg_lengths,
        samples.readings,
        samples.commanded_poses,
        rows,
        required,
        reference.calibration,
    )
    data |= {
        'platform_id': platform,
        'checked_geometry': reference.source,
        'calibration_run': reference.run_dir,
        'postures': len(samples),
        'planned_platform_time_s': planned_s,
        'row_noise': rows.channels(),
        'noise_from': 'the calibration' if reference.noise is not None else 'configured sigmas',
        'unmodelled_included': reference.unmodelled is not None,
    }
    return data


def check_summary(data):
    """The check's text: verdict, accuracy now with its uncertainty, why, the legs that moved."""
    accuracy, required = data['accuracy'], data['required']
    lines = [
        f'check: {data["verdict"].upper()} (platform {data.get("platform_id")}, '
        f'{data.get("postures")} postures)',
        f'accuracy now: position {accuracy["position_mm_mean"]:.4f} '
        f'+- {accuracy["position_mm_sigma"]:.4f} mm, phi {accuracy["orientation_deg_mean"]:.5f} '
        f'+- {accuracy["orientation_deg_sigma"]:.5f} deg (mean over the checked postures, noise '
        f'removed; required {required["position_mm"]} mm, {required["orientation_deg"]} deg)',
    ]
    change = data.get('change')
    if change is not None:
        test = change['global_test']
        lines.append(
            f'change since the calibration (leg offsets): chi2 {test["statistic"]:.1f} on '
            f'{test["dof"]} dof, p = {test["p_value"]:.3g}'
        )
    for reason in data['reasons']:
        lines.append(f'  why: {reason}')
    for note in data.get('notes', []):
        lines.append(f'  note: {note}')
    for entry in data['moved']:
        likely = ' (the likeliest; not significant alone)' if entry.get('likely') else ''
        lines.append(
            f'  moved: {entry["parameter"]} {entry["change_report"]:+.4f} '
            f'+- {entry["sigma_report"]:.4f} {entry["unit"]}{likely}'
        )
    if data.get('planned_platform_time_s') is not None:
        lines.append(f'planned platform time: {data["planned_platform_time_s"]:.1f} s')
    return '\n'.join(lines)
