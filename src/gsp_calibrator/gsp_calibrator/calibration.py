"""The calibration pipeline around the core, without ROS (pure).

1. :func:`choose_postures`: a seeded pool of valid postures under the nominal geometry, then the
   core's condition-number selection (``gsp_kinematics.selection.select_postures``).
2. :func:`identify_from_samples`: the core's ``identify`` on the averaged posture rows
   (``run_directory.Samples``), then checks: converged, and every free parameter identifiable
   (full rank of the column-scaled information matrix). A failed check gives
   ``CalibrationOutcome.success = False`` and a message naming the parameters; no geometry.
3. :func:`finish_run`: identification of a collected run, and its result files.
4. :func:`format_response` / :func:`parse_response`: the text of the Trigger response (a human
   summary, then the calibrated geometry params-file YAML).
"""

import dataclasses
import math
import time

import numpy as np

from gsp_kinematics import goodness, identifiability
from gsp_kinematics.device import device_readings
from gsp_kinematics.geometry import (
    ALL_PARAMETER_NAMES,
    ANGULAR_SENSOR_PARAMETERS,
    NUM_PARAMETERS,
    geometry_to_yaml,
    parameter_errors,
)
from gsp_kinematics.identification import (
    FORMULATIONS,
    IdentificationError,
    Sigmas,
    identify,
    resolve_free,
)
from gsp_kinematics.kinematics import (
    Workspace,
    home_pose,
    inverse_kinematics,
    sample_valid_postures,
)
from gsp_kinematics.rotation import wrap_angle
from gsp_kinematics.route import plan_route
from gsp_kinematics.selection import best_addition, posture_information, select_postures

#: Free parameters of the calibrator: the 44 and the identifiable sensor errors.
DEFAULT_FREE = ('extended',)
RESPONSE_SEPARATOR = '--- calibrated geometry (ROS 2 parameters file) ---'
RUN_DIRECTORY_LABEL = 'run directory: '
IDENTIFICATION_TIME_LABEL = 'identification time: '
#: Comment of the calibrated geometry file and the latched result.
RESULT_COMMENT = 'calibrated by gsp_calibrator'
#: Added to the result's comment when the goodness of fit rejects the model.
REJECTED_COMMENT = 'REJECTED by the goodness-of-fit check (p < 0.01): see result.json'


class CalibrationError(RuntimeError):
    """The calibration cannot go on; the message says why."""


# --- posture selection ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PostureSelection:
    """Postures chosen for a calibration."""

    poses: np.ndarray  #: (count, 6) commanded postures [x, y, z, psi, theta, phi], m and rad
    pool_indices: np.ndarray  #: (count,) their indices in the pool
    condition_number: float  #: scaled condition number of the selected set's information
    pool_size: int
    seed: int
    duration_s: float  #: wall time of the selection, s


def posture_pool(nominal, pool_size, seed, workspace=Workspace()):
    """``pool_size`` random postures (N, 6), reachable under ``nominal``, from ``seed``."""
    rng = np.random.default_rng(int(seed))
    return sample_valid_postures(nominal, int(pool_size), rng, workspace)


def selection_formulation(formulation):
    """The information model of the selection for an identification ``formulation``."""
    return 'implicit' if formulation == 'implicit' else 'fk'


def choose_postures(
    nominal,
    count,
    pool_size,
    seed,
    sigmas=Sigmas(),
    free=DEFAULT_FREE,
    formulation='implicit',
    workspace=Workspace(),
):
    """Select ``count`` postures from a seeded pool of ``pool_size`` (:class:`PostureSelection`)."""
    count, pool_size = int(count), int(pool_size)
    if count < 1:
        raise CalibrationError(f'posture count must be >= 1, got {count}')
    if pool_size < count:
        raise CalibrationError(f'pool_size ({pool_size}) must be >= posture_count ({count})')
    started = time.perf_counter()
    pool = posture_pool(nominal, pool_size, seed, workspace)
    indices, condition = select_postures(
        nominal,
        pool,
        count,
        sigmas,
        free=resolve_free(free),
        formulation=selection_formulation(formulation),
    )
    return PostureSelection(
        poses=pool[indices],
        pool_indices=np.asarray(indices),
        condition_number=float(condition),
        pool_size=pool_size,
        seed=int(seed),
        duration_s=time.perf_counter() - started,
    )


