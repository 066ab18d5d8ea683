"""The identification's formulations as models of
:func:`gsp_kinematics.estimation._solver.lm.levenberg_marquardt`."""

import numpy as np

from gsp_kinematics import channels

from ...model.device import READING_NAMES, paper_inclinations_jacobians
from ...model.geometry import NUM_ALL_PARAMETERS, PARAMETER_INDEX, Geometry
from ...model.kinematics import (
    expand_leg_parameters,
    forward_kinematics_masked,
    inverse_kinematics_jacobians,
)
from ...rotation import wrap_angle
from .lm import Point, Step, block_normal_equations, cost_of, eliminate_poses
from .readings import PHI_ROW, ReadingsModel, readings_jacobians
from .redundancy import redundancy_flat, redundancy_with_poses

#: Column of the yaw reading ``phi`` in ``READING_NAMES`` (an angle: its residual is wrapped).
_PHI = channels.PHI_READING_COLUMN
_KQ = slice(PARAMETER_INDEX['kq1'], PARAMETER_INDEX['kq6'] + 1)
_D0, _GAMMA, _KDM = PARAMETER_INDEX['D0'], PARAMETER_INDEX['gamma'], PARAMETER_INDEX['kDm']
#: Columns of the offsets alpha0, beta0, phi0: each adds to the reading of its row (0, 1, 2).
_OFFSETS = [PARAMETER_INDEX[name] for name in ('alpha0', 'beta0', 'phi0')]


class _Model:
    """What both formulations share: the free parameters inside the nominal extended vector
    (the 44 and the sensor errors, :data:`gsp_kinematics.model.geometry.ALL_PARAMETER_NAMES`)."""

    #: :class:`gsp_kinematics.model.effect_groups.EffectTerms` of the free effect parameters
    #: (None: none); their values follow the free parameters' in a point's values.
    effects, effect_count = None, 0

    def __init__(self, nominal, free):
        self.nominal = nominal
        self.nominal_vector = nominal.to_full_vector()
        self.limits = nominal.limits
        self.free = free

    def geometry(self, free_values):
        """The geometry with the free parameters set to ``free_values`` (the rest nominal)."""
        vector = self.nominal_vector.copy()
        vector[self.free] = free_values
        return Geometry.from_full_vector(vector, self.limits)


def _wrap_phi(difference, columns):
    """Wrap the ``phi`` column (if among ``columns``) of a reading difference, in place."""
    if _PHI in columns:
        column = columns.index(_PHI)
        difference[:, column] = wrap_angle(difference[:, column])
    return difference


