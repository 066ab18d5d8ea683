"""Identification of a collected run and its result files (pure, no rclpy).
See docs/verdict.md."""

import dataclasses
import math
import time
import traceback
import typing

import numpy as np

from gsp_calibrator.collection.approach import effect_design, reference_instant
from gsp_calibrator.collection.events import ELSEWHERE_CAUSES
from gsp_calibrator.files.run_directory import RESULT_FILE, RIGID_RESULT_FILE
from gsp_calibrator.report.accuracy import prediction_for
from gsp_calibrator.report.data import settle_line
from gsp_calibrator.report.effects import effects_record, untried_groups
from gsp_calibrator.report.write import outcome_inputs, write_all
from gsp_calibrator.run.postures import (
    DEFAULT_FREE,
    CalibrationError,
    route_additions_line,
    workspace_poses,
)
from gsp_calibrator.run.response import RESULT_COMMENT, outcome_summary
from gsp_calibrator.run.rigid import Verdicts, rigid_result
from gsp_kinematics.estimation import identifiability, noise_from_data
from gsp_kinematics.estimation.goodness import fit_diagnosis
from gsp_kinematics.estimation.identification import (
    DEFAULT_FORMULATION,
    FORMULATIONS,
    IdentificationError,
    Options,
    resolve_free,
)
from gsp_kinematics.estimation.prediction import accuracy_summary, thermal_strain_rms
from gsp_kinematics.estimation.verdict import acceptance
from gsp_kinematics.estimation.verdict.cross_validation import DEFAULT_FOLDS, cross_validate
from gsp_kinematics.estimation.verdict.model_choice import (
    DEFAULT_THERMAL_TIME_CONSTANTS,
    choose_model,
)
from gsp_kinematics.model.device import DeviceModelError, distance_from_commands
from gsp_kinematics.model.effect_groups import AUTO, effect_groups_of, is_effect_name, split_auto
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoise

#: Added to the rigid geometry's comment (result_rigid.yaml).
RIGID_COMMENT = (
    'rigid: the identified effects folded in, for a controller without geometry.effects.* '
    '(docs/platform_effects.md)'
)
#: Said when the device readings do not fit the device model at all.
DEVICE_MODEL_HINT = (
    ': the device readings do not fit the device model (swapped, mis-signed or mis-scaled '
    'device channels? check the inclinometer, encoder and LVDT wiring and units)'
)
#: Added to the result's comment when the calibration is not accepted (not applied).
NOT_ACCEPTED_COMMENT = 'NOT ACCEPTED (not applied): see the verdict in result.json'


class RowWeights(typing.NamedTuple):
    """What weighs the averaged rows in the fit."""

    sigmas: SensorNoise  #: each row's noise (the configured noise averaged over its samples)
    within: object  #: the within-posture noise estimated from the rows' lag sums
    design: object  #: the run's ``EffectDesign`` (times, approach directions, payload)


class Fit(typing.NamedTuple):
    """What :func:`_fit` found."""

    result: object  #: the core's IdentificationResult
    estimates: dict  #: the noise estimates per channel (``noise_from_data``)
    sigmas: SensorNoise  #: the row weights used
    effects: object  #: the ``EffectDesign`` when effects were freed, else None
    choice: object  #: the ``ModelChoice`` of ``auto``, else None
    untried: dict | None  #: ``{effect group not tried: why}`` of ``auto``, else None


class Judging(typing.NamedTuple):
    """What a result is judged with."""

    requirement: acceptance.Requirement
    folds: int  #: cross-validation folds
    identify_options: dict  #: the core's options (``options``: LM options)
    workspace: np.ndarray  #: (M,) bool: the rows commanded at the workspace postures


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
    noise_estimates: dict = dataclasses.field(default_factory=dict)  #: ``noise_record``, SI
    noise_source: str = noise_from_data.DEFAULT_NOISE_SOURCE  #: 'estimated' or 'configured'
    fit_diagnosis: str = ''  #: the goodness-of-fit diagnosis (plain text): a diagnostic
    accuracy: dict | None = None  #: the cross-validated accuracy (None: not measured)
    unmodelled: object = None  #: SensorNoise the model leaves unexplained (None: none shown)
    prediction: dict | None = None  #: the predicted accuracy (``report.accuracy``)
    judgement: object = None  #: ``acceptance.Verdict`` (None: no result to judge)
    requirement: object = None  #: the ``acceptance.Requirement`` judged against
    effects: dict | None = None  #: ``report.effects.effects_record`` (None: none chosen, freed)
    rigid_geometry: object = None  #: the effects folded in (``run.rigid``; None: no effects)
    rigid_accuracy: dict | None = None  #: its held-out accuracy (``run.rigid.judge_rigid``)
    rigid_judgement: object = None  #: and its verdict

    @property
    def accepted(self):
        """The calibration meets the requirement and beats the nominal geometry: apply it."""
        return bool(self.success and self.judgement is not None and self.judgement.accepted)

    @property
    def verdicts(self):
        """``run.rigid.Verdicts``: the compensating and the rigid geometry's verdicts."""
        return Verdicts(self.judgement if self.success else None, self.rigid_judgement)

    @property
    def fit_accepted(self):
        """The goodness of fit accepts the model (p >= 0.01); False without a fit."""
        goodness = self.result.goodness_of_fit if self.result is not None else None
        return bool(goodness and goodness.accepted)


