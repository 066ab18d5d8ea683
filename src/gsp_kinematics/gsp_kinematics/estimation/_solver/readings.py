"""What every sensor reads at given poses, and its analytic Jacobian, in one batched pass (private)
(docs/sensor_errors.md)."""

import numpy as np

from gsp_kinematics import channels

from ...model.device import position_to_inclinations
from ...model.geometry import NUM_ALL_PARAMETERS, PARAMETER_INDEX
from ...rotation import euler_to_matrix

#: The ten readings of a posture, in row order.
ROW_NAMES = channels.CHANNEL_NAMES
#: Row of the yaw reading ``phi`` (an angle: a difference of it is wrapped).
PHI_ROW = channels.CIRCULAR_COLUMNS[0]
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
_A = slice(PARAMETER_INDEX['A1x'], PARAMETER_INDEX['A6z'] + 1)
_B = slice(PARAMETER_INDEX['B1x'], PARAMETER_INDEX['B6z'] + 1)
_LOFF = slice(PARAMETER_INDEX['Loff1'], PARAMETER_INDEX['Loff6'] + 1)
_KQ = slice(PARAMETER_INDEX['kq1'], PARAMETER_INDEX['kq6'] + 1)
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
    """The readings and Jacobians of a fixed set of free parameters (``free``: 54 bools); the
    Jacobian's columns are the pose (6), the free parameters in vector order, then
    ``extra_columns`` zero columns for the caller."""

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
        self._kept = (rotation, rotated, vectors, lengths, alpha, link)

    def jacobian(self):
        """The Jacobian of the readings (M, 10, width): the pose, then the free parameters (the
        extra columns zero)."""
        model = self.model
        rotation, rotated, vectors, lengths, alpha, link = self._kept
        count = self.poses.shape[0]
        out = np.zeros((count, 10, model.width))
        scale = self.leg_scale[:, None]
        directions = vectors / lengths[..., None]
        scaled = directions * scale  # d reading_i / dt = n_i / (1 + kq_i)
        out[:, :6, :3] = scaled
        # d(R B_i)/d(angle a) = omega_a x R B_i, so d reading_i/d(angle a) = omega_a . c_i with
        # c_i = R B_i x n_i / (1 + kq_i); for R = R_Y(theta) R_X(psi) R_z(phi):
        # omega_psi = R_Y e_x = (cos theta, 0, -sin theta), omega_theta = e_y, omega_phi = R e_z.
        p_x, p_y, p_z = rotated[..., 0], rotated[..., 1], rotated[..., 2]
        n_x, n_y, n_z = scaled[..., 0], scaled[..., 1], scaled[..., 2]
        c_x, c_y, c_z = p_y * n_z - p_z * n_y, p_z * n_x - p_x * n_z, p_x * n_y - p_y * n_x
        theta = self.poses[:, 4:5]
        out[:, :6, 3] = c_x * np.cos(theta) - c_z * np.sin(theta)
        out[:, :6, 4] = c_y
        axis = rotation[:, None, :, 2]
        out[:, :6, 5] = c_x * axis[..., 0] + c_y * axis[..., 1] + c_z * axis[..., 2]
        # Leg parameters: d/dA_i = -n_i, d/dB_i = R^T n_i, d/dL_off_i = -1, all over (1 + kq_i);
        # d/dkq_i = -reading_i / (1 + kq_i).
        legs, columns, entries = model._leg_plan
        if legs.size:
            compact = np.empty((count, 6, 8))
            compact[:, :, 0:3] = -scaled
            compact[:, :, 3:6] = np.matmul(scaled, rotation)
            compact[:, :, 6] = -scale[:, 0]
            compact[:, :, 7] = -self.readings[:, :6] * scale[:, 0]
            out[:, legs, columns] = compact[:, legs, entries]
        self._device_jacobian(out, link, alpha)
        return out

    def _device_jacobian(self, out, link, alpha):
        """Rows 6-9: the inclinometer, the encoder and the LVDT.

        With the unit link direction ``u`` (device.position_to_inclinations): ``sin(alpha) =
        u_y - u_x cot(gamma)``, and ``beta = atan2(b, a) + atan2(-u_z, r)`` with ``a = cos(gamma)
        sin(alpha)``, ``b = cos(alpha)``, ``r = u_x / sin(gamma) + a``. Only the tangent part of
        dt moves u: ``du = (I - u u^T) dt / |t|``.
        """
        gamma = self.parameters[_GAMMA]
        sin_gamma, cos_gamma = np.sin(gamma), np.cos(gamma)
        unit = self.poses[:, :3] / link[:, None]
        u_x, u_z = unit[:, 0], unit[:, 2]
        sin_alpha, cos_alpha = np.sin(alpha), np.cos(alpha)
        r = u_x / sin_gamma + cos_gamma * sin_alpha
        first = 1.0 - (sin_gamma * sin_alpha) ** 2  # a^2 + b^2
        second = r**2 + u_z**2
        # d alpha = (du_y - cot(gamma) du_x + u_x / sin(gamma)^2 dgamma) / cos(alpha);
        # d beta = (-cos(gamma) d alpha + sin(gamma) sin(alpha) cos(alpha) dgamma) / first
        #          + (u_z dr - r du_z) / second, dr = du_x / sin(gamma) + da - u_x cos(gamma) /
        #          sin(gamma)^2 dgamma, da = cos(gamma) cos(alpha) d alpha - sin(gamma) sin(alpha) dgamma
        via_alpha = cos_gamma * (u_z * cos_alpha / second - 1.0 / first)
        rows = np.zeros((alpha.size, 2, 3))
        rows[:, 0, 0] = -cos_gamma / (sin_gamma * cos_alpha)
        rows[:, 0, 1] = 1.0 / cos_alpha
        rows[:, 1] = via_alpha[:, None] * rows[:, 0]
        rows[:, 1, 0] += u_z / (sin_gamma * second)
        rows[:, 1, 2] -= r / second
        tangent = rows - np.einsum('mrk,mk->mr', rows, unit)[..., None] * unit[:, None, :]
        out[:, 6:8, :3] = tangent / link[:, None, None]
        out[:, 8, 5] = 1.0
        out[:, 9, :3] = unit * self.lvdt_scale
        rows, columns, device_rows, entries = self.model._device_plan
        if rows.size:
            alpha_gamma = u_x / (sin_gamma**2 * cos_alpha)
            beta_gamma = (
                via_alpha * alpha_gamma
                + sin_gamma * sin_alpha * cos_alpha / first
                - u_z * (u_x * cos_gamma / sin_gamma**2 + sin_gamma * sin_alpha) / second
            )
            compact = np.zeros((alpha.size, 4, 6))
            compact[:, 0, 1] = alpha_gamma
            compact[:, 1, 1] = beta_gamma
            compact[:, 0, 2] = compact[:, 1, 3] = compact[:, 2, 4] = 1.0
            compact[:, 3, 0] = -self.lvdt_scale
            compact[:, 3, 5] = -self.readings[:, 9] * self.lvdt_scale
            out[:, rows, columns] = compact[:, device_rows, entries]


#: Every parameter free: the full extended Jacobian.
_EVERY_PARAMETER = ReadingsModel(np.ones(NUM_ALL_PARAMETERS, dtype=bool))


def readings_jacobians(geometry, poses):
    """The ten readings (M, 10) at ``poses`` (M, 6) under ``geometry``, their derivatives w.r.t.
    the pose (M, 10, 6) and w.r.t. the extended parameter vector (M, 10, 54)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    prediction = _EVERY_PARAMETER.predict(geometry.to_full_vector(), poses)
    jacobian = prediction.jacobian()
    return prediction.readings, jacobian[:, :, :6], jacobian[:, :, 6:]
