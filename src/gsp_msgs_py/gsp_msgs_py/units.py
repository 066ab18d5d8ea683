"""Unit constants and helpers. Everything inside the project is SI (m, rad, s); mm and deg are
for reports and logs only. Helpers accept scalars or array-likes (returned as numpy arrays)."""

import math

import numpy as np

M_TO_MM = 1000.0
MM_TO_M = 1.0 / M_TO_MM
M_TO_UM = 1.0e6
RAD_TO_DEG = 180.0 / math.pi
DEG_TO_RAD = math.pi / 180.0
NS_PER_S = 1_000_000_000


def _scale(value, factor):
    if np.ndim(value) == 0:
        return float(value) * factor
    return np.asarray(value, dtype=float) * factor


def m_to_mm(value):
    """Metres to millimetres."""
    return _scale(value, M_TO_MM)


def mm_to_m(value):
    """Millimetres to metres."""
    return _scale(value, MM_TO_M)


def rad_to_deg(value):
    """Radians to degrees."""
    return _scale(value, RAD_TO_DEG)


def deg_to_rad(value):
    """Degrees to radians."""
    return _scale(value, DEG_TO_RAD)
