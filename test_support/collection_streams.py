"""Stamps and readings the collection tests feed the calibrator's streams with (no ROS):
one posture's leg lengths ``Q`` (m), device readings ``R`` ``[alpha, beta, phi, d_m]`` (rad, m),
its pose ``POSE`` and the per-channel noise ``NOISE`` of the ten reading channels."""

import numpy as np

MS = 1_000_000  #: ns
S = 1000 * MS  #: ns
T0 = 1_700_000_000 * S  #: a wall-clock stamp (ns)
Q = np.array([0.5, 0.51, 0.52, 0.53, 0.54, 0.55])
R = np.array([0.01, -0.02, 0.3, 0.004])
POSE = np.array([0.01, -0.01, 1.0, 0.01, -0.02, 0.03])
NOISE = [1e-6] * 6 + [1.7e-5, 1.7e-5, 1.7e-5, 1e-6]
