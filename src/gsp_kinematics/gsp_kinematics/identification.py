"""Parameter identification (paper section 4.1) and an errors-in-variables alternative.

Formulations:

* ``'fk'``: per posture, forward kinematics of the measured leg lengths under the current
  parameters predicts the device readings ``[alpha, beta, phi, d_m]``; residuals are measured minus
  predicted, each divided by its sensor's sigma. The Jacobian comes from the implicit function
  theorem through FK (no finite differences).
* ``'paper'``: eq (11): residuals ``alpha, beta, phi`` only, with ``D = D0 + Dm`` as an input.
* ``'implicit'``: maximum likelihood with the M poses as unknowns beside the parameters (implicit
  loop / errors in variables). Every sensor, the six legs included, is a residual over its sigma;
  there is no inner FK loop, and the block-sparse normal equations are solved through a Schur
  complement on the 6x6 pose blocks.

All three are minimised by the same Levenberg-Marquardt loop (Marquardt's diagonal scaling), which
stops on the step ``du`` or on the change of the residual ``dX``, as in the paper's Fig. 5.
"""

import dataclasses
import math
import time

import numpy as np

from .device import READING_NAMES, device_readings_jacobians, paper_inclinations_jacobians
from .geometry import NUM_PARAMETERS, PARAMETER_INDEX, PARAMETER_NAMES, Geometry
from .kinematics import (
    expand_leg_parameters,
    forward_kinematics_masked,
    inverse_kinematics_jacobians,
)

FORMULATIONS = ("implicit", "fk", "paper")
DEFAULT_FORMULATION = "implicit"

SENSOR_NAMES = ("leg_lengths",) + READING_NAMES


class IdentificationError(ValueError):
    """Inputs to the identification are unusable; the message says which."""