def _unidentifiable_message(analysis, count):
    """Why a rank-deficient result is not applied: the rank, the names, the null directions."""
    names = analysis['names']
    combinations = [entry['combination'] for entry in analysis['unidentifiable']]
    shown = '; '.join(combinations[:5]) + (' ...' if len(combinations) > 5 else '')
    return (
        f'non-identifiable parameters: the scaled information matrix has rank '
        f'{analysis["rank"]} of {analysis["parameters"]} with {count} posture(s); '
        f'not identifiable: {", ".join(names) if names else "(unnamed)"} '
        f'(null directions: {shown}). Add postures or fix these parameters '
        '(free_parameters); nothing applied'
    )


def _rows_elsewhere(nominal, samples, max_posture_error):
    """Why rows of ``samples`` whose device position is more than ``max_posture_error`` (m)
    from the command cannot be identified ('' without any; a NaN row is the fit's to name)."""
    distances = distance_from_commands(nominal, samples.commanded_poses, samples.readings)
    elsewhere = np.flatnonzero(distances > max_posture_error)
    if not elsewhere.size:
        return ''
    return (
        f'the device measures the platform {np.min(distances[elsewhere]) * 1e3:.0f}-'
        f'{np.max(distances[elsewhere]) * 1e3:.0f} mm from the commanded position at '
        f'posture(s) {samples.posture[elsewhere].tolist()} (max_posture_error '
        f'{max_posture_error * 1e3:.0f} mm): it was not where it was sent '
        f'({ELSEWHERE_CAUSES}): delete those rows from samples.csv'
    )


def identify_from_samples(
    nominal,
    samples,
    sigmas=DEFAULT_SENSOR_NOISE,
    free=DEFAULT_FREE,
    formulation=DEFAULT_FORMULATION,
    noise_source=noise_from_data.DEFAULT_NOISE_SOURCE,
    requirement=acceptance.Requirement(),
    folds=DEFAULT_FOLDS,
    payload_mass=0.0,
    centre_of_mass=(0.0, 0.0, 0.0),
    workspace_poses=None,
    leg_mass=(0.0,) * 6,
    max_posture_error=math.inf,
    **identify_options,
):
    """Identify from the averaged rows ``samples`` (``Rows``; ``sigmas``: per-sample noise, m and
    rad) and judge the result (:class:`CalibrationOutcome`; docs/verdict.md): a failure
    (``success=False``) names why; a success is cross-validated, its accuracy measured on the
    rows commanded at ``workspace_poses`` (K, 6; None: every row), and judged."""
    free = _checked_free(free, formulation, noise_source)
    count = len(samples)
    row_sigmas = sigmas.averaged(samples.n_samples)
    outcome = CalibrationOutcome(
        success=False, message='', postures=count, sigmas=row_sigmas, noise_source=noise_source
    )
    if count == 0:
        outcome.message = 'no posture was collected: nothing to identify'
        return outcome
    outcome.message = _rows_elsewhere(nominal, samples, max_posture_error)
    if outcome.message:
        return outcome
    within = noise_from_data.within_row_noise(samples.lag_sums, samples.n_samples)
    design = effect_design(samples, payload_mass, centre_of_mass, leg_mass)
    started = time.perf_counter()
    try:
        weights = RowWeights(row_sigmas, within, design)
        fit = _fit(nominal, samples, weights, free, formulation, noise_source, identify_options)
    except (IdentificationError, DeviceModelError, np.linalg.LinAlgError, ValueError) as error:
        hint = DEVICE_MODEL_HINT if isinstance(error, DeviceModelError) else ''
        outcome.message = f'identification failed: {error}{hint}'
        return outcome
    finally:
        outcome.duration_s = time.perf_counter() - started
    outcome.result = result = fit.result
    outcome.sigmas = fit.sigmas
    if not result.converged:
        outcome.message = (
            f'identification did not converge after {result.iterations} iteration(s) '
            f'(status {result.status}: {result.message}); nothing applied'
        )
        return outcome
    _, stamp = reference_instant(samples)
    design = fit.effects or design
    outcome.effects = effects_record(result, design, nominal, fit.choice, fit.untried, stamp)
    analysis = identifiability.analyse_result(result)
    outcome.identifiability = analysis
    if not identifiability.identifies_all(analysis):
        outcome.message = _unidentifiable_message(analysis, count)
        return outcome
    outcome.success = True
    outcome.geometry = result.geometry
    outcome.noise_estimates = noise_from_data.noise_record(fit.estimates, sigmas, samples.n_samples)
    outcome.fit_diagnosis = fit_diagnosis(
        result.goodness_of_fit,
        result.outliers,
        outcome.noise_estimates,
        free_sensor_errors=result.sensor_errors_free,
    )
    workspace = workspace_rows(samples.commanded_poses, workspace_poses)
    judging = Judging(requirement, folds, identify_options, workspace)
    _judge(outcome, nominal, samples, fit, row_sigmas, judging)
    return outcome


