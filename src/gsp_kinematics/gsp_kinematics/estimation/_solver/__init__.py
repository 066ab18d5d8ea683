"""The solver behind :mod:`gsp_kinematics.estimation.identification` (private): the formulations' residuals and
Jacobians (``formulations``), the device readings model (``readings``) and the Levenberg-Marquardt
driver with the Schur complement over the poses (``lm``); the shape of ``scipy.optimize._lsq``."""