@dataclasses.dataclass(frozen=True)
class Sigmas:
    """Standard deviation of each sensor's noise (m, rad): the residual weights."""

    leg_lengths: float = 1e-6
    inclinometer: float = math.radians(0.001)
    encoder: float = math.radians(0.001)
    lvdt: float = 1e-6

    @classmethod
    def from_levels(cls, angle_noise_deg, length_noise_mm):
        """Table 3's convention: one angular level (deg) and one length level (mm)."""
        return cls(
            leg_lengths=length_noise_mm / 1000.0,
            inclinometer=math.radians(angle_noise_deg),
            encoder=math.radians(angle_noise_deg),
            lvdt=length_noise_mm / 1000.0,
        )

    def readings(self):
        """Sigmas of ``[alpha, beta, phi, d_m]``."""
        return np.array([self.inclinometer, self.inclinometer, self.encoder, self.lvdt])

    def validate(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not (math.isfinite(value) and value > 0.0):
                raise IdentificationError(f"sigma for {field.name} must be positive and finite, got {value}")


@dataclasses.dataclass(frozen=True)
class Options:
    """Levenberg-Marquardt settings."""

    max_iterations: int = 100
    step_tolerance: float = 1e-12  #: du: stop when |du| <= tol * (tol + |u|)
    cost_tolerance: float = 1e-12  #: dX: stop when the relative cost decrease is below this
    gradient_tolerance: float = 1e-12  #: stop when the scaled gradient is below this
    initial_damping: float = 1e-3  #: lambda, relative to Marquardt's diag(J^T J)
    max_fk_rejections: int = 8  #: rejected steps (FK failures) before a posture is dropped


@dataclasses.dataclass
class IdentificationResult:
    """What an identification returns (cf. scipy.optimize.OptimizeResult)."""

    geometry: Geometry  #: the calibrated geometry (fixed parameters keep their nominal value)
    parameters: np.ndarray  #: the 44 estimates (m, rad)
    standard_deviations: np.ndarray  #: 44, from the covariance; NaN for fixed parameters
    covariance: np.ndarray  #: (n_free, n_free) over the free parameters
    free: np.ndarray  #: 44 bools
    formulation: str
    residual_rms: dict  #: per sensor, in its unit (m or rad); only sensors in the residual
    cost: float  #: 0.5 * sum of squared weighted residuals
    iterations: int
    status: int  #: >0 converged (1 du, 2 dX, 3 gradient), 0 max iterations, <0 failure
    message: str
    excluded_postures: list  #: posture indices dropped because FK failed under an estimate
    poses: np.ndarray  #: the estimated poses (M, 6) at the solution
    residuals: np.ndarray  #: (M, k) weighted residuals, NaN rows for excluded postures
    duration_s: float
    information: np.ndarray  #: (n_free, n_free) J^T J of the free parameters (Schur-reduced)

    @property
    def converged(self):
        return self.status > 0

    @property
    def free_names(self):
        return [name for name, is_free in zip(PARAMETER_NAMES, self.free, strict=True) if is_free]

    def correlations(self, threshold=0.9):
        """Pairs of free parameters whose |correlation| exceeds ``threshold``."""
        deviations = np.sqrt(np.diag(self.covariance))
        with np.errstate(invalid="ignore", divide="ignore"):
            matrix = self.covariance / np.outer(deviations, deviations)
        names = self.free_names
        pairs = []
        for i in range(len(names)):
            for j in range(i + 1, len(names)):
                if abs(matrix[i, j]) > threshold:
                    pairs.append((names[i], names[j], float(matrix[i, j])))
        return pairs


def resolve_free(free):
    """A 44-bool mask from None (all), a mask, or an iterable of parameter names."""
    if free is None:
        return np.ones(NUM_PARAMETERS, dtype=bool)
    if isinstance(free, np.ndarray) and free.dtype == bool:
        if free.shape != (NUM_PARAMETERS,):
            raise IdentificationError(f"free mask must have {NUM_PARAMETERS} entries")
        return free.copy()
    mask = np.zeros(NUM_PARAMETERS, dtype=bool)
    for name in free:
        if name not in PARAMETER_INDEX:
            raise IdentificationError(f"unknown parameter name {name!r} (expected e.g. 'A1x', 'Loff3', 'D0', 'gamma')")
        mask[PARAMETER_INDEX[name]] = True
    if not mask.any():
        raise IdentificationError("no free parameters")
    return mask


def wrap_angle(angle):
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


# --- models ------------------------------------------------------------------------------------


class _FkModel:
    """Residuals of device readings predicted through FK of the measured legs."""

    def __init__(self, nominal, leg_lengths, readings, sigmas, free, pose_guesses, paper, sensors):
        self.nominal_vector = nominal.to_vector()
        self.limits = nominal.limits
        self.leg_lengths = leg_lengths
        self.readings = readings
        self.free = free
        self.paper = paper
        columns = [0, 1, 2] if paper else [0, 1, 2, 3]
        self.columns = [c for c in columns if READING_NAMES[c] in sensors]
        self.weights = 1.0 / sigmas.readings()[self.columns]
        self.poses = pose_guesses.copy()
        self.active = np.ones(leg_lengths.shape[0], dtype=bool)

    def geometry(self, free_values):
        vector = self.nominal_vector.copy()
        vector[self.free] = free_values
        return Geometry.from_vector(vector, self.limits)

    def evaluate(self, free_values, linearize):
        """``(residuals (M, k), jacobian (M, k, n) or None, poses, converged (M,))``."""
        geometry = self.geometry(free_values)
        poses, converged = forward_kinematics_masked(geometry, self.leg_lengths, self.poses)
        use = converged & self.active
        count, k, n = poses.shape[0], len(self.columns), int(self.free.sum())
        residuals = np.zeros((count, k))
        jacobian = np.zeros((count, k, n)) if linearize else None
        if not use.any():
            return residuals, jacobian, poses, converged
        good = poses[use]
        if self.paper:
            predicted, d_pred_d_pose, d_pred_d_device = self._paper_prediction(geometry, good, use)
        else:
            predicted, d_pred_d_pose, d_pred_d_device = device_readings_jacobians(geometry, good)
            predicted, d_pred_d_pose, d_pred_d_device = (
                predicted[:, self.columns],
                d_pred_d_pose[:, self.columns],
                d_pred_d_device[:, self.columns],
            )
        difference = self.readings[use][:, self.columns] - predicted
        phi_column = self.columns.index(2) if 2 in self.columns else None
        if phi_column is not None:
            difference[:, phi_column] = wrap_angle(difference[:, phi_column])
        residuals[use] = difference * self.weights
        if linearize:
            _, d_q_d_pose, d_q_d_leg = inverse_kinematics_jacobians(geometry, good)
            d_q_d_u = np.zeros(d_q_d_leg.shape[:2] + (NUM_PARAMETERS,))
            d_q_d_u[:, :, :42] = expand_leg_parameters(d_q_d_leg)
            # q(X(u), u) = q_measured  =>  dX/du = -(dq/dX)^-1 dq/du
            d_pose_d_u = -np.linalg.solve(d_q_d_pose, d_q_d_u[:, :, self.free])
            d_pred_d_u = d_pred_d_pose @ d_pose_d_u
            device_free = self.free[42:]
            d_pred_d_u[:, :, np.cumsum(self.free)[42:][device_free] - 1] += d_pred_d_device[:, :, device_free]
            jacobian[use] = -d_pred_d_u * self.weights[None, :, None]
        return residuals, jacobian, poses, converged

    def _paper_prediction(self, geometry, poses, use):
        d_m = self.readings[use][:, 3]
        angles, d_angles_d_pose, d_angles_d_device = paper_inclinations_jacobians(geometry, poses, d_m)
        predicted = np.concatenate([angles, poses[:, 5:6]], axis=1)
        d_pose = np.concatenate([d_angles_d_pose, np.zeros((poses.shape[0], 1, 6))], axis=1)
        d_pose[:, 2, 5] = 1.0
        d_device = np.concatenate([d_angles_d_device, np.zeros((poses.shape[0], 1, 2))], axis=1)
        keep = [c for c in (0, 1, 2) if c in self.columns]
        return predicted[:, keep], d_pose[:, keep], d_device[:, keep]


class _ImplicitModel:
    """All sensors as residuals; the parameters and every pose are unknowns."""

    def __init__(self, nominal, leg_lengths, readings, sigmas, free, initial_poses, sensors):
        self.nominal_vector = nominal.to_vector()
        self.limits = nominal.limits
        self.leg_lengths = leg_lengths
        self.readings = readings
        self.free = free
        self.columns = [c for c in range(4) if READING_NAMES[c] in sensors]
        self.leg_weight = 1.0 / sigmas.leg_lengths
        self.reading_weights = 1.0 / sigmas.readings()[self.columns]
        self.use_legs = "leg_lengths" in sensors
        self.initial_poses = initial_poses

    def geometry(self, free_values):
        vector = self.nominal_vector.copy()
        vector[self.free] = free_values
        return Geometry.from_vector(vector, self.limits)

    def evaluate(self, free_values, poses, linearize):
        geometry = self.geometry(free_values)
        q, d_q_d_pose, d_q_d_leg = inverse_kinematics_jacobians(geometry, poses)
        predicted, d_pred_d_pose, d_pred_d_device = device_readings_jacobians(geometry, poses)
        leg_residuals = (q - self.leg_lengths) * self.leg_weight
        if not self.use_legs:
            leg_residuals = leg_residuals[:, :0]
        difference = predicted[:, self.columns] - self.readings[:, self.columns]
        if 2 in self.columns:
            column = self.columns.index(2)
            difference[:, column] = wrap_angle(difference[:, column])
        residuals = np.concatenate([leg_residuals, difference * self.reading_weights], axis=1)
        if not linearize:
            return residuals, None, None
        count, n = poses.shape[0], int(self.free.sum())
        d_q_d_u = np.zeros((count, 6, NUM_PARAMETERS))
        d_q_d_u[:, :, :42] = expand_leg_parameters(d_q_d_leg)
        d_pred_d_u = np.zeros((count, 4, NUM_PARAMETERS))
        d_pred_d_u[:, :, 42:] = d_pred_d_device
        blocks_pose = [d_q_d_pose * self.leg_weight] if self.use_legs else []
        blocks_pose.append(d_pred_d_pose[:, self.columns] * self.reading_weights[None, :, None])
        blocks_u = [d_q_d_u[:, :, self.free] * self.leg_weight] if self.use_legs else []
        blocks_u.append(d_pred_d_u[:, self.columns][:, :, self.free] * self.reading_weights[None, :, None])
        jac_pose = np.concatenate(blocks_pose, axis=1)
        jac_u = np.concatenate(blocks_u, axis=1)
        assert jac_u.shape[2] == n
        return residuals, jac_pose, jac_u


def schur_information(jac_pose, jac_u, pose_damping=None):
    """Per-posture Schur blocks: ``H_uu``, ``H_Xu``, ``H_XX`` and the reduced matrix over u."""
    jac_pose_t = np.swapaxes(jac_pose, 1, 2)
    h_xx = jac_pose_t @ jac_pose
    if pose_damping is not None:
        h_xx = h_xx + pose_damping
    h_xu = jac_pose_t @ jac_u
    flat_u = jac_u.reshape(-1, jac_u.shape[2])
    h_uu = flat_u.T @ flat_u
    h_xx_inv_h_xu = np.linalg.solve(h_xx, h_xu)
    reduced = h_uu - h_xu.reshape(-1, h_xu.shape[2]).T @ h_xx_inv_h_xu.reshape(-1, h_xu.shape[2])
    return reduced, h_xx, h_xu, h_xx_inv_h_xu


# --- the Levenberg-Marquardt loop ----------------------------------------------------------------


def _lm_update_damping(damping, ratio, nu):
    if ratio > 0.0:
        return damping * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3), 2.0
    return damping * nu, nu * 2.0