def workspace_rows(commanded_poses, workspace_poses, tolerance=1e-9):
    """(M,) bool: the rows commanded at one of ``workspace_poses`` (K, 6; None: none)."""
    commanded = np.asarray(commanded_poses, dtype=float).reshape(-1, 6)
    if workspace_poses is None or not len(workspace_poses) or not len(commanded):
        return np.zeros(len(commanded), bool)
    poses = np.asarray(workspace_poses, dtype=float).reshape(-1, 6)
    distance = np.max(np.abs(commanded[:, None, :] - poses[None, :, :]), axis=2)
    return distance.min(axis=1) < tolerance


def _checked_free(free, formulation, noise_source):
    """``free`` as a list (``auto`` outside the ``implicit`` formulation: its plain model);
    CalibrationError or IdentificationError naming what is wrong."""
    if formulation not in FORMULATIONS:
        raise CalibrationError(f'formulation must be one of {FORMULATIONS}, got {formulation!r}')
    if noise_from_data.noise_source_error(noise_source):
        raise CalibrationError(f'noise_source {noise_from_data.noise_source_error(noise_source)}')
    free = [free] if isinstance(free, str) else list(free)
    if any(is_effect_name(n) for n in free) and formulation != 'implicit':
        raise CalibrationError(
            f"the effect groups need formulation 'implicit', got {formulation!r}"
        )
    if AUTO in free and formulation != 'implicit':
        free, _ = split_auto(free)  # no effect group to choose: the plain model
    resolve_free(free)
    return free


def _fit(nominal, samples, weights, free, formulation, noise_source, identify_options):
    """The :class:`Fit` of the rows with their ``weights``, ``auto`` chosen first."""
    row_sigmas, within, design = weights.sigmas, weights.within, weights.design
    plain, auto = split_auto(free)
    choice = untried = None
    if auto:
        # The choice's test needs the rows' real noise: the within-posture estimate where the
        # run gives one (not only a lower bound), else the configured sigmas.
        known = noise_from_data.within_sigmas(within, row_sigmas)
        choice, untried = _choose(nominal, samples, known, design, plain, identify_options)
        free = plain + list(choice.groups)
        design = dataclasses.replace(design, thermal_time_constant_s=choice.thermal_time_constant_s)
    effects = design if any(is_effect_name(n) for n in free) else None
    result, estimates, used = noise_from_data.identify_with_noise(
        noise_source,
        nominal,
        samples.leg_lengths,
        samples.readings,
        row_sigmas,
        within,
        formulation=formulation,
        free=resolve_free(free) if effects is None else free,
        pose_guesses=samples.commanded_poses,
        effects=effects,
        # The choice's fit of the chosen model has the start weights: the first round's.
        first=None if choice is None else choice.result,
        **identify_options,
    )
    return Fit(result, estimates, used, effects, choice, untried)


def _choose(nominal, samples, row_sigmas, design, plain, identify_options):
    """``(ModelChoice, {group not tried: why})`` of ``auto`` on the rows (the core's
    ``choose_model`` beside the ``plain`` model)."""
    choice = choose_model(
        nominal,
        samples.leg_lengths,
        samples.readings,
        row_sigmas,
        design,
        base=tuple(plain),
        pose_guesses=samples.commanded_poses,
        thermal_time_constants=DEFAULT_THERMAL_TIME_CONSTANTS,
        options=identify_options.get('options', Options()),
    )
    return choice, untried_groups(design, len(samples), effect_groups_of(plain))


def uncompensated_thermal_strain(result, design):
    """(6,) each leg's rms thermal strain over the run, which the controllers do not compensate,
    when ``result`` identified the thermal growth; else None."""
    rates = [result.effects.get(f'strain_rate{leg}') for leg in range(1, 7)]
    if design is None or design.times_s is None or any(rate is None for rate in rates):
        return None
    return thermal_strain_rms([rate[0] for rate in rates], design)