class _FkModel(_Model):
    """Residuals of device readings predicted through FK of the measured legs."""

    #: Cautious: FK may fail for a posture after a long step (see accept and give_up).
    initial_damping = 1e-3

    def __init__(self, nominal, leg_lengths, readings, sigmas, free, pose_guesses, paper, sensors):
        super().__init__(nominal, free)
        self.leg_lengths = leg_lengths
        self.readings = readings
        self.paper = paper
        columns = [0, 1, 2] if paper else [0, 1, 2, 3]
        self.columns = [c for c in columns if READING_NAMES[c] in sensors]
        self.weights = 1.0 / sigmas.readings()[self.columns]
        self.poses = pose_guesses.copy()  #: FK's guesses: the last solution of each posture
        self.active = np.ones(leg_lengths.shape[0], dtype=bool)
        self.readmitted = set()
        self.root_weights = None  #: (M, k) square roots of the robust weights (None: all 1)

    def evaluate(self, free_values, linearize):
        """``(residuals (M, k), jacobian (M, k, n) or None, poses, converged (M,))``."""
        geometry = self.geometry(free_values)
        # FK of the true articular variables (1 + kq) q the leg readings q stand for.
        true_legs = geometry.sensors.true_leg_lengths(self.leg_lengths)
        poses, converged = forward_kinematics_masked(geometry, true_legs, self.poses)
        use = converged & self.active
        count, k, n = poses.shape[0], len(self.columns), int(self.free.sum())
        residuals = np.zeros((count, k))
        jacobian = np.zeros((count, k, n)) if linearize else None
        if not use.any():
            return residuals, jacobian, poses, converged
        good = poses[use]
        if self.paper:
            predicted, d_pred_d_pose, d_pred_d_u = self._paper_prediction(geometry, good, use)
        else:
            # The device rows (6 onwards) of the readings and their derivatives.
            rows = [6 + c for c in self.columns]
            predicted, d_pred_d_pose, d_pred_d_u = (
                a[:, rows] for a in readings_jacobians(geometry, good)
            )
        difference = _wrap_phi(self.readings[use][:, self.columns] - predicted, self.columns)
        residuals[use] = difference * self.weights
        if linearize:
            _, d_q_d_pose, d_q_d_leg = inverse_kinematics_jacobians(geometry, good)
            # IK(X, u) = (1 + kq) q_measured  =>  dX/du = -(dq/dX)^-1 d(IK - (1 + kq) q)/du
            d_q_d_u = np.zeros(d_q_d_leg.shape[:2] + (NUM_ALL_PARAMETERS,))
            d_q_d_u[:, :, :42] = expand_leg_parameters(d_q_d_leg)
            legs = np.arange(6)
            d_q_d_u[:, legs, _KQ.start + legs] = -self.leg_lengths[use]
            d_pose_d_u = -np.linalg.solve(d_q_d_pose, d_q_d_u[:, :, self.free])
            d_pred_d_u = d_pred_d_pose @ d_pose_d_u + d_pred_d_u[:, :, self.free]
            jacobian[use] = -d_pred_d_u * self.weights[None, :, None]
        if self.root_weights is not None:
            residuals *= self.root_weights
            if linearize:
                jacobian *= self.root_weights[..., None]
        return residuals, jacobian, poses, converged

    def _paper_prediction(self, geometry, poses, use):
        """Eq (11)'s predictions with ``D = D0 + (1 + kDm) Dm`` and the reading offsets."""
        d_m = self.readings[use][:, 3]
        angles, d_angles_d_pose, d_angles_d_device = paper_inclinations_jacobians(
            geometry, poses, (1.0 + geometry.sensors.lvdt_gain_error) * d_m
        )
        offsets = np.append(geometry.sensors.inclinometer_offsets, geometry.sensors.encoder_offset)
        predicted = np.concatenate([angles, poses[:, 5:6]], axis=1) + offsets
        d_pose = np.concatenate([d_angles_d_pose, np.zeros((poses.shape[0], 1, 6))], axis=1)
        d_pose[:, 2, 5] = 1.0
        d_u = np.zeros((poses.shape[0], 3, NUM_ALL_PARAMETERS))
        d_u[:, 0:2, [_D0, _GAMMA]] = d_angles_d_device
        d_u[:, 0:2, _KDM] = d_angles_d_device[:, :, 0] * d_m[:, None]
        for row, column in enumerate(_OFFSETS):
            d_u[:, row, column] = 1.0
        keep = [c for c in (0, 1, 2) if c in self.columns]
        return predicted[:, keep], d_pose[:, keep], d_u[:, keep]

    def _point(self, values):
        residuals, jacobian, poses, converged = self.evaluate(values, linearize=True)
        return Point(values, residuals, cost_of(residuals), jacobian, (poses, converged))

    # --- the driver's interface ---

    def restart(self, point):
        """``point`` evaluated again (after the robust weights changed)."""
        return self._point(point.values)

    def unknowns(self):
        """Unknowns the residuals estimate: the free parameters."""
        return int(self.free.sum())

    def start(self):
        """The point at the nominal; postures whose FK fails there are left out from the start."""
        point = self._point(self.nominal_vector[self.free])
        poses, converged = point.state
        self.active &= converged
        self.poses = np.where(converged[:, None], poses, self.poses)
        return point

    def too_few_residuals(self):
        return self.active.sum() * len(self.columns) < self.free.sum()

    def normal_equations(self, point):
        flat_jacobian = point.linearization.reshape(-1, point.linearization.shape[2])
        normal = flat_jacobian.T @ flat_jacobian
        gradient = flat_jacobian.T @ point.residuals.ravel()
        diagonal = np.maximum(np.diag(normal), 1e-30)
        return np.max(np.abs(gradient) / np.sqrt(diagonal)), (normal, gradient, diagonal)

    def solve(self, point, system, damping):
        normal, gradient, diagonal = system
        step = np.linalg.solve(normal + damping * np.diag(diagonal), -gradient)
        predicted_reduction = -(gradient @ step) - 0.5 * step @ normal @ step
        return Step(step, None, predicted_reduction)

    def trial(self, point, step):
        trial = self._point(point.values + step.parameters)
        _, converged = trial.state
        trial.feasible = not (self.active & ~converged).any()
        return trial

    def give_up(self, point, trial):
        """The estimate keeps leaving FK's reach for these postures: drop them (reported)."""
        _, converged = trial.state
        self.active &= converged
        return self._point(point.values)

    def accept(self, trial):
        poses, converged = trial.state
        self.poses = np.where(converged[:, None], poses, self.poses)
        recovered = ~self.active & converged
        if not recovered.any():
            return trial, False
        # A better estimate brings a posture back within FK's reach: use it again.
        self.active |= recovered
        self.readmitted.update(np.flatnonzero(recovered).tolist())
        return self._point(trial.values), True

    # --- what the result reports ---

    def information(self, point):
        flat_jacobian = point.linearization.reshape(-1, point.linearization.shape[2])
        return flat_jacobian.T @ flat_jacobian

    def redundancy(self, point):
        """Redundancy numbers (M, k) of the weighted residuals; NaN rows: postures left out."""
        return redundancy_flat(point.linearization, self.active)

    def reported_residuals(self, point):
        """Normalised residuals (no robust weights) with NaN rows for the postures left out."""
        residuals = point.residuals.copy()
        if self.root_weights is not None:
            residuals /= self.root_weights
        residuals[~self.active] = np.nan
        return residuals

    def column_names(self):
        """Name of each residual column."""
        return [READING_NAMES[c] for c in self.columns]

    def sensor_columns(self):
        """``{sensor: (column of the residuals, weight)}``."""
        return {READING_NAMES[c]: (i, self.weights[i]) for i, c in enumerate(self.columns)}

    def excluded_postures(self):
        return sorted(np.flatnonzero(~self.active).tolist())

    def estimated_poses(self, point):
        return self.poses.copy()

    def notes(self):
        """What the message adds to the termination reason: postures readmitted or left out."""
        notes = ''
        if self.readmitted:
            notes += (
                f'; posture(s) {sorted(self.readmitted)[:20]} readmitted after FK failed at an '
                'earlier estimate'
            )
        excluded = self.excluded_postures()
        if excluded:
            notes += f'; excluded posture(s) {excluded[:20]} where FK failed'
        return notes


