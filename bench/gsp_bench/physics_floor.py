"""The physics section's floor (:mod:`gsp_bench.physics`): what the suite's model can reach on
the physics platform, free of noise, and what its noise leaves of it.

* :func:`compensated_floor`: the true geometry as the controller, with the suite's compensation
  of the platform's sag (docs/platform_effects.md: leg compliance under the platform's 40 kg,
  heavy legs) fitted to where the physics platform rests (least squares, no noise). What the
  model cannot explain of the physics (the servos, the legs as two bodies, the joints' masses)
  stays in it.
* :func:`ideal_mm`: the calibrator's result at its defaults on the model's platform (the
  kinematic platform whose sag is the fitted compensation's, exactly what the model describes)
  with the same seed's plan and the sensors' default noise, the truth over the workspace
  (:func:`gsp_bench.verdict.one_run`): the error the fit makes at this noise.

A calibration on the physics platform can reach neither alone: its truth is judged against
``hypot(floor, ideal)``, the two as independent errors, in the median over seeds (one run's
truth scatters as much as the margin).
"""

import math

import numpy as np
from scipy.optimize import least_squares

from gsp_bench import verdict
from gsp_kinematics.model.effect_groups import EffectDesign, commanded_leg_readings, model_poses
from gsp_kinematics.model.effects import NUM_EFFECT_PARAMETERS, IdentifiedEffects, PlatformEffects
from gsp_kinematics.model.geometry import default_geometry
from gsp_platform_sim.physics_model import PhysicalParameters

#: Rotation weighed as position at this lever arm (m/rad) in the fit.
LEVER_ARM_M = 0.5
#: Noise draws of the ideal platform's run per seed.
NOISE_DRAWS = 5
#: The fit's start: the legs' stiffness (N/m), each leg's mass (kg), the centre of mass's z (m).
START = (PhysicalParameters().leg_stiffness, 12.0, 0.0)


def compensation(values):
    """``(controller, design)``: the true geometry compensating the compliance of ``values``
    (6 compliances m/N, the legs' mass kg, the centre of mass's height m) under the platform's
    mass."""
    design = EffectDesign(
        payload_mass=PhysicalParameters().platform_mass,
        centre_of_mass=(0.0, 0.0, float(values[7])),
        leg_mass=(float(values[6]),) * 6,
    )
    effects = np.zeros(NUM_EFFECT_PARAMETERS)
    effects[:6] = values[:6]
    identified = IdentifiedEffects.from_result_values(effects, design)
    return default_geometry('true').replace(effects=identified), design


def compensated_floor(poses, reached, true_position_mm):
    """The floor over ``poses`` (M, 6): ``reached`` (M, 6; NaN: refused) where the physics
    platform rests with the true geometry as its controller; ``true_position_mm(controller,
    poses)`` measures a controller on the physics. Returns ``floor_mm``, ``uncompensated_mm``
    and the fitted compensation (``compliance_m_per_n``, ``leg_mass_kg``, ``centre_of_mass_z_m``,
    ``fit_rms_um``)."""
    held = np.all(np.isfinite(reached), axis=1)
    poses, reached = poses[held], reached[held]
    true = default_geometry('true')
    readings = commanded_leg_readings(true, poses)
    weights = np.array([1.0, 1.0, 1.0, LEVER_ARM_M, LEVER_ARM_M, LEVER_ARM_M])
    scale = np.r_[np.full(6, 1.0 / START[0]), 1.0, 0.01]  # each unknown near 1 in the solver

    def residual(x):
        controller, design = compensation(x * scale)
        modelled, _ = model_poses(controller, readings, poses, design)
        return 1e6 * ((modelled - reached) * weights).ravel()  # um

    start = np.r_[np.ones(6), START[1], START[2] / scale[7]]
    fit = least_squares(residual, start, bounds=(np.r_[np.zeros(7), -50.0], np.full(8, 50.0)))
    values = fit.x * scale
    return {
        'floor_mm': true_position_mm(compensation(values)[0], poses),
        'uncompensated_mm': float(
            np.mean(1e3 * np.linalg.norm(reached[:, :3] - poses[:, :3], axis=1))
        ),
        'compliance_m_per_n': values[:6].tolist(),
        'leg_mass_kg': float(values[6]),
        'centre_of_mass_z_m': float(values[7]),
        'fit_rms_um': float(np.sqrt(np.mean(fit.fun**2))),
    }


def model_platform(floor):
    """The ``PlatformEffects`` of :func:`compensated_floor`'s fit ``floor``: the platform the
    model describes exactly."""
    return PlatformEffects(
        payload_mass=PhysicalParameters().platform_mass,
        centre_of_mass=np.array([0.0, 0.0, floor['centre_of_mass_z_m']]),
        leg_mass=np.full(6, floor['leg_mass_kg']),
        leg_stiffness=1.0 / np.asarray(floor['compliance_m_per_n']),
    )


def ideal_mm(seed, postures, floor, draws=NOISE_DRAWS):
    """The calibrator's truth (mm) at its defaults on the model's platform
    (:func:`model_platform` of ``floor``) with seed ``seed``'s plan of ``postures``: the median
    over ``draws`` draws of the sensors' default noise (a single run's truth scatters by tens of
    percent; NaN when every run fails)."""
    design = verdict.default_design({'seed': int(seed), 'posture_count': int(postures)})
    effects = model_platform(floor)
    runs = [verdict.one_run(design, effects, draws * int(seed) + draw) for draw in range(draws)]
    true = [run['true_mm'] for run in runs if 'true_mm' in run]
    return float(np.median(true)) if true else math.nan
