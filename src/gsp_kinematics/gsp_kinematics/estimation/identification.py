"""Parameter identification (paper section 4.1) and an errors-in-variables alternative."""

import dataclasses
import math
import time

import numpy as np

from gsp_kinematics import channels

from ..model.device import READING_NAMES, device_position
from ..model.effect_groups import (
    AUTO,
    EffectDesign,
    EffectTerms,
    effect_estimates,
    geometry_with_effects,
    is_effect_name,
    resolve_effects,
    split_auto,
)
from ..model.effects import EFFECT_PARAMETER_NAMES, NUM_EFFECT_PARAMETERS, EffectDesignError
from ..model.geometry import (
    ALL_PARAMETER_NAMES,
    NUM_ALL_PARAMETERS,
    NUM_PARAMETERS,
    PARAMETER_INDEX,
    PARAMETER_NAMES,
    SENSOR_PARAMETER_NAMES,
    Geometry,
)
from ..model.kinematics import forward_kinematics_masked
from ..model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoiseError
from . import goodness
from ._solver.formulations import _FkModel, _ImplicitModel
from ._solver.lm import TERMINATION_MESSAGES, levenberg_marquardt

FORMULATIONS = ('implicit', 'fk', 'paper')
DEFAULT_FORMULATION = 'implicit'

#: The residual groups: the leg lengths, then each device reading (:mod:`gsp_kinematics.channels`).
SENSOR_NAMES = (channels.LEG_LENGTHS,) + READING_NAMES

#: Sensor-error parameters left out of ``extended``: each is confounded with the 44 and the other
#: sensor errors, so its nominal value is a datum (docs/sensor_errors.md): ``phi0`` with a yaw of
#: the platform frame (the B_i), ``beta0`` with a tilt of the base (the A_iz), ``kDm`` with the
#: scale of every length (D0, the L_off_i and the leg gains kq_i).
DATUM_SENSOR_PARAMETERS = ('beta0', 'phi0', 'kDm')
#: Named groups of free parameters: ``paper`` (the 44 of the paper) and ``extended`` (the 44 and
#: every sensor error identifiable together with them).
PARAMETER_GROUPS = {
    'paper': PARAMETER_NAMES,
    'extended': PARAMETER_NAMES
    + tuple(name for name in SENSOR_PARAMETER_NAMES if name not in DATUM_SENSOR_PARAMETERS),
}
#: Most IRLS rounds of a robust fit.
MAX_ROBUST_ROUNDS = 20


class IdentificationError(ValueError):
    """Inputs to the identification are unusable; the message says which."""


@dataclasses.dataclass(frozen=True)
class Options:
    """Levenberg-Marquardt settings."""

    max_iterations: int = 100
    step_tolerance: float = 1e-12  #: du: stop when |du| <= tol * (tol + |u|)
    cost_tolerance: float = 1e-12  #: dX: stop when the relative cost decrease is below this
    gradient_tolerance: float = 1e-12  #: stop when the scaled gradient is below this
    #: lambda, relative to Marquardt's diag(J^T J); None: the formulation's own (1e-6 for
    #: 'implicit', whose start is close and whose model is nearly linear; 1e-3 for 'fk', 'paper')
    initial_damping: float | None = None
    max_fk_rejections: int = 8  #: rejected steps (FK failures) before a posture is dropped
    loss: str = 'linear'  #: robust loss: 'linear', 'huber' or 'cauchy' (goodness.LOSSES)
    #: Where the robust loss departs from least squares, in sigmas (Huber's 95%-efficiency 1.345).
    loss_scale: float = 1.345
    #: |studentised residual| naming an outlier; None: Bonferroni over the residuals at 1 %
    outlier_threshold: float | None = goodness.DEFAULT_OUTLIER_THRESHOLD