def posture_route(settings, poses):
    """The route (:func:`gsp_kinematics.route.plan_route`) through ``poses`` from the home pose
    (where platform_sim starts), with the run's nominal geometry and leg limits."""
    return plan_route(settings.nominal, home_pose(), poses, settings.motion_limits)


class PostureReplacer:
    """The replacement of a posture the platform rejected: the best remaining posture of the
    run's pool (:func:`gsp_kinematics.selection.best_addition`, the selection's criterion).

    Built once per run (the pool and its information, about 0.1 s); called with the run's poses
    (M, 6) and the 1-based postures rejected, it returns the pose (6,) to add, or None when the
    pool has none left. A pose that is not in the pool (another selection) counts as chosen
    only if it is.
    """

    def __init__(self, settings):
        self.pool = posture_pool(settings.nominal, settings.pool_size, settings.seed)
        self.information = posture_information(
            settings.nominal,
            self.pool,
            settings.sigmas,
            resolve_free(list(settings.free_parameters)),
            selection_formulation(settings.formulation),
        )

    def _pool_indices(self, poses):
        poses = np.asarray(poses, dtype=float).reshape(-1, 6)
        distance = np.max(np.abs(poses[:, None, :] - self.pool[None, :, :]), axis=2)
        nearest = np.argmin(distance, axis=1)
        return [
            int(i)
            for i, d in zip(nearest, distance[np.arange(len(poses)), nearest], strict=True)
            if d < 1e-9
        ]

    def __call__(self, poses, rejected):
        poses = np.asarray(poses, dtype=float).reshape(-1, 6)
        rejected_rows = [k - 1 for k in rejected]
        kept = [m for m in range(len(poses)) if m not in rejected_rows]
        chosen = self._pool_indices(poses[kept])
        excluded = self._pool_indices(poses[rejected_rows]) if rejected_rows else []
        try:
            index = best_addition(self.information, chosen, excluded)
        except ValueError:
            return None
        return self.pool[index].copy()


def selection_arguments(settings):
    """The positional arguments of :func:`choose_postures` and :func:`selection_key` for a run's
    ``CalibratorSettings``."""
    return (
        settings.nominal,
        settings.posture_count,
        settings.pool_size,
        settings.seed,
        settings.sigmas,
        list(settings.free_parameters),
        settings.formulation,
    )


def selection_key(nominal, count, pool_size, seed, sigmas, free, formulation):
    """A hashable key of everything :func:`choose_postures` depends on (for caching)."""
    return (
        tuple(np.round(nominal.to_full_vector(), 15)),
        nominal.limits,
        int(count),
        int(pool_size),
        int(seed),
        sigmas,
        tuple(resolve_free(free)),
        selection_formulation(formulation),
    )


# --- identifiability -----------------------------------------------------------------------------


def analyse_identifiability(result):
    """The core's identifiability analysis of an ``IdentificationResult``.

    ``{'rank', 'parameters' (free count), 'condition_number' (scaled Jacobian),
    'unidentifiable' (null directions), 'names' (every parameter in one, sorted)}``.
    """
    information = np.asarray(result.information, dtype=float)
    if not np.all(np.isfinite(information)):
        names = list(result.free_names)
        return {
            'rank': 0,
            'parameters': len(names),
            'condition_number': math.inf,
            'unidentifiable': [],
            'names': names,
        }
    analysis = identifiability.analyse_identifiability(information, result.free)
    analysis['names'] = identifiability.unidentifiable_parameters(analysis)
    return analysis


# --- identification ------------------------------------------------------------------------------