def _check_inputs(nominal, leg_lengths, readings, pose_guesses):
    leg_lengths = np.asarray(leg_lengths, dtype=float)
    readings = np.asarray(readings, dtype=float)
    if leg_lengths.ndim != 2 or leg_lengths.shape[1] != 6:
        raise IdentificationError(f"leg_lengths must be (M, 6), got {leg_lengths.shape}")
    if readings.shape != (leg_lengths.shape[0], 4):
        raise IdentificationError(
            f"readings must be (M, 4) [alpha, beta, phi, d_m] with M = {leg_lengths.shape[0]}, got {readings.shape}"
        )
    bad = np.flatnonzero(~(np.all(np.isfinite(leg_lengths), axis=1) & np.all(np.isfinite(readings), axis=1)))
    if bad.size:
        raise IdentificationError(f"non-finite leg lengths or readings at posture(s) {bad.tolist()[:20]}")
    if pose_guesses is None:
        # The device alone gives the position; a level platform at that position is a fair start.
        from .device import device_position

        link_length = nominal.device_length + readings[:, 3]
        position = device_position(readings[:, 0], readings[:, 1], link_length, nominal.inclinometer_axes_angle)
        level = np.concatenate([position, np.zeros((len(readings), 2)), readings[:, 2:3]], axis=1)
        # The device does not see the tilt (psi, theta): let this first FK travel far in angle,
        # then use its solution as the guess, so later FK calls keep the tight jump check.
        solved, converged = forward_kinematics_masked(
            nominal, leg_lengths, level, max_position_jump=0.5, max_angle_jump=math.pi / 2
        )
        pose_guesses = np.where(converged[:, None], solved, level)
    pose_guesses = np.asarray(pose_guesses, dtype=float)
    if pose_guesses.shape != leg_lengths.shape:
        raise IdentificationError(f"pose_guesses must be (M, 6), got {pose_guesses.shape}")
    return leg_lengths, readings, pose_guesses


