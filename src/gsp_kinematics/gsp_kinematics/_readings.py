"""What every sensor reads at given poses, and its analytic Jacobian, in one batched pass (private).

A posture has ten readings (:data:`ROW_NAMES`): the six leg sensors ``q_i / (1 + kq_i)`` with
``q_i = |R B_i + t - A_i| - L_off_i``, then the device's ``[alpha, beta, phi, d_m]`` with the sensor
errors (docs/sensor_errors.md). Each row depends on its own pose and on a few entries of the
extended parameter vector (:data:`gsp_kinematics.geometry.ALL_PARAMETER_NAMES`): leg i on
``A_i, B_i, L_off_i, kq_i``, the device rows on ``D0, gamma, alpha0, beta0, phi0, kDm``. The
Jacobian is written straight into the columns of the free parameters, without the full 54 columns.

:class:`ReadingsModel` splits the work in two: :meth:`ReadingsModel.predict` (the readings, and
what the derivatives reuse) and :meth:`Prediction.jacobian`, so that a trial step the
Levenberg-Marquardt driver rejects never pays for its Jacobian.
"""

import numpy as np

from .device import READING_NAMES, link_direction_derivatives, position_to_inclinations
from .geometry import NUM_ALL_PARAMETERS, PARAMETER_INDEX
from .rotation import euler_to_matrix

#: The ten readings of a posture, in row order.
ROW_NAMES = tuple(f'leg{leg}' for leg in range(1, 7)) + READING_NAMES
#: Row of the yaw reading ``phi`` (an angle: a difference of it is wrapped).
PHI_ROW = ROW_NAMES.index('phi')
#: Extended-vector columns each leg row depends on: ``A_i (3), B_i (3), L_off_i, kq_i``.
_LEG_COLUMNS = np.array(
    [
        [PARAMETER_INDEX[f'A{leg}{axis}'] for axis in 'xyz']
        + [PARAMETER_INDEX[f'B{leg}{axis}'] for axis in 'xyz']
        + [PARAMETER_INDEX[f'Loff{leg}'], PARAMETER_INDEX[f'kq{leg}']]
        for leg in range(1, 7)
    ]
)
#: Extended-vector columns the device rows depend on.
_DEVICE_COLUMNS = np.array(
    [PARAMETER_INDEX[name] for name in ('D0', 'gamma', 'alpha0', 'beta0', 'phi0', 'kDm')]
)
_A, _B = slice(0, 18), slice(18, 36)
_LOFF, _KQ = slice(36, 42), slice(44, 50)
_D0, _GAMMA, _KDM = PARAMETER_INDEX['D0'], PARAMETER_INDEX['gamma'], PARAMETER_INDEX['kDm']
_OFFSETS = slice(PARAMETER_INDEX['alpha0'], PARAMETER_INDEX['phi0'] + 1)


#: Which device parameter (columns of ``_DEVICE_COLUMNS``) each device row depends on.
_DEVICE_DEPENDS_ON = np.array(
    [
        # D0, gamma, alpha0, beta0, phi0, kDm
        [0, 1, 1, 0, 0, 0],  # alpha
        [0, 1, 0, 1, 0, 0],  # beta
        [0, 0, 0, 0, 1, 0],  # phi
        [1, 0, 0, 0, 0, 1],  # d_m
    ],
    dtype=bool,
)


class ReadingsModel:
    """The readings and Jacobians of a fixed set of free parameters.

    ``free``: 54 bools over the extended vector; the Jacobian's columns are the pose (6) and then
    the free parameters in vector order. ``extra_columns`` more (zero) columns are allocated after
    them, for the caller's use (the identification appends the residual).
    """

    def __init__(self, free, extra_columns=0):
        free = np.asarray(free, dtype=bool)
        self.free = free
        self.width = 6 + int(free.sum()) + extra_columns
        column = np.full(NUM_ALL_PARAMETERS, -1)
        column[free] = 6 + np.arange(int(free.sum()))
        # Scatter plans (rows, output columns, source entries) of the free entries only.
        legs, entries = np.nonzero(column[_LEG_COLUMNS] >= 0)
        self._leg_plan = (legs, column[_LEG_COLUMNS][legs, entries], entries)
        rows, entries = np.nonzero((column[_DEVICE_COLUMNS] >= 0)[None, :] & _DEVICE_DEPENDS_ON)
        self._device_plan = (6 + rows, column[_DEVICE_COLUMNS][entries], rows, entries)

    def predict(self, parameters, poses):
        """:class:`Prediction` of the ten readings (M, 10) at ``poses`` (M, 6) under the extended
        parameter vector ``parameters`` (54)."""
        return Prediction(self, np.asarray(parameters, dtype=float), np.asarray(poses, float))