@dataclasses.dataclass
class CalibrationOutcome:
    """What :func:`identify_from_samples` found."""

    success: bool
    message: str  #: why it failed ('' on success)
    result: object = None  #: the core's IdentificationResult (None if identify raised)
    geometry: object = None  #: the calibrated Geometry, only on success
    identifiability: dict = dataclasses.field(default_factory=dict)
    postures: int = 0  #: posture rows given
    sigmas: object = None  #: the weights of the averaged rows
    duration_s: float = 0.0  #: identification wall time, s
    noise_estimates: dict = dataclasses.field(default_factory=dict)  #: goodness.estimate_noise
    verdict: str = ''  #: the goodness-of-fit verdict (plain text)

    @property
    def fit_accepted(self):
        """The goodness of fit accepts the model (p >= 0.01); False without a fit."""
        result = self.result
        return bool(
            result is not None and result.goodness_of_fit and result.goodness_of_fit.accepted
        )

    @property
    def unidentifiable(self):
        """Names of the parameters in a null direction (sorted; empty if identifiable)."""
        return list(self.identifiability.get('names', []))


def averaged_sigmas(sigmas, n_samples):
    """Weights of rows that average ``n_samples`` pairs: ``sigma / sqrt(n)`` (median n)."""
    n_samples = np.asarray(n_samples, dtype=float)
    if n_samples.size == 0 or not np.all(n_samples >= 1):
        return sigmas
    factor = 1.0 / math.sqrt(float(np.median(n_samples)))
    return Sigmas(
        leg_lengths=sigmas.leg_lengths * factor,
        inclinometer=sigmas.inclinometer * factor,
        encoder=sigmas.encoder * factor,
        lvdt=sigmas.lvdt * factor,
    )


def noise_channels(sigmas):
    """``{channel: configured per-sample sigma}`` of :func:`gsp_kinematics.goodness.estimate_noise`."""
    return {
        'leg_lengths': sigmas.leg_lengths,
        'inclinometer': sigmas.inclinometer,
        'encoder': sigmas.encoder,
        'lvdt': sigmas.lvdt,
    }


def identify_from_samples(
    nominal,
    samples,
    sigmas=Sigmas(),
    free=DEFAULT_FREE,
    formulation='implicit',
    within_posture_std=None,
    **identify_options,
):
    """Identify from averaged rows and check the result (:class:`CalibrationOutcome`).

    ``samples`` is a ``run_directory.Samples``; ``sigmas`` are per-sample noise levels (m, rad),
    scaled by :func:`averaged_sigmas`. The commanded postures start the pose estimates. Fails
    (``success=False``, message naming the parameters) when the identification raises, does not
    converge, or leaves free parameters unidentifiable. ``within_posture_std`` (M, 10): the
    sample standard deviation of the 6 legs and 4 readings within each posture, for the noise
    estimates (None: not estimated). A successful outcome carries the goodness-of-fit
    ``verdict``; :attr:`CalibrationOutcome.fit_accepted` says whether the model explains the data.
    """
    if formulation not in FORMULATIONS:
        raise CalibrationError(f'formulation must be one of {FORMULATIONS}, got {formulation!r}')
    free_mask = resolve_free(free)
    count = len(samples)
    row_sigmas = averaged_sigmas(sigmas, samples.n_samples)
    outcome = CalibrationOutcome(success=False, message='', postures=count, sigmas=row_sigmas)
    if count == 0:
        outcome.message = 'no posture was collected: nothing to identify'
        return outcome
    started = time.perf_counter()
    try:
        result = identify(
            nominal,
            samples.leg_lengths,
            samples.readings,
            row_sigmas,
            formulation=formulation,
            free=free_mask,
            pose_guesses=samples.commanded_poses,
            **identify_options,
        )
    except (IdentificationError, np.linalg.LinAlgError, ValueError) as error:
        outcome.duration_s = time.perf_counter() - started
        outcome.message = f'identification failed: {error}'
        return outcome
    outcome.duration_s = time.perf_counter() - started
    outcome.result = result
    if not result.converged:
        outcome.message = (
            f'identification did not converge after {result.iterations} iteration(s) '
            f'(status {result.status}: {result.message}); nothing applied'
        )
        return outcome
    analysis = analyse_identifiability(result)
    outcome.identifiability = analysis
    if analysis['names'] or analysis['rank'] < analysis['parameters']:
        names = analysis['names']
        combinations = [entry['combination'] for entry in analysis['unidentifiable']]
        shown = '; '.join(combinations[:5]) + (' ...' if len(combinations) > 5 else '')
        outcome.message = (
            f'non-identifiable parameters: the scaled information matrix has rank '
            f'{analysis["rank"]} of {analysis["parameters"]} with {count} posture(s); '
            f'not identifiable: {", ".join(names) if names else "(unnamed)"} '
            f'(null directions: {shown}). Add postures or fix these parameters '
            '(free_parameters); nothing applied'
        )
        return outcome
    outcome.success = True
    outcome.geometry = result.geometry
    if within_posture_std is not None and len(within_posture_std) == count:
        outcome.noise_estimates = goodness.estimate_noise(
            within_posture_std, samples.n_samples, noise_channels(sigmas)
        )
    outcome.verdict = goodness.verdict(
        result.goodness_of_fit,
        result.outliers,
        outcome.noise_estimates,
        free_sensor_errors=result.sensor_errors_free,
    )
    return outcome


