"""The physics section's floor (:mod:`gsp_bench.physics_floor`), on the MuJoCo platform itself:
the suite's compensation fitted to where the physics platform rests explains its sag, and the
ideal platform's reference is the calibrator's own truth at this noise."""

import math

import numpy as np

from gsp_bench import physics, physics_floor
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_platform_sim.physics_model import PhysicalParameters


def test_the_fitted_compensation_explains_the_physics_platforms_sag():
    poses = sample_valid_postures(default_geometry('nominal'), 4, np.random.default_rng(12345))
    reached = physics.poses_at_rest(physics.preset_simulator(default_geometry('true')), poses)
    floor = physics_floor.compensated_floor(poses, reached, physics.true_position_mm)
    # Rigidly the platform sags by tens of um under its 40 kg and its legs' weight; the suite's
    # compliance model, fitted, leaves about 1 % of it (the servos and the legs' two bodies).
    assert 0.01 < floor['uncompensated_mm'] < 0.1, floor
    assert floor['floor_mm'] < 0.05 * floor['uncompensated_mm'], floor
    assert floor['fit_rms_um'] < 1.0, floor
    # The legs' compliance is the springs' (30 N/um) plus the servos' (within 30 %).
    leg_compliance = 1.0 / PhysicalParameters().leg_stiffness
    np.testing.assert_allclose(floor['compliance_m_per_n'], leg_compliance, rtol=0.3)


def test_the_ideal_reference_is_the_calibrators_truth_at_the_sensors_noise():
    floor = {'compliance_m_per_n': [3.7e-8] * 6, 'leg_mass_kg': 12.0, 'centre_of_mass_z_m': 0.0}
    ideal = physics_floor.ideal_mm(0, 60, floor, draws=1)
    # The fit's error at the default noise over 60 postures: a few um, never zero.
    assert math.isfinite(ideal) and 0.0005 < ideal < 0.02, ideal