class Prediction:
    """The readings at some poses (``readings``, (M, 10)) and, on demand, their Jacobian."""

    def __init__(self, model, parameters, poses):
        self.model = model
        self.poses = poses
        self.parameters = parameters
        rotation = euler_to_matrix(poses[:, 3:])
        position = poses[:, :3]
        rotated = np.matmul(parameters[_B].reshape(6, 3), np.swapaxes(rotation, 1, 2))  # R B_i
        vectors = rotated + (position[:, None, :] - parameters[_A].reshape(6, 3))
        lengths = np.sqrt(np.einsum('mik,mik->mi', vectors, vectors))
        self.leg_scale = 1.0 / (1.0 + parameters[_KQ])
        gamma = parameters[_GAMMA]
        alpha, beta = position_to_inclinations(position, gamma)
        link = np.sqrt(np.einsum('mk,mk->m', position, position))
        self.lvdt_scale = 1.0 / (1.0 + parameters[_KDM])
        readings = np.empty((poses.shape[0], 10))
        readings[:, :6] = (lengths - parameters[_LOFF]) * self.leg_scale
        readings[:, 6] = alpha
        readings[:, 7] = beta
        readings[:, 8] = poses[:, 5]
        readings[:, 6:9] += parameters[_OFFSETS]
        readings[:, 9] = (link - parameters[_D0]) * self.lvdt_scale
        self.readings = readings
        self._kept = (rotation, rotated, vectors, lengths, alpha, beta, link)

    def jacobian(self, out=None):
        """The Jacobian of the readings (M, 10, width): the pose, then the free parameters;
        written into ``out`` when given (its other columns untouched, zeros expected)."""
        model = self.model
        rotation, rotated, vectors, lengths, alpha, beta, link = self._kept
        count = self.poses.shape[0]
        if out is None:
            out = np.zeros((count, 10, model.width))
        scale = self.leg_scale[:, None]
        directions = vectors / lengths[..., None]
        # d(R B_i)/d(angle a) = omega_a x R B_i, so dq_i/d(angle a) = omega_a . (R B_i x n_i); for
        # R = R_Y(theta) R_X(psi) R_z(phi): omega_psi = R_Y e_x, omega_theta = e_y, omega_phi = R e_z.
        theta = self.poses[:, 4]
        omega = np.zeros((count, 3, 3))
        omega[:, 0, 0] = np.cos(theta)
        omega[:, 2, 0] = -np.sin(theta)
        omega[:, 1, 1] = 1.0
        omega[:, :, 2] = rotation[:, :, 2]
        out[:, :6, :3] = directions * scale
        out[:, :6, 3:6] = np.matmul(np.cross(rotated, directions), omega) * scale
        # Leg parameters: dq/dA_i = -n_i, dq/dB_i = R^T n_i, dq/dL_off_i = -1; the reading
        # q_i / (1 + kq_i) adds -reading / (1 + kq_i) for kq_i.
        legs, columns, entries = model._leg_plan
        if legs.size:
            compact = np.empty((count, 6, 8))
            compact[:, :, 0:3] = -directions
            compact[:, :, 3:6] = np.matmul(directions, rotation)
            compact[:, :, 6] = -1.0
            compact[:, :, 7] = -self.readings[:, :6]
            compact *= scale
            out[:, legs, columns] = compact[:, legs, entries]
        self._device_jacobian(out, link, alpha, beta)
        return out

    def _device_jacobian(self, out, link, alpha, beta):
        """Rows 6-9: the inclinometer, the encoder and the LVDT."""
        gamma = self.parameters[_GAMMA]
        unit = self.poses[:, :3] / link[:, None]
        d_alpha, d_beta, d_gamma = link_direction_derivatives(alpha, beta, gamma)
        # On the link's unit sphere, sin(alpha) = u_y - u_x cot(gamma) (device.position_to_
        # inclinations): d alpha = row_alpha . du; then du = G_alpha d alpha + G_beta d beta gives
        # d beta = G_beta . (du - G_alpha d alpha) / |G_beta|^2. Only the tangent part of dt
        # moves u: du = (I - u u^T) dt / |t|.
        cos_alpha = np.cos(alpha)
        row_alpha = np.zeros((alpha.size, 3))
        row_alpha[:, 0] = -1.0 / (np.tan(gamma) * cos_alpha)
        row_alpha[:, 1] = 1.0 / cos_alpha
        beta_norm = np.einsum('mk,mk->m', d_beta, d_beta)
        cross_term = np.einsum('mk,mk->m', d_beta, d_alpha)
        row_beta = (d_beta - cross_term[:, None] * row_alpha) / beta_norm[:, None]
        rows = np.stack([row_alpha, row_beta], axis=1)  # (M, 2, 3)
        tangent = rows - np.einsum('mrk,mk->mr', rows, unit)[..., None] * unit[:, None, :]
        out[:, 6:8, :3] = tangent / link[:, None, None]
        out[:, 8, 5] = 1.0
        out[:, 9, :3] = unit * self.lvdt_scale
        rows, columns, device_rows, entries = self.model._device_plan
        if rows.size:
            alpha_gamma = unit[:, 0] / (np.sin(gamma) ** 2 * cos_alpha)
            beta_gamma = (
                -np.einsum('mk,mk->m', d_beta, d_alpha * alpha_gamma[:, None] + d_gamma) / beta_norm
            )
            compact = np.zeros((alpha.size, 4, 6))
            compact[:, 0, 1] = alpha_gamma
            compact[:, 1, 1] = beta_gamma
            compact[:, 0, 2] = compact[:, 1, 3] = compact[:, 2, 4] = 1.0
            compact[:, 3, 0] = -self.lvdt_scale
            compact[:, 3, 5] = -self.readings[:, 9] * self.lvdt_scale
            out[:, rows, columns] = compact[:, device_rows, entries]