def sensor_error_text(result):
    """``'kq1 +3.1e-04 (sd 2e-05), alpha0 +0.0101 deg (sd 0.0004)'`` of the free sensor errors."""
    parts = []
    for index, name in enumerate(ALL_PARAMETER_NAMES[NUM_PARAMETERS:], start=NUM_PARAMETERS):
        if not result.free[index]:
            continue
        value, deviation = result.parameters[index], result.standard_deviations[index]
        if name in ANGULAR_SENSOR_PARAMETERS:
            parts.append(
                f'{name} {math.degrees(value):+.4f} deg (sd {math.degrees(deviation):.2g})'
            )
        else:
            parts.append(f'{name} {value:+.2e} (sd {deviation:.1g})')
    return ', '.join(parts)


def _angle_or_length(channel, value):
    if channel in ('inclinometer', 'encoder'):
        return f'{math.degrees(value):.3g} deg'
    return f'{value * 1e6:.3g} um'


def fit_lines(outcome):
    """Summary lines of the goodness of fit, outliers, down-weighted postures and noise."""
    result = outcome.result
    lines = [outcome.verdict] if outcome.verdict else []
    if result is None:
        return lines
    if result.outliers:
        shown = ', '.join(
            f'{entry["posture"]} ({entry["sensor"]} {entry["max_normalised_residual"]:.1f} sigma)'
            for entry in result.outliers[:10]
        )
        lines.append(f'outlier postures (normalised residual > threshold): {shown}')
    if result.down_weighted:
        shown = ', '.join(
            f'{entry["posture"]} (weight {entry["weight"]:.3g})'
            for entry in result.down_weighted[:10]
        )
        lines.append(f'{result.loss} loss down-weighted postures: {shown}')
    for channel, entry in outcome.noise_estimates.items():
        lines.append(
            f'noise {channel}: estimated {_angle_or_length(channel, entry["estimated"])}, '
            f'configured {_angle_or_length(channel, entry["configured"])}'
            + (' -- WARNING: differs by more than 2x' if entry['warning'] else '')
        )
    return lines


def posture_residuals(nominal, commanded_pose, leg_lengths, readings):
    """Measured minus the nominal model at the commanded pose: ``{sensor: value}`` (m, rad).

    ``leg_lengths`` is the largest |q - IK(nominal, pose)| over the six legs; the device
    readings are ``alpha, beta, phi, d_m`` minus ``device_readings(nominal, pose)``.
    """
    pose = np.reshape(np.asarray(commanded_pose, dtype=float), (1, 6))
    legs = np.asarray(leg_lengths, dtype=float) - inverse_kinematics(nominal, pose)[0]
    device = np.asarray(readings, dtype=float) - device_readings(nominal, pose)[0]
    device[2] = wrap_angle(device[2])
    residuals = {'leg_lengths': float(np.max(np.abs(legs)))}
    residuals.update(
        {name: float(v) for name, v in zip(('alpha', 'beta', 'phi', 'd_m'), device, strict=True)}
    )
    return residuals


@dataclasses.dataclass(frozen=True)
class PostureReport:
    """How the calibrator reports the end of a posture: log lines and one progress message."""

    log: tuple  #: ``(('info' | 'warning', text), ...)``
    phase: str  #: progress phase
    message: str  #: progress message
    residuals: dict = None  #: :func:`posture_residuals` of a row
    warning: bool = False  #: progress level WARN
    skipped: int = None  #: the posture, when skipped