def identify(
    nominal,
    leg_lengths,
    readings,
    sigmas=Sigmas(),
    formulation=DEFAULT_FORMULATION,
    free=None,
    pose_guesses=None,
    sensors=SENSOR_NAMES,
    options=Options(),
):
    """Identify the free parameters from M postures.

    ``leg_lengths`` (M, 6): measured articular variables q (m). ``readings`` (M, 4): measured
    ``[alpha, beta, phi, d_m]`` (rad, m). ``pose_guesses`` (M, 6): where FK starts (e.g. the
    commanded postures); by default built from the device readings. ``sensors`` drops
    measurements (e.g. without ``'d_m'``) for identifiability studies.
    """
    if formulation not in FORMULATIONS:
        raise IdentificationError(f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
    unknown = set(sensors) - set(SENSOR_NAMES)
    if unknown:
        raise IdentificationError(f"unknown sensors {sorted(unknown)}; expected some of {SENSOR_NAMES}")
    sigmas.validate()
    free = resolve_free(free)
    leg_lengths, readings, pose_guesses = _check_inputs(nominal, leg_lengths, readings, pose_guesses)
    started = time.perf_counter()
    if formulation == "implicit":
        result = _identify_implicit(nominal, leg_lengths, readings, sigmas, free, pose_guesses, sensors, options)
    else:
        result = _identify_fk(
            nominal, leg_lengths, readings, sigmas, free, pose_guesses, formulation == "paper", sensors, options
        )
    result.duration_s = time.perf_counter() - started
    return result


def _finish(model, free_values, free, formulation, information, residuals, weights_by_sensor, **fields):
    vector = model.nominal_vector.copy()
    vector[free] = free_values
    covariance = _safe_inverse(information)
    deviations = np.full(NUM_PARAMETERS, np.nan)
    deviations[free] = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    rms = {}
    for name, (column, weight) in weights_by_sensor.items():
        values = residuals[:, column] / weight
        values = values[np.isfinite(values)]
        rms[name] = float(np.sqrt(np.mean(values**2))) if values.size else float("nan")
    return IdentificationResult(
        geometry=Geometry.from_vector(vector, model.limits),
        parameters=vector,
        standard_deviations=deviations,
        covariance=covariance,
        free=free,
        formulation=formulation,
        residual_rms=rms,
        residuals=residuals,
        information=information,
        duration_s=0.0,
        **fields,
    )


def _safe_inverse(matrix):
    try:
        inverse = np.linalg.inv(matrix)
        if np.all(np.isfinite(inverse)):
            return inverse
    except np.linalg.LinAlgError:
        pass
    return np.linalg.pinv(matrix)


def _identify_fk(nominal, leg_lengths, readings, sigmas, free, pose_guesses, paper, sensors, options):
    model = _FkModel(nominal, leg_lengths, readings, sigmas, free, pose_guesses, paper, sensors)
    values = nominal.to_vector()[free]
    residuals, jacobian, poses, converged = model.evaluate(values, linearize=True)
    excluded = sorted(np.flatnonzero(~converged).tolist())
    model.active &= converged
    model.poses = np.where(converged[:, None], poses, model.poses)
    if model.active.sum() * len(model.columns) < free.sum():
        return _fail_result(model, values, free, "paper" if paper else "fk", excluded, poses, residuals,
                            f"FK failed at the nominal parameters for posture(s) {excluded[:20]}: too few left")
    cost = 0.5 * float(np.sum(residuals**2))
    damping, nu = None, 2.0
    readmitted = set()
    status, message, iteration, rejections = 0, "maximum number of iterations reached", 0, 0
    for iteration in range(1, options.max_iterations + 1):  # noqa: B007 (reported after)
        flat_jacobian = jacobian.reshape(-1, jacobian.shape[2])
        flat_residual = residuals.ravel()
        normal = flat_jacobian.T @ flat_jacobian
        gradient = flat_jacobian.T @ flat_residual
        diagonal = np.maximum(np.diag(normal), 1e-30)
        if np.max(np.abs(gradient) / np.sqrt(diagonal)) <= options.gradient_tolerance * max(1.0, math.sqrt(2 * cost)):
            status, message = 3, "gradient below tolerance"
            break
        if damping is None:
            damping = options.initial_damping
        step = np.linalg.solve(normal + damping * np.diag(diagonal), -gradient)
        predicted_reduction = -(gradient @ step) - 0.5 * step @ normal @ step
        trial_residuals, trial_jacobian, trial_poses, trial_converged = model.evaluate(values + step, linearize=True)
        newly_failed = model.active & ~trial_converged
        if newly_failed.any():
            rejections += 1
            damping, nu = damping * nu, nu * 2.0
            if rejections >= options.max_fk_rejections:
                # The estimate keeps leaving FK's reach for these postures: drop them, say so.
                dropped = np.flatnonzero(newly_failed)
                excluded = sorted(set(excluded) | set(dropped.tolist()))
                model.active &= ~newly_failed
                residuals, jacobian, poses, _ = model.evaluate(values, linearize=True)
                cost = 0.5 * float(np.sum(residuals**2))
                rejections = 0
            continue
        rejections = 0
        trial_cost = 0.5 * float(np.sum(trial_residuals**2))
        ratio = (cost - trial_cost) / predicted_reduction if predicted_reduction > 0 else -1.0
        damping, nu = _lm_update_damping(damping, ratio, nu)
        if ratio > 0.0:
            decrease = cost - trial_cost
            values = values + step
            residuals, jacobian, cost = trial_residuals, trial_jacobian, trial_cost
            model.poses = np.where(trial_converged[:, None], trial_poses, model.poses)
            poses = trial_poses
            recovered = ~model.active & trial_converged
            if recovered.any():
                # A better estimate brings a posture back within FK's reach: use it again.
                model.active |= recovered
                readmitted.update(np.flatnonzero(recovered).tolist())
                residuals, jacobian, poses, _ = model.evaluate(values, linearize=True)
                cost = 0.5 * float(np.sum(residuals**2))
                continue
            if np.linalg.norm(step) <= options.step_tolerance * (options.step_tolerance + np.linalg.norm(values)):
                status, message = 1, "du: parameter step below tolerance"
                break
            if decrease <= options.cost_tolerance * cost:
                status, message = 2, "dX: residual change below tolerance"
                break
        elif np.linalg.norm(step) <= options.step_tolerance * (options.step_tolerance + np.linalg.norm(values)):
            status, message = 1, "du: parameter step below tolerance"
            break
    flat_jacobian = jacobian.reshape(-1, jacobian.shape[2])
    information = flat_jacobian.T @ flat_jacobian
    out_residuals = residuals.copy()
    out_residuals[~model.active] = np.nan
    excluded = sorted(np.flatnonzero(~model.active).tolist())
    if readmitted:
        message += f"; posture(s) {sorted(readmitted)[:20]} readmitted after FK failed at an earlier estimate"
    if excluded:
        message += f"; excluded posture(s) {excluded[:20]} where FK failed"
    weights = {READING_NAMES[c]: (i, model.weights[i]) for i, c in enumerate(model.columns)}
    return _finish(
        model, values, free, "paper" if paper else "fk", information, out_residuals, weights,
        cost=cost, iterations=iteration, status=status, message=message,
        excluded_postures=excluded, poses=model.poses.copy(),
    )


def _fail_result(model, values, free, formulation, excluded, poses, residuals, message):
    information = np.eye(int(free.sum())) * np.nan
    return IdentificationResult(
        geometry=model.geometry(values), parameters=model.nominal_vector.copy(),
        standard_deviations=np.full(NUM_PARAMETERS, np.nan), covariance=information,
        free=free, formulation=formulation, residual_rms={}, cost=float("nan"), iterations=0,
        status=-1, message=message, excluded_postures=excluded, poses=poses,
        residuals=residuals, duration_s=0.0, information=information,
    )


def _identify_implicit(nominal, leg_lengths, readings, sigmas, free, pose_guesses, sensors, options):
    poses, converged = forward_kinematics_masked(nominal, leg_lengths, pose_guesses)
    # Where FK under the nominal fails, the pose still has a start: the guess itself.
    poses = np.where(converged[:, None], poses, pose_guesses)
    model = _ImplicitModel(nominal, leg_lengths, readings, sigmas, free, poses, sensors)
    values = nominal.to_vector()[free]
    residuals, jac_pose, jac_u = model.evaluate(values, poses, linearize=True)
    cost = 0.5 * float(np.sum(residuals**2))
    damping, nu = options.initial_damping, 2.0
    status, message, iteration = 0, "maximum number of iterations reached", 0
    for iteration in range(1, options.max_iterations + 1):  # noqa: B007 (reported after)
        jac_pose_t = np.swapaxes(jac_pose, 1, 2)
        flat_u = jac_u.reshape(-1, jac_u.shape[2])
        gradient_pose = (jac_pose_t @ residuals[..., None])[..., 0]
        gradient_u = flat_u.T @ residuals.ravel()
        h_xx = jac_pose_t @ jac_pose
        h_xu = jac_pose_t @ jac_u
        h_uu = flat_u.T @ flat_u
        diag_pose = np.maximum(np.diagonal(h_xx, axis1=1, axis2=2), 1e-30)
        diag_u = np.maximum(np.diag(h_uu), 1e-30)
        scaled_gradient = max(
            np.max(np.abs(gradient_u) / np.sqrt(diag_u)), np.max(np.abs(gradient_pose) / np.sqrt(diag_pose))
        )
        if scaled_gradient <= options.gradient_tolerance * max(1.0, math.sqrt(2 * cost)):
            status, message = 3, "gradient below tolerance"
            break
        damped_xx = h_xx + damping * diag_pose[:, :, None] * np.eye(6)[None]
        damped_uu = h_uu + damping * np.diag(diag_u)
        solved_xu = np.linalg.solve(damped_xx, h_xu)  # (M, 6, n)
        solved_gx = np.linalg.solve(damped_xx, gradient_pose[..., None])[..., 0]  # (M, 6)
        flat_h_xu = h_xu.reshape(-1, h_xu.shape[2])
        reduced = damped_uu - flat_h_xu.T @ solved_xu.reshape(-1, solved_xu.shape[2])
        reduced_rhs = -gradient_u + flat_h_xu.T @ solved_gx.ravel()
        step_u = np.linalg.solve(reduced, reduced_rhs)
        step_pose = -(solved_gx + solved_xu @ step_u)
        # Predicted reduction of the Gauss-Newton model for the combined step.
        jac_step = (jac_pose @ step_pose[..., None])[..., 0] + jac_u @ step_u
        predicted_reduction = -float(np.sum(residuals * jac_step)) - 0.5 * float(np.sum(jac_step**2))
        trial_values = values + step_u
        trial_poses = poses + step_pose
        trial_residuals, trial_jac_pose, trial_jac_u = model.evaluate(trial_values, trial_poses, linearize=True)
        trial_cost = 0.5 * float(np.sum(trial_residuals**2))
        ratio = (cost - trial_cost) / predicted_reduction if predicted_reduction > 0 and math.isfinite(trial_cost) else -1.0
        damping, nu = _lm_update_damping(damping, ratio, nu)
        small_step = np.linalg.norm(step_u) <= options.step_tolerance * (
            options.step_tolerance + np.linalg.norm(values)
        ) and np.max(np.abs(step_pose)) <= options.step_tolerance * 10.0
        if ratio > 0.0:
            decrease = cost - trial_cost
            values, poses = trial_values, trial_poses
            residuals, jac_pose, jac_u, cost = trial_residuals, trial_jac_pose, trial_jac_u, trial_cost
            if small_step:
                status, message = 1, "du: parameter step below tolerance"
                break
            if decrease <= options.cost_tolerance * cost:
                status, message = 2, "dX: residual change below tolerance"
                break
        elif small_step:
            status, message = 1, "du: parameter step below tolerance"
            break
    information = schur_information(jac_pose, jac_u)[0]
    names = (["leg_lengths"] if model.use_legs else []) + [READING_NAMES[c] for c in model.columns]
    weights = {}
    column = 0
    if model.use_legs:
        weights["leg_lengths"] = (slice(0, 6), model.leg_weight)
        column = 6
    for i, c in enumerate(model.columns):
        weights[READING_NAMES[c]] = (column + i, model.reading_weights[i])
    assert len(weights) == len(names)
    return _finish(
        model, values, free, "implicit", information, residuals, weights,
        cost=cost, iterations=iteration, status=status, message=message,
        excluded_postures=[], poses=poses,
    )