@dataclasses.dataclass
class IdentificationResult:
    """What an identification returns (cf. scipy.optimize.OptimizeResult)."""

    geometry: Geometry  #: the calibrated geometry (fixed parameters keep their nominal value)
    parameters: np.ndarray  #: the 54 estimates: the 44 (m, rad) then the sensor errors
    standard_deviations: np.ndarray  #: 54, from the covariance; NaN for fixed parameters
    covariance: np.ndarray  #: (n_free, n_free) over the free parameters
    free: np.ndarray  #: 54 bools (ALL_PARAMETER_NAMES)
    formulation: str
    residual_rms: dict  #: per sensor, in its unit (m or rad); only sensors in the residual
    cost: float  #: 0.5 * sum of squared weighted residuals
    iterations: int
    status: int  #: >0 converged (1 du, 2 dX, 3 gradient), 0 max iterations, <0 failure: TERMINATION_MESSAGES
    message: str
    excluded_postures: list  #: posture indices dropped because FK failed under an estimate
    poses: np.ndarray  #: the estimated poses (M, 6) at the solution
    residuals: np.ndarray  #: (M, k) weighted residuals, NaN rows for excluded postures
    duration_s: float
    information: np.ndarray  #: (n_free, n_free) J^T J of the free parameters (Schur-reduced)
    goodness_of_fit: object = None  #: goodness.GoodnessOfFit (None if no solution)
    loss: str = 'linear'
    residual_columns: tuple = ()  #: name of each residual column
    outliers: list = dataclasses.field(default_factory=list)  #: goodness.outlier_postures
    down_weighted: list = dataclasses.field(default_factory=list)  #: [{'posture', 'weight'}]
    #: (M, k) redundancy numbers of the residuals (their variance under the model; None: no fit)
    redundancy: np.ndarray | None = None
    robust_weights: np.ndarray | None = None  #: (M, k) IRLS weights of a robust fit (None: 1)
    #: The effect parameters (:data:`gsp_kinematics.model.effects.EFFECT_PARAMETER_NAMES`, 24):
    #: which are free, their estimates (0 when fixed) and standard deviations (NaN when fixed).
    #: ``covariance`` and ``information`` cover the free parameters, then the free effects.
    effect_free: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(NUM_EFFECT_PARAMETERS, bool)
    )
    effect_values: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(NUM_EFFECT_PARAMETERS)
    )
    effect_standard_deviations: np.ndarray = dataclasses.field(
        default_factory=lambda: np.full(NUM_EFFECT_PARAMETERS, np.nan)
    )

    def variance_components(self):
        """``{channel: (q, r)}`` of the residuals (:func:`goodness.variance_components`)."""
        residuals = self.residuals
        excluded = self.goodness_of_fit.excluded_postures if self.goodness_of_fit else ()
        if excluded:  # postures a robust fit left out are not in its test either
            residuals = residuals.copy()
            residuals[list(excluded)] = np.nan
        return goodness.variance_components(
            residuals, self.redundancy, self.residual_columns, self.robust_weights
        )

    @property
    def converged(self):
        return self.status > 0

    @property
    def free_names(self):
        """The free parameters, then the free effect parameters (the covariance's order)."""
        names = [name for name, free in zip(ALL_PARAMETER_NAMES, self.free, strict=True) if free]
        return names + [
            name
            for name, free in zip(EFFECT_PARAMETER_NAMES, self.effect_free, strict=True)
            if free
        ]

    @property
    def effects(self):
        """``{name: (estimate, standard deviation)}`` of the free effect parameters (SI)."""
        return {
            name: (float(value), float(deviation))
            for name, free, value, deviation in zip(
                EFFECT_PARAMETER_NAMES,
                self.effect_free,
                self.effect_values,
                self.effect_standard_deviations,
                strict=True,
            )
            if free
        }

    @property
    def sensor_errors_free(self):
        """Whether any sensor-error parameter was estimated."""
        return bool(np.any(self.free[NUM_PARAMETERS:]))

    def correlations(self, threshold=0.9):
        """Pairs of free parameters whose |correlation| exceeds ``threshold``."""
        deviations = np.sqrt(np.diag(self.covariance))
        with np.errstate(invalid='ignore', divide='ignore'):
            matrix = self.covariance / np.outer(deviations, deviations)
        names = self.free_names
        rows, columns = np.nonzero(np.triu(np.abs(matrix) > threshold, k=1))
        return [
            (names[i], names[j], float(matrix[i, j])) for i, j in zip(rows, columns, strict=True)
        ]