def posture_report(event, count, nominal):
    """The :class:`PostureReport` of a protocol ``RowReady`` or ``PostureSkipped`` ``event`` of a
    run of ``count`` postures under the ``nominal`` geometry."""
    from gsp_msgs_py.names import PHASE_COLLECTING, PHASE_MOVING

    k = event.posture
    if not hasattr(event, 'sample'):  # skipped
        text = f'posture {k} of {count} skipped: {event.reason}'
        log = (('warning', f'posture {k}/{count} skipped: {event.reason}'),)
        return PostureReport(log, PHASE_MOVING, text, warning=True, skipped=k)
    row = event.sample
    log = ()
    if event.dropped:
        log = (
            (
                'warning',
                f'posture {k}/{count}: dropped {event.dropped} synchronised sample(s) '
                'inconsistent with the rest (glitch, or a stream still reporting the '
                'previous posture)',
            ),
        )
    log += (('info', f'posture {k}/{count}: {row.n_samples} samples averaged'),)
    residuals = posture_residuals(nominal, event.pose, row.leg_lengths, row.readings)
    text = f'posture {k} of {count}: {row.n_samples} samples averaged'
    return PostureReport(log, PHASE_COLLECTING, text, residuals)


# --- reports -------------------------------------------------------------------------------------


def residual_summary(residual_rms):
    """``'legs 0.06 um, alpha 0.0003 deg, ...'`` of per-sensor residual RMS (m, rad)."""
    parts = []
    for name, value in residual_rms.items():
        if name in ('alpha', 'beta', 'phi'):
            parts.append(f'{name} {math.degrees(value):.2g} deg')
        else:
            parts.append(f'{"legs" if name == "leg_lengths" else name} {value * 1e6:.3g} um')
    return ', '.join(parts)


def outcome_summary(outcome, selected=None, skipped=(), run_directory=None, reference=None):
    """Human summary lines of a calibration (str, no trailing newline).

    ``selected``: postures commanded; ``skipped``: ``[(k, reason), ...]``; ``reference``: a
    geometry to print parameter errors against (e.g. the truth, in tests and the demo).
    """
    lines = []
    head = 'calibration succeeded' if outcome.success else 'calibration FAILED'
    used = f'{outcome.postures} posture(s)' + (f' of {selected} commanded' if selected else '')
    lines.append(f'{head}: {used}')
    if not outcome.success:
        lines.append(f'reason: {outcome.message}')
    for k, reason in skipped:
        lines.append(f'skipped posture {k}: {reason}')
    result = outcome.result
    if result is not None:
        lines.append(
            f'{result.formulation} formulation, {int(np.sum(result.free))} free parameter(s), '
            f'{result.iterations} iteration(s): {result.message}'
        )
        lines.append(f'{IDENTIFICATION_TIME_LABEL}{outcome.duration_s * 1000.0:.1f} ms')
        if result.residual_rms:
            lines.append(f'residual rms: {residual_summary(result.residual_rms)}')
    if outcome.identifiability:
        condition = outcome.identifiability.get('condition_number', math.inf)
        lines.append(
            f'identifiability: rank {outcome.identifiability.get("rank")} of '
            f'{outcome.identifiability.get("parameters")}, scaled condition number '
            f'{condition:.4g}'
        )
    if outcome.success and result is not None:
        deviations = result.standard_deviations
        free = np.asarray(result.free, dtype=bool)
        lengths = deviations[:43][free[:43]]
        if lengths.size:
            lines.append(
                f'largest standard deviation: {np.nanmax(lengths) * 1000.0:.4g} mm'
                + (f', gamma {math.degrees(deviations[43]):.3g} deg' if free[43] else '')
            )
        sensor_text = sensor_error_text(result)
        if sensor_text:
            lines.append(f'sensor errors: {sensor_text}')
    if outcome.success:
        lines.extend(fit_lines(outcome))
        if not outcome.fit_accepted:
            lines.append(
                'result REJECTED by the goodness-of-fit check: written but not applied '
                '(apply_rejected_fit applies it anyway)'
            )
    if outcome.success and reference is not None:
        errors = parameter_errors(outcome.geometry, reference)
        lines.append(
            f'parameter errors vs reference: max {np.max(np.abs(errors[:43])):.4g} mm, '
            f'gamma {abs(errors[43]):.3g} deg'
        )
    if run_directory is not None:
        lines.append(f'{RUN_DIRECTORY_LABEL}{run_directory}')
    return '\n'.join(lines)