def _judge(outcome, nominal, samples, fit, row_sigmas, judging):
    """Cross-validate, predict and judge ``outcome``'s result (:class:`Judging`; fills the
    outcome)."""
    requirement, folds, identify_options, workspace = judging
    result, estimates, effects = fit.result, fit.estimates, fit.effects
    noise = SensorNoise.from_channels(
        {channel: entry.noise for channel, entry in estimates.items()}, default=row_sigmas
    )
    thermal = uncompensated_thermal_strain(result, effects)
    outcome.unmodelled = noise_from_data.unmodelled_error(estimates)
    validation = cross_validate(
        result,
        nominal,
        samples.leg_lengths,
        samples.readings,
        outcome.sigmas,
        folds=folds,
        noise=noise,
        effects=effects,
        uncompensated_strain=thermal,
        unmodelled=outcome.unmodelled,
        linearised=True,  # each fold's fit one Gauss-Newton step from the full fit
        options=identify_options.get('options', Options()),
    )
    outcome.accuracy = validation.summary(workspace)
    outcome.accuracy['workspace_postures'] = [int(k) for k in samples.posture[workspace]]
    outcome.prediction = prediction_for(
        result,
        analysis=outcome.identifiability,
        unmodelled=outcome.unmodelled,
        thermal_strain=thermal,
    )
    headline = None
    if outcome.prediction is not None:
        headline = accuracy_summary(outcome.prediction)
    outcome.requirement = requirement
    outcome.judgement = acceptance.judge(
        outcome.accuracy, requirement, outcome.unmodelled, headline
    )
    # A controller that cannot compensate the effects: the rigid geometry and its accuracy.
    outcome.rigid_geometry, rigid = rigid_result(outcome)
    if rigid is not None:
        outcome.effects['rigid'] = rigid


@dataclasses.dataclass(frozen=True)
class WrittenRun:
    """What :func:`write_run_files` wrote: the run's human summary, and a report failure."""

    summary: str
    report_error: str = ''  #: '' when result.json and report.md were written (or not due)


def identify_with_settings(settings, samples):
    """:func:`identify_from_samples` of ``samples`` as a calibrator with ``settings`` does."""
    return identify_from_samples(
        settings.nominal,
        samples,
        settings.sigmas,
        list(settings.free_parameters),
        settings.formulation,
        settings.noise_source,
        settings.requirement,
        settings.cross_validation_folds,
        payload_mass=settings.payload_mass,
        centre_of_mass=settings.payload_centre_of_mass,
        workspace_poses=workspace_poses(settings),
        leg_mass=settings.leg_mass,
        max_posture_error=settings.max_posture_error,
        options=settings.identify_options(),
    )


def write_run_files(run, settings, outcome, collection, options):
    """Write the files of an identified run (pure; the node runs it in a worker thread)."""
    skipped = [(entry['posture'], entry['reason']) for entry in collection['skipped']]
    additions = collection.get('route_additions') or {}
    summary = outcome_summary(
        outcome,
        selected=settings.commanded_posture_count + additions.get('added_postures', 0),
        skipped=skipped,
        run_directory=run.path,
    )
    if additions:
        summary += '\n' + route_additions_line(additions)
    if settle_line(collection.get('settle')):
        summary += '\n' + settle_line(collection['settle'])
    report_error = ''
    if outcome.result is not None:
        try:
            write_all(
                run.path,
                outcome.result,
                outcome_inputs(outcome, settings.nominal, options, collection=collection),
                plots=settings.write_report_plots,
            )
        except Exception as error:
            report_error = f'{error}\n{traceback.format_exc()}'
    if outcome.success:
        comment = RESULT_COMMENT + ('' if outcome.accepted else f'\n{NOT_ACCEPTED_COMMENT}')
        write_results(run, outcome, comment)
    return WrittenRun(summary, report_error)


def write_results(run, outcome, comment):
    """Write a successful ``outcome``'s geometry to ``run`` (its ``RunDirectory``) as
    ``result.yaml`` and, with identified effects, the rigid one as ``result_rigid.yaml``."""
    run.write_geometry(outcome.geometry, RESULT_FILE, comment=comment)
    if outcome.rigid_geometry is not None:
        # The rigid file carries its own verdict's mark (docs/verdict.md).
        kept = comment.replace(f'\n{NOT_ACCEPTED_COMMENT}', '')
        rigid_comment = f'{kept}\n{RIGID_COMMENT}'
        if not outcome.verdicts.of(compensates=False)[0].accepted:
            rigid_comment += f'\n{NOT_ACCEPTED_COMMENT}'
        run.write_geometry(outcome.rigid_geometry, RIGID_RESULT_FILE, comment=rigid_comment)