def free_parameters_error(names, effects=True):
    """Reason ('' if none) why ``names`` (parameter and group names, :data:`PARAMETER_GROUPS`;
    with ``effects``, also the effect groups, their parameters and :data:`AUTO`) is not a set of
    free parameters: the one check of a free-parameter list."""
    names = list(names)
    if not names:
        return 'must name at least one parameter'
    unknown = [
        n
        for n in names
        if n not in PARAMETER_INDEX
        and n not in PARAMETER_GROUPS
        and not (effects and (is_effect_name(n) or n == AUTO))
    ]
    if unknown:
        effect_names = (
            ", effect groups 'compliance', 'backlash', 'thermal', 'joint_offsets' or "
            f"'{AUTO}' (choose them from the data)"
            if effects
            else ''
        )
        return (
            f'unknown parameter name(s) {unknown}; expected groups ({", ".join(PARAMETER_GROUPS)}) '
            'or names among A1x..A6z, B1x..B6z, Loff1..Loff6, D0, gamma, kq1..kq6, alpha0, '
            f'beta0, phi0, kDm{effect_names}'
        )
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        return f'duplicated name(s) {duplicated}'
    if AUTO in names and any(is_effect_name(n) for n in names):
        return f"'{AUTO}' chooses the effect groups: name no effect group or parameter beside it"
    return ''


def resolve_free(free):
    """A 54-bool mask (:data:`ALL_PARAMETER_NAMES`) from None (the paper's 44), a mask (44 or
    54 entries), or an iterable of parameter names and group names (:data:`PARAMETER_GROUPS`)."""
    if free is None:
        free = PARAMETER_GROUPS['paper']
    if isinstance(free, str):
        free = [free]
    if isinstance(free, np.ndarray) and free.dtype == bool:
        if free.shape == (NUM_PARAMETERS,):
            return np.concatenate([free, np.zeros(NUM_ALL_PARAMETERS - NUM_PARAMETERS, bool)])
        if free.shape != (NUM_ALL_PARAMETERS,):
            raise IdentificationError(
                f'free mask must have {NUM_PARAMETERS} or {NUM_ALL_PARAMETERS} entries'
            )
        return free.copy()
    free = list(free)
    reason = free_parameters_error(free)
    if reason:
        raise IdentificationError(f'free parameters: {reason}')
    free, _ = split_auto(free)  # the plain model of a choice
    mask = np.zeros(NUM_ALL_PARAMETERS, dtype=bool)
    for name in free:
        if is_effect_name(name):  # the effect groups and their parameters: resolve_effects
            continue
        members = PARAMETER_GROUPS.get(name, (name,))
        mask[[PARAMETER_INDEX[member] for member in members]] = True
    return mask


def _check_inputs(nominal, leg_lengths, readings, pose_guesses):
    leg_lengths = np.asarray(leg_lengths, dtype=float)
    readings = np.asarray(readings, dtype=float)
    if leg_lengths.ndim != 2 or leg_lengths.shape[1] != 6:
        raise IdentificationError(f'leg_lengths must be (M, 6), got {leg_lengths.shape}')
    if readings.shape != (leg_lengths.shape[0], 4):
        raise IdentificationError(
            f'readings must be (M, 4) [alpha, beta, phi, d_m] with M = {leg_lengths.shape[0]}, got {readings.shape}'
        )
    bad = np.flatnonzero(
        ~(np.all(np.isfinite(leg_lengths), axis=1) & np.all(np.isfinite(readings), axis=1))
    )
    if bad.size:
        raise IdentificationError(
            f'non-finite leg lengths or readings at posture(s) {bad.tolist()[:20]}'
        )
    if pose_guesses is None:
        # The device alone gives the position; a level platform at that position is a fair start.
        ideal = nominal.sensors.ideal_device_readings(readings)
        link_length = nominal.device_length + ideal[:, 3]
        position = device_position(
            ideal[:, 0], ideal[:, 1], link_length, nominal.inclinometer_axes_angle
        )
        level = np.concatenate([position, np.zeros((len(readings), 2)), ideal[:, 2:3]], axis=1)
        # The device does not see the tilt (psi, theta): let this first FK travel far in angle,
        # then use its solution as the guess, so later FK calls keep the tight jump check.
        solved, converged = forward_kinematics_masked(
            nominal,
            nominal.sensors.true_leg_lengths(leg_lengths),
            level,
            max_position_jump=0.5,
            max_angle_jump=math.pi / 2,
        )
        pose_guesses = np.where(converged[:, None], solved, level)
    pose_guesses = np.asarray(pose_guesses, dtype=float)
    if pose_guesses.shape != leg_lengths.shape:
        raise IdentificationError(f'pose_guesses must be (M, 6), got {pose_guesses.shape}')
    return leg_lengths, readings, pose_guesses