def failure_message(error, collected, run):
    """The response text of a run that ended early with ``error`` after ``collected`` postures;
    ``run``: its ``RunDirectory`` (the rows are in its ``samples.csv``)."""
    from .run_directory import SAMPLES_FILE

    return (
        f'calibration FAILED after {collected} collected posture(s): {error}\n'
        f'{collected} posture(s) saved to {run.file(SAMPLES_FILE)}\n'
        f'{RUN_DIRECTORY_LABEL}{run.path}'
    )


def format_response(summary, geometry=None, node_name='/**'):
    """Trigger response message: the summary, then (on success) the geometry params file."""
    if geometry is None:
        return summary
    yaml_text = geometry_to_yaml(
        geometry, node_name=node_name, comment='calibrated by gsp_calibrator'
    )
    return f'{summary}\n{RESPONSE_SEPARATOR}\n{yaml_text}'


@dataclasses.dataclass(frozen=True)
class ParsedResponse:
    """A Trigger response message split into its parts."""

    summary: str
    geometry_yaml: str  #: '' when the response carries no geometry
    run_directory: str  #: '' when not named
    identification_ms: float  #: NaN when not given


def parse_response(message):
    """Split a calibrate response (see :func:`format_response`) into a :class:`ParsedResponse`."""
    summary, separator, geometry_yaml = message.partition('\n' + RESPONSE_SEPARATOR + '\n')
    if not separator:
        summary, geometry_yaml = message, ''
    run_directory, identification_ms = '', math.nan
    for line in summary.splitlines():
        if line.startswith(RUN_DIRECTORY_LABEL):
            run_directory = line[len(RUN_DIRECTORY_LABEL) :].strip()
        elif line.startswith(IDENTIFICATION_TIME_LABEL):
            try:
                identification_ms = float(line[len(IDENTIFICATION_TIME_LABEL) :].split()[0])
            except (ValueError, IndexError):
                pass
    return ParsedResponse(summary, geometry_yaml, run_directory, identification_ms)


@dataclasses.dataclass(frozen=True)
class FinishedRun:
    """What :func:`finish_run` did: the outcome, its human summary, and a report failure."""

    outcome: CalibrationOutcome
    summary: str
    report_error: str = ''  #: '' when result.json and report.md were written (or not due)


def finish_run(run, settings, samples, collection, options, within_posture_std=None):
    """Identify a collected run and write its files (pure; the node runs it in a worker thread).

    ``run``: the ``RunDirectory``; ``settings``: the run's ``CalibratorSettings``; ``samples``:
    the collected rows; ``collection``: the protocol's ``summary()`` (skipped postures, drops);
    ``options``: the run options stored with the results; ``within_posture_std``: see
    :func:`identify_from_samples`. Writes ``result.json``, ``report.md``
    and its PNGs when identification gives a result (a failure there is returned, never raised:
    the report must not fail the run) and ``result.yaml`` when the calibration succeeded.
    """
    import traceback

    from . import report
    from .run_directory import RESULT_FILE

    outcome = identify_from_samples(
        settings.nominal,
        samples,
        settings.sigmas,
        list(settings.free_parameters),
        settings.formulation,
        within_posture_std,
        options=settings.identify_options(),
    )
    skipped = [(entry['posture'], entry['reason']) for entry in collection['skipped']]
    summary = outcome_summary(
        outcome, selected=settings.posture_count, skipped=skipped, run_directory=run.path
    )
    report_error = ''
    if outcome.result is not None:
        try:
            report.write_all(
                run.path,
                outcome.result,
                **report.outcome_arguments(
                    outcome, settings.nominal, options, collection=collection
                ),
            )
        except Exception as error:
            report_error = f'{error}\n{traceback.format_exc()}'
    if outcome.success:
        comment = RESULT_COMMENT + ('' if outcome.fit_accepted else f'\n{REJECTED_COMMENT}')
        run.write_geometry(outcome.geometry, RESULT_FILE, comment=comment)
    return FinishedRun(outcome, summary, report_error)
