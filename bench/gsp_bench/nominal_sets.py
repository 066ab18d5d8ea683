"""The paper's exact geometry ("the drawing") and its nominal parameter sets (Tables 1 and 2).

The table numbers come from the shipped tables (:mod:`gsp_bench.tables`).
"""

import math

import numpy as np
from scipy.optimize import least_squares

from gsp_kinematics.model.geometry import Geometry, Limits, SensorErrors

from .tables import load_tables, table1, table2

_TABLES, _ = load_tables()
#: Table 1: (max, mean, sigma) of the 42 platform-parameter errors, mm.
TABLE1_ERRORS_MM = table1(_TABLES)
#: Table 2: nominal (D0 mm, gamma deg). The exact values are 850 mm and 90 deg.
TABLE2_DEVICE = table2(_TABLES)
EXACT_DEVICE_LENGTH = _TABLES['exact_device']['device_length_mm'] / 1000.0  # m
EXACT_INCLINOMETER_AXES_ANGLE = math.radians(_TABLES['exact_device']['inclinometer_axes_angle_deg'])


def drawing_geometry(
    base_radius=1.0,
    platform_radius=0.8,
    base_half_angle_deg=15.0,
    platform_half_angle_deg=15.0,
    leg_offset=0.6,
    device_length=EXACT_DEVICE_LENGTH,
    inclinometer_axes_angle=EXACT_INCLINOMETER_AXES_ANGLE,
):
    """The symmetric 6-6 design ("the drawing") that the default files derive from.

    Base joint pairs straddle 0, 120 and 240 deg; platform pairs straddle 60, 180 and 300 deg, so
    each leg joins neighbouring corners. Limits: stroke 0..1.2 m, joint angles 70/80 deg. With the
    paper's ranges (x, y +-400 mm, z 850..1150 mm, rotations +-40 deg) about 63 % of random postures
    are reachable. The wide platform (0.8 m vs 1.0 m base) keeps orientation well conditioned.
    """
    base, platform = [], []
    for corner in range(3):
        for side in (-1, 1):
            angle = math.radians(120.0 * corner + side * base_half_angle_deg)
            base.append([base_radius * math.cos(angle), base_radius * math.sin(angle), 0.0])
            angle = math.radians(120.0 * corner + side * (60.0 - platform_half_angle_deg))
            platform.append(
                [platform_radius * math.cos(angle), platform_radius * math.sin(angle), 0.0]
            )
    return Geometry(
        base_joints=np.array(base),
        platform_joints=np.array(platform),
        leg_offsets=np.full(6, leg_offset),
        device_length=device_length,
        inclinometer_axes_angle=inclinometer_axes_angle,
        limits=Limits(
            leg_stroke_min=0.0,
            leg_stroke_max=1.2,
            base_joint_max_angle=math.radians(70.0),
            platform_joint_max_angle=math.radians(80.0),
        ),
    )


def errors_with_statistics(rng, count, maximum, mean, sigma):
    """``count`` signed errors whose max |e|, mean |e| and std match the given values.

    Draws Gaussian magnitudes, then shapes them with ``a * m**p`` (largest pinned to ``maximum``)
    so the three statistics match exactly; signs alternate-randomly with zero mean.
    """
    magnitudes = np.abs(rng.standard_normal(count))
    order = np.argsort(magnitudes)
    signs = rng.permutation(np.resize([1.0, -1.0], count))
    normalised = magnitudes / magnitudes.max()

    def shaped(p):
        values = normalised**p
        values[order[-1]] = 1.0
        return values

    def mismatch(log_p_and_scale):
        p, scale = np.exp(log_p_and_scale)
        values = np.minimum(scale * shaped(p), 1.0) * maximum
        values[order[-1]] = maximum
        signed = values * signs
        return [values.mean() - mean, signed.std() - sigma]

    solution = least_squares(mismatch, x0=[0.0, 0.0], xtol=1e-14, ftol=1e-14)
    p, scale = np.exp(solution.x)
    values = np.minimum(scale * shaped(p), 1.0) * maximum
    values[order[-1]] = maximum
    return values * signs


def nominal_set(exact, set_number, seed=0):
    """Nominal set 1-3: ``exact`` plus platform errors with Table 1's statistics and Table 2's device."""
    if set_number not in TABLE1_ERRORS_MM:
        raise ValueError(f'nominal set must be 1, 2 or 3, got {set_number}')
    rng = np.random.default_rng(1000 * set_number + seed)
    maximum, mean, sigma = TABLE1_ERRORS_MM[set_number]
    errors = errors_with_statistics(rng, 42, maximum, mean, sigma) / 1000.0
    vector = exact.to_vector()
    vector[:42] += errors
    device_length_mm, gamma_deg = TABLE2_DEVICE[set_number]
    vector[42] = device_length_mm / 1000.0
    vector[43] = math.radians(gamma_deg)
    return Geometry.from_vector(vector, exact.limits)


#: Sensor errors of the shipped real platform (docs/sensor_errors.md): leg gain errors of a few
#: 1e-4, an inclinometer alpha offset of 0.01 deg (identifiable; beta0 is not, and stays 0) and an
#: LVDT gain error of 1e-3, which is the length datum: the nominal model carries it (bench
#: calibrated against gauge blocks), since no calibration from these sensors can find it.
DEFAULT_SENSOR_ERRORS = SensorErrors(
    leg_gain_errors=[3e-4, -2e-4, 4e-4, -1e-4, 2e-4, -3e-4],
    inclinometer_offsets=[math.radians(0.01), 0.0],
    encoder_offset=0.0,
    lvdt_gain_error=1e-3,
)


def default_true_and_nominal(seed=7):
    """The shipped demo pair: the real platform (drawing with set-1-sized errors, D0 850 mm,
    gamma 90 deg, :data:`DEFAULT_SENSOR_ERRORS`) and its nominal model (the clean drawing with
    Table 2 set 1's device values and the LVDT gain datum)."""
    drawing = drawing_geometry()
    rng = np.random.default_rng(seed)
    maximum, mean, sigma = TABLE1_ERRORS_MM[1]
    vector = drawing.to_vector()
    vector[:42] += errors_with_statistics(rng, 42, maximum, mean, sigma) / 1000.0
    true = Geometry.from_vector(vector, drawing.limits).replace(sensors=DEFAULT_SENSOR_ERRORS)
    device_length_mm, gamma_deg = TABLE2_DEVICE[1]
    nominal = drawing.replace(
        device_length=device_length_mm / 1000.0,
        inclinometer_axes_angle=math.radians(gamma_deg),
        sensors=SensorErrors(lvdt_gain_error=DEFAULT_SENSOR_ERRORS.lvdt_gain_error),
    )
    return true, nominal