class _ImplicitModel(_Model):
    """All sensors as residuals; the parameters and every pose are unknowns (a trial step's
    Jacobian, a :class:`_LazyJacobian`, is computed only if the driver keeps the step)."""

    #: The start (nominal, pose guesses) is close and the model nearly linear: Gauss-Newton-like
    #: steps from the first (cf. Madsen, Nielsen & Tingleff: tau = 1e-6 for a good start).
    initial_damping = 1e-6

    def __init__(
        self, nominal, leg_lengths, readings, sigmas, free, pose_guesses, sensors, effects=None
    ):
        super().__init__(nominal, free)
        self.effects = effects
        self.effect_count = 0 if effects is None else effects.count
        self.pose_guesses = pose_guesses
        self.leg_lengths = leg_lengths
        self.readings = readings
        self.columns = [c for c in range(4) if READING_NAMES[c] in sensors]
        self.leg_weight = 1.0 / sigmas.leg_lengths
        self.reading_weights = 1.0 / sigmas.readings()[self.columns]
        self.use_legs = channels.LEG_LENGTHS in sensors
        self.root_weights = None  #: (M, k) square roots of the robust weights (None: all 1)
        # The residual's rows among the ten readings of a posture (_readings.ROW_NAMES).
        self.rows = (list(range(6)) if self.use_legs else []) + [6 + c for c in self.columns]
        self.row_weights = np.concatenate(
            [np.full(6 if self.use_legs else 0, self.leg_weight), self.reading_weights]
        )
        self.measured = np.concatenate([leg_lengths, readings], axis=1)[:, self.rows]
        self.phi_row = self.rows.index(PHI_ROW) if PHI_ROW in self.rows else None
        # The effect parameters' columns, then the residual's.
        self.readings_model = ReadingsModel(free, extra_columns=self.effect_count + 1)

    def evaluate(self, free_values, poses, linearize):
        """``(residuals (M, k), jac_pose (M, k, 6), jac_u (M, k, n))``; Jacobians None unless
        ``linearize``."""
        residuals, jacobian = self._evaluate(free_values, poses)
        if not linearize:
            return residuals, None, None
        augmented = jacobian()
        return residuals, augmented[:, :, :6], augmented[:, :, 6:-1]

    def _evaluate(self, free_values, poses):
        """``(residuals, _LazyJacobian)`` at the free parameters and poses."""
        vector = self.nominal_vector.copy()
        count = len(free_values) - self.effect_count
        vector[self.free] = free_values[:count]
        prediction = self.readings_model.predict(vector, poses)
        if self.effect_count:
            # q_i (1 + kq_i) gains sum theta h (effects.groups); d/d theta = h / (1 + kq_i).
            # The regressors at the current estimate (d h / d geometry left out of the Jacobian).
            estimate = Geometry.from_full_vector(vector, self.limits)
            columns = self.effects.regressors(poses, estimate) * prediction.leg_scale[None, :, None]
            prediction.readings[:, :6] += columns @ free_values[count:]
            prediction.effect_columns = columns
        predicted = prediction.readings
        if len(self.rows) < predicted.shape[1]:
            predicted = predicted[:, self.rows]
        residuals = predicted - self.measured
        if self.phi_row is not None:
            residuals[:, self.phi_row] = wrap_angle(residuals[:, self.phi_row])
        residuals *= self.row_weights
        if self.root_weights is not None:
            residuals *= self.root_weights
        return residuals, _LazyJacobian(self, prediction, residuals)

    def _augmented(self, prediction, residuals):
        """The weighted ``[J_X | J_u | r]`` (M, k, 6 + n + 1) of a prediction."""
        augmented = prediction.jacobian()
        if self.effect_count:
            end = augmented.shape[2] - 1
            augmented[:, :6, end - self.effect_count : end] = prediction.effect_columns
        if len(self.rows) < augmented.shape[1]:
            augmented = augmented[:, self.rows]
        augmented *= self.row_weights[:, None]
        if self.root_weights is not None:
            augmented *= self.root_weights[..., None]
        augmented[:, :, -1] = residuals
        return augmented

    def _point(self, values, poses):
        residuals, jacobian = self._evaluate(values, poses)
        return Point(values, residuals, cost_of(residuals), jacobian, poses)

    # --- the driver's interface ---

    def restart(self, point):
        """``point`` evaluated again (after the robust weights changed)."""
        return self._point(point.values, point.state)

    def unknowns(self):
        """Unknowns the residuals estimate: the free parameters and six a pose."""
        return int(self.free.sum()) + self.effect_count + 6 * self.leg_lengths.shape[0]

    def start(self):
        """The point at the nominal with the pose guesses. The poses are unknowns: the first
        steps (each a damped Newton step on the poses too) do the work of an FK beforehand."""
        start = np.concatenate([self.nominal_vector[self.free], np.zeros(self.effect_count)])
        return self._point(start, self.pose_guesses.copy())

    def too_few_residuals(self):
        return False  # the poses are unknowns too: the design, not FK, decides identifiability

    def normal_equations(self, point):
        pose_rows, parameter_block = point.linearization.normal_equations()
        size = parameter_block.shape[0] - 1
        diag_pose = np.maximum(np.diagonal(pose_rows[:, :, :6], axis1=1, axis2=2), 1e-30)
        diag_u = np.maximum(np.diag(parameter_block)[:size], 1e-30)
        scaled_gradient = max(
            np.max(np.abs(parameter_block[:size, size]) / np.sqrt(diag_u)),
            np.max(np.abs(pose_rows[:, :, -1]) / np.sqrt(diag_pose)),
        )
        return scaled_gradient, (pose_rows, parameter_block, diag_pose, diag_u)

    def solve(self, point, system, damping):
        pose_rows, parameter_block, diag_pose, diag_u = system
        reduced, solved = eliminate_poses(
            pose_rows, parameter_block, damping * diag_pose, damping * diag_u
        )
        size = reduced.shape[0]
        step_u = np.linalg.solve(reduced[:, :size], -reduced[:, size])
        step_pose = -(solved[:, :, size] + solved[:, :, :size] @ step_u)
        # The Gauss-Newton model's decrease for a step h of (H + damping D) h = -g:
        # -g.h - h.H.h / 2 = (damping h.D.h - g.h) / 2 (no cancellation, no J h needed).
        gradient_step = float(
            np.einsum('mj,mj->', pose_rows[:, :, -1], step_pose)
            + parameter_block[:size, size] @ step_u
        )
        damped_step = float(np.einsum('mj,mj,mj->', diag_pose, step_pose, step_pose))
        damped_step += float(diag_u @ step_u**2)
        predicted_reduction = 0.5 * (damping * damped_step - gradient_step)
        return Step(step_u, step_pose, predicted_reduction)

    def trial(self, point, step):
        return self._point(point.values + step.parameters, point.state + step.others)

    def give_up(self, point, trial):
        raise AssertionError('the implicit model has no infeasible trials')

    def accept(self, trial):
        return trial, False

    # --- what the result reports ---

    def information(self, point):
        reduced, _ = eliminate_poses(*point.linearization.normal_equations())
        return reduced[:, :-1]

    def redundancy(self, point):
        """Redundancy numbers (M, k) of the weighted residuals (the poses are unknowns too)."""
        augmented = point.linearization()
        return redundancy_with_poses(
            augmented[:, :, :6], augmented[:, :, 6:-1], self.information(point)
        )

    def reported_residuals(self, point):
        """Normalised residuals (no robust weights)."""
        if self.root_weights is None:
            return point.residuals
        return point.residuals / self.root_weights

    def column_names(self):
        """Name of each residual column."""
        legs = list(channels.sensor_channel_names(channels.LEG_LENGTHS)) if self.use_legs else []
        return legs + [READING_NAMES[c] for c in self.columns]

    def sensor_columns(self):
        """``{sensor: (column(s) of the residuals, weight)}``."""
        columns = {}
        first = 0
        if self.use_legs:
            columns[channels.LEG_LENGTHS] = (
                channels.SENSOR_SLICES[channels.LEG_LENGTHS],
                self.leg_weight,
            )
            first = channels.LEG_COUNT
        for i, c in enumerate(self.columns):
            columns[READING_NAMES[c]] = (first + i, self.reading_weights[i])
        return columns

    def excluded_postures(self):
        return []

    def estimated_poses(self, point):
        return point.state

    def notes(self):
        return ''


class _LazyJacobian:
    """A point's weighted ``[J_X | J_u | r]``, computed on the first call and kept, and its
    normal equations (:func:`gsp_kinematics.estimation._solver.lm.block_normal_equations`), likewise."""

    def __init__(self, model, prediction, residuals):
        self._arguments = (prediction, residuals)
        self._model = model
        self._value = None
        self._normal_equations = None

    def normal_equations(self):
        if self._normal_equations is None:
            self._normal_equations = block_normal_equations(self())
        return self._normal_equations

    def __call__(self):
        if self._value is None:
            self._value = self._model._augmented(*self._arguments)
            self._arguments = None  # the prediction's intermediates are no longer needed
        return self._value