def identify(
    nominal,
    leg_lengths,
    readings,
    sigmas=DEFAULT_SENSOR_NOISE,
    formulation=DEFAULT_FORMULATION,
    free=None,
    pose_guesses=None,
    sensors=SENSOR_NAMES,
    options=Options(),
    effects=None,
):
    """Identify the ``free`` parameters (:func:`resolve_free`; effect groups need ``effects``, the
    run's :class:`EffectDesign`) from M postures' measured legs (M, 6) m and ``readings`` (M, 4)
    (docs/core_api.md); ``options.loss`` other than ``'linear'``: IRLS."""
    if formulation not in FORMULATIONS:
        raise IdentificationError(f'formulation must be one of {FORMULATIONS}, got {formulation!r}')
    unknown = set(sensors) - set(SENSOR_NAMES)
    if unknown:
        raise IdentificationError(
            f'unknown sensors {sorted(unknown)}; expected some of {SENSOR_NAMES}'
        )
    try:
        sigmas.validate()
    except SensorNoiseError as error:
        raise IdentificationError(str(error)) from None
    try:
        goodness.validate_loss(options.loss, options.loss_scale)
    except ValueError as error:
        raise IdentificationError(str(error)) from None
    if free is not None and not isinstance(free, np.ndarray) and AUTO in list(free):
        raise IdentificationError(f"'{AUTO}' is a choice of model: model_choice.choose_model")
    effect_mask = resolve_effects([] if free is None or isinstance(free, np.ndarray) else free)
    free = resolve_free(free)
    leg_lengths, readings, pose_guesses = _check_inputs(
        nominal, leg_lengths, readings, pose_guesses
    )
    terms = _effect_terms(nominal, effects, effect_mask, formulation, len(leg_lengths))
    started = time.perf_counter()
    if formulation == 'implicit':
        model = _ImplicitModel(
            nominal, leg_lengths, readings, sigmas, free, pose_guesses, sensors, terms
        )
    else:
        model = _FkModel(
            nominal,
            leg_lengths,
            readings,
            sigmas,
            free,
            pose_guesses,
            formulation == 'paper',
            sensors,
        )
    point, status, iterations = model.start(), -1, 0
    if not model.too_few_residuals():
        point, status, iterations = levenberg_marquardt(model, point, options)
        if options.loss != 'linear' and status > 0:
            point, status, iterations = _robust_rounds(model, point, status, iterations, options)
    result = _result(model, point, formulation, status, iterations, options)
    result.duration_s = time.perf_counter() - started
    return result


def converged_identification(*args, **kwargs):
    """:func:`identify`'s result if it converged, else None (also on an IdentificationError)."""
    try:
        result = identify(*args, **kwargs)
    except IdentificationError:
        return None
    return result if result.converged else None


def _effect_terms(nominal, design, mask, formulation, count):
    """The :class:`EffectTerms` of the free effect parameters (None without any)."""
    if not mask.any():
        return None
    if formulation != 'implicit':
        raise IdentificationError(
            f"the effect groups need formulation 'implicit' (the leg readings are residuals), "
            f'got {formulation!r}'
        )
    try:
        return EffectTerms(nominal, design or EffectDesign(), mask, count)
    except EffectDesignError as error:
        raise IdentificationError(str(error)) from None


