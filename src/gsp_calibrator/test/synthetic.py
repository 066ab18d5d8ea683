"""Test helper shared by test_offline.py and test_report.py: synthetic posture rows."""

import numpy as np

from gsp_calibrator.files.run_directory import Rows
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_kinematics.model.validation import sensor_measurements


def synthetic_samples(count=30, seed=1, sigmas=SensorNoise(), n_samples=1, first_stamp=0.0):
    """Noisy measurements of the true platform at ``count`` postures valid for the nominal:
    ``n_samples`` per row, stamps ``first_stamp``, ``first_stamp + 1``, ... (s)."""
    nominal, truth = default_geometry('nominal'), default_geometry('true')
    rng = np.random.default_rng(seed)
    poses = sample_valid_postures(nominal, count, rng)
    legs, readings = sensor_measurements(truth, poses)
    legs = legs + rng.normal(0.0, sigmas.leg_lengths, (count, 6))
    readings = readings + rng.normal(0.0, 1.0, (count, 4)) * sigmas.readings()
    return Rows(
        np.arange(1, count + 1),
        poses,
        legs,
        readings,
        np.full(count, n_samples),
        first_stamp + np.arange(count, dtype=float),
    )
