"""The identification's Levenberg-Marquardt driver and the Schur complement (private).

One loop serves every formulation; a formulation is a *model* that supplies
``normal_equations(point) -> (scaled_gradient, system)``, ``solve(point, system, damping) ->
Step``, ``trial(point, step) -> Point`` (``feasible`` False where FK fails), ``give_up(point,
trial)``, ``initial_damping`` and ``accept(trial) -> (point, changed)``. The driver stops on
the step, the change of the residual (the paper's Fig. 5) or a vanishing gradient
(:data:`TERMINATION_MESSAGES`)."""

import dataclasses
import math

import numpy as np

#: Status of an identification -> its message (``status > 0``: converged).
TERMINATION_MESSAGES = {
    -1: 'too few residuals for the free parameters',
    0: 'maximum number of iterations reached',
    1: 'du: parameter step below tolerance',
    2: 'dX: residual change below tolerance',
    3: 'gradient below tolerance',
}


@dataclasses.dataclass
class Point:
    """An estimate of the free parameters and what the model computed there."""

    values: np.ndarray  #: the free parameters u (m, rad)
    residuals: np.ndarray  #: (M, k) weighted residuals
    cost: float  #: 0.5 * sum of squared residuals
    linearization: object = None  #: the model's Jacobian(s) at the point
    state: object = None  #: the model's other unknowns or bookkeeping (e.g. the poses)
    feasible: bool = True  #: False: the model could not be evaluated here


@dataclasses.dataclass
class Step:
    """A damped step: ``du``, the model's other unknowns' step, and the model's predicted gain."""

    parameters: np.ndarray  #: du
    others: np.ndarray | None  #: e.g. the poses' step (m, rad); None if there are none
    predicted_reduction: float  #: the decrease of the cost the linear model promises


def cost_of(residuals):
    """0.5 * sum of squared residuals."""
    return 0.5 * float(np.sum(residuals**2))


def levenberg_marquardt(model, start, options):
    """Minimise the model's cost from ``start``: ``(point, status, iterations)``; ``options``: an
    :class:`gsp_kinematics.estimation.identification.Options`."""
    point = start
    damping = options.initial_damping
    damping, nu = model.initial_damping if damping is None else damping, 2.0
    status, iteration, rejections = 0, 0, 0
    linearized = None  # the point the normal equations ``system`` belong to
    for iteration in range(1, options.max_iterations + 1):  # noqa: B007 (reported after)
        if point is not linearized:
            # After a rejected step only the damping changes: the system is reused.
            scaled_gradient, system = model.normal_equations(point)
            linearized = point
            if scaled_gradient <= options.gradient_tolerance * max(1.0, math.sqrt(2 * point.cost)):
                status = 3
                break
        step = model.solve(point, system, damping)
        if step.predicted_reduction <= options.cost_tolerance * point.cost:
            # The linear model promises less than dX's tolerance, below the rounding noise of the
            # cost itself: another step would only shuffle the last digits (cf. MINPACK's ftol).
            status = 2
            break
        trial = model.trial(point, step)
        if not trial.feasible:
            rejections += 1
            damping, nu = damping * nu, nu * 2.0
            if rejections >= options.max_fk_rejections:
                point = model.give_up(point, trial)
                rejections = 0
            continue
        rejections = 0
        if step.predicted_reduction > 0 and math.isfinite(trial.cost):
            ratio = (point.cost - trial.cost) / step.predicted_reduction
        else:
            ratio = -1.0
        damping, nu = _update_damping(damping, ratio, nu)
        if ratio > 0.0:
            decrease = point.cost - trial.cost
            point, changed = model.accept(trial)
            if changed:
                continue
            if _step_is_small(step, point.values, options):
                status = 1
                break
            if decrease <= options.cost_tolerance * point.cost:
                status = 2
                break
        elif _step_is_small(step, point.values, options):
            status = 1
            break
    return point, status, iteration


def _update_damping(damping, ratio, nu):
    """Nielsen's update: shrink the damping after a good step, grow it geometrically after a bad one."""
    if ratio > 0.0:
        return damping * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3), 2.0
    return damping * nu, nu * 2.0


def _step_is_small(step, values, options):
    """``|du| <= tol * (tol + |u|)``, and the other unknowns moved by at most ``10 tol``."""
    tolerance = options.step_tolerance
    if np.linalg.norm(step.parameters) > tolerance * (tolerance + np.linalg.norm(values)):
        return False
    return step.others is None or np.max(np.abs(step.others)) <= tolerance * 10.0


# --- the poses eliminated: Schur complement --------------------------------------------------------
#
# The implicit formulation's Jacobian is block-sparse: posture m's k residuals depend on its own
# pose X_m (6) and on the n parameters u. Its rows are kept per posture as one augmented array
# ``[J_X | J_u | r]`` (M, k, 6 + n + 1), and the normal equations as two dense pieces whose size
# grows linearly with M: ``pose_rows`` (M, 6, 6 + n + 1) = ``J_X^T [J_X | J_u | r]`` per posture,
# and ``parameter_block`` (n + 1, n + 1) = ``[J_u | r]^T [J_u | r]`` summed over the postures.
# Eliminating the 6 x 6 pose blocks (the Schur complement) leaves an n x n system.


def block_normal_equations(augmented):
    """``(pose_rows, parameter_block)`` of an augmented Jacobian ``[J_X | J_u | r]`` (M, k, 6+n+1)."""
    pose_rows = np.matmul(np.swapaxes(augmented[:, :, :6], 1, 2), augmented)
    # Merging the posture and row axes of the slice is a view: one product over all rows.
    flat = augmented[:, :, 6:].reshape(-1, augmented.shape[2] - 6)
    return pose_rows, flat.T @ flat


def eliminate_poses(pose_rows, parameter_block, pose_damping=None, parameter_damping=None):
    """``(reduced (n, n+1), solved (M, 6, n+1))``: the reduced system ``[S | g_S]`` and
    ``H_XX^-1 [H_Xu | g_X]`` (``S = H_uu - sum_m H_Xu^T H_XX^-1 H_Xu``), ``pose_damping`` (M, 6)
    and ``parameter_damping`` (n,), if given, added to the diagonals of ``H_XX`` and ``H_uu``."""
    size = parameter_block.shape[0] - 1
    h_xx = pose_rows[:, :, :6]
    if pose_damping is not None:
        h_xx = h_xx.copy()
        h_xx.reshape(-1, 36)[:, ::7] += pose_damping  # the diagonals of the 6x6 blocks
    # One batched inverse of the 6 x 6 blocks: far cheaper than a batched solve with n + 1
    # right-hand sides, which copies each posture's system.
    solved = np.linalg.inv(h_xx) @ pose_rows[:, :, 6:]
    h_xu = pose_rows[:, :, 6 : 6 + size].reshape(-1, size)
    reduced = parameter_block[:size] - h_xu.T @ solved.reshape(-1, size + 1)
    if parameter_damping is not None:
        reduced[:, :size] += np.diag(parameter_damping)
    return reduced, solved