def _robust_rounds(model, point, status, iterations, options):
    """Iteratively reweighted least squares: weights from the normalised residuals, then the
    LM driver again from the current point, until the weights settle."""
    for _ in range(MAX_ROBUST_ROUNDS):
        normalised = model.reported_residuals(point)
        weights = goodness.robust_weights(normalised, options.loss, options.loss_scale)
        previous = np.ones_like(weights) if model.root_weights is None else model.root_weights**2
        model.root_weights = np.sqrt(weights)
        if np.max(np.abs(weights - previous)) < 1e-3:
            break
        point, status, more = levenberg_marquardt(model, model.restart(point), options)
        iterations += more
        if status <= 0:
            break
    return point, status, iterations


def _result(model, point, formulation, status, iterations, options):
    """The result at the driver's final ``point`` (status < 0: the nominal, NaN statistics)."""
    free = model.free
    vector = model.nominal_vector.copy()
    residuals = model.reported_residuals(point)
    rms = {}
    fit, outliers, down_weighted, redundancy, weights = None, [], [], None, None
    if status >= 0:
        columns = model.column_names()
        redundancy = model.redundancy(point)
        weights = None if model.root_weights is None else model.root_weights**2
        # Each residual against its own standard deviation under the noise the residuals show:
        # wrong sigmas scale every residual of a channel alike and name no posture.
        components = goodness.variance_components(residuals, redundancy, columns, weights)
        studentised = goodness.studentised(residuals, redundancy, columns, components)
        outliers = goodness.isolated_outliers(
            goodness.outlier_postures(studentised, options.outlier_threshold, columns),
            studentised,
            model.estimated_poses(point),
            options.outlier_threshold,
        )
        excluded = []
        if weights is not None:
            down_weighted = goodness.down_weighted_postures(weights)
            # A robust fit judges the model on the data it kept: named outliers are left out.
            excluded = [entry['posture'] for entry in outliers]
        unknowns = model.unknowns() - (6 * len(excluded) if formulation == 'implicit' else 0)
        fit = goodness.goodness_of_fit(residuals, unknowns, excluded)
    if status < 0:
        cost = float('nan')
        size = int(free.sum()) + model.effect_count
        information = covariance = np.eye(size) * np.nan
    else:
        vector[free] = point.values[: int(free.sum())]
        cost = point.cost
        information = model.information(point)
        covariance = _safe_inverse(information)
        for name, (column, weight) in model.sensor_columns().items():
            values = residuals[:, column] / weight
            values = values[np.isfinite(values)]
            rms[name] = float(np.sqrt(np.mean(values**2))) if values.size else float('nan')
    all_deviations = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    deviations = np.full(NUM_ALL_PARAMETERS, np.nan)
    deviations[free] = all_deviations[: int(free.sum())]
    effect_free, effect_values, effect_deviations = effect_estimates(
        model, point, status, all_deviations
    )
    return IdentificationResult(
        geometry=geometry_with_effects(
            Geometry.from_full_vector(vector, model.limits), model, effect_values
        ),
        parameters=vector,
        standard_deviations=deviations,
        covariance=covariance,
        free=free,
        formulation=formulation,
        residual_rms=rms,
        cost=cost,
        iterations=iterations,
        status=status,
        message=TERMINATION_MESSAGES[status] + model.notes(),
        excluded_postures=model.excluded_postures(),
        poses=model.estimated_poses(point),
        residuals=residuals,
        duration_s=0.0,
        information=information,
        goodness_of_fit=fit,
        loss=options.loss,
        residual_columns=tuple(model.column_names()),
        outliers=outliers,
        down_weighted=down_weighted,
        redundancy=redundancy,
        robust_weights=weights,
        effect_free=effect_free,
        effect_values=effect_values,
        effect_standard_deviations=effect_deviations,
    )


def _safe_inverse(matrix):
    try:
        inverse = np.linalg.inv(matrix)
        if np.all(np.isfinite(inverse)):
            return inverse
    except np.linalg.LinAlgError:
        pass
    return np.linalg.pinv(matrix)
