"""Pure tests of the device backends (no ROS)."""

import dataclasses
import math

import numpy as np
import pytest

from gsp_device_driver.backends import (
    BackendError,
    DeviceBackend,
    DeviceSample,
    SimDeviceBackend,
    backend_class,
)
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import default_geometry, default_geometry_path
from gsp_kinematics.model.sensor_noise import SensorNoise

TRUE = default_geometry('true')
POSE = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])
STDS = np.array([1e-4, 1e-4, 2e-4, 3e-6])  # alpha, beta, phi (rad), d_m (m)


def device_noise(inclinometer, encoder, lvdt):
    """A true noise of the device sensors (rad, rad, m); no leg noise."""
    return SensorNoise(0.0, inclinometer, encoder, lvdt)


def make_sim(stds=(0.0, 0.0, 0.0), seed=0):
    return SimDeviceBackend(
        TRUE.device_length,
        TRUE.inclinometer_axes_angle,
        device_noise(*stds),
        rng=np.random.default_rng(seed),
        sensors=TRUE.sensors,
    )


def test_no_sample_before_the_first_true_pose():
    assert make_sim().read(1.0) is None


def test_noise_free_readings_are_the_core_device_model():
    sim = make_sim()
    sim.observe_true_pose(POSE)
    sample = sim.read(12.5)
    assert isinstance(sample, DeviceSample) and sample.stamp_s == 12.5
    np.testing.assert_allclose(
        sample.readings(),
        TRUE.sensors.device_readings(device_readings(TRUE, POSE[None])[0]),
        atol=1e-12,
    )
    # The true sensor errors: encoder zero phi0, LVDT gain error kDm (docs/sensor_errors.md).
    assert sample.phi == POSE[5] + TRUE.sensors.encoder_offset
    assert sample.d_m == pytest.approx(
        (np.linalg.norm(POSE[:3]) - TRUE.device_length) / (1.0 + TRUE.sensors.lvdt_gain_error),
        abs=1e-12,
    )


def test_noise_stds_are_honoured():
    sim = make_sim((STDS[0], STDS[2], STDS[3]), seed=3)
    sim.observe_true_pose(POSE)
    exact = TRUE.sensors.device_readings(device_readings(TRUE, POSE[None])[0])
    errors = np.stack([sim.read(0.0).readings() for _ in range(20000)]) - exact
    np.testing.assert_allclose(errors.std(axis=0), STDS, rtol=0.03)
    assert np.all(np.abs(errors.mean(axis=0)) < 4 * STDS / np.sqrt(len(errors)))
    # Independent channels: alpha and beta noise uncorrelated.
    assert abs(np.corrcoef(errors[:, 0], errors[:, 1])[0, 1]) < 0.05


def test_update_noise_changes_only_given_values_and_refuses_bad_ones():
    sim = make_sim((1e-5, 2e-5, 3e-6))
    sim.update_noise(dataclasses.replace(sim.noise, encoder=5e-5))
    np.testing.assert_array_equal(sim.noise.readings(), [1e-5, 1e-5, 5e-5, 3e-6])
    for bad in (-1e-6, math.nan, math.inf):
        with pytest.raises(BackendError, match='lvdt_noise_std'):
            sim.update_noise(dataclasses.replace(sim.noise, lvdt=bad))
    np.testing.assert_array_equal(sim.noise.readings(), [1e-5, 1e-5, 5e-5, 3e-6])
    with pytest.raises(BackendError):
        make_sim((-1.0, 0.0, 0.0))


def test_bad_true_pose_is_refused_and_the_last_good_one_kept():
    sim = make_sim()
    sim.observe_true_pose(POSE)
    for bad in ([0.0, math.nan, 1.0, 0.0, 0.0, 0.0], [0.0] * 6, [1.0, 2.0]):
        with pytest.raises(ValueError):
            sim.observe_true_pose(bad)
    np.testing.assert_allclose(
        sim.read(0.0).readings(), TRUE.sensors.device_readings(device_readings(TRUE, POSE[None])[0])
    )


def test_sim_from_config_reads_the_device_from_the_true_geometry_file():
    sim = backend_class('sim').from_config(
        true_geometry_file=default_geometry_path('true'),
        inclinometer_noise_std=1e-5,
        encoder_noise_std=2e-5,
        lvdt_noise_std=3e-6,
        rng=np.random.default_rng(0),
        unrelated_key='ignored',
    )
    assert sim._device.device_length == TRUE.device_length
    assert sim._device.inclinometer_axes_angle == TRUE.inclinometer_axes_angle
    np.testing.assert_array_equal(sim.noise.readings(), [1e-5, 1e-5, 2e-5, 3e-6])


def test_unknown_backend_names_the_valid_ones():
    with pytest.raises(BackendError, match="unknown device backend 'replay'.*sim"):
        backend_class('replay')


def test_a_backend_without_simulated_noise_refuses_noise_changes():
    class ConstantBackend(DeviceBackend):
        name = 'constant'

        @classmethod
        def from_config(cls, **_unused):
            return cls()

        def read_available(self, now_s):
            return [DeviceSample(now_s, 0.25, 0.25, 0.25, 0.25)]

    backend = ConstantBackend.from_config(true_geometry_file='unused')
    assert backend.read_available(3.0) == [DeviceSample(3.0, 0.25, 0.25, 0.25, 0.25)]
    with pytest.raises(BackendError, match='no simulated noise'):
        backend.update_noise(device_noise(0.0, 0.0, 1e-6))
    backend.close()  # nothing to release


def test_the_start_up_line_reports_noise_only_for_a_backend_that_simulates_it(tmp_path):
    from gsp_device_driver.device_driver_node import startup_line
    from gsp_device_driver.serial_backend import SerialDeviceBackend

    values = {'backend': 'serial', 'publish_rate': 200.0}
    serial = SerialDeviceBackend(str(tmp_path / 'absent'), angle_unit='urad', length_unit='um')
    line = startup_line(values, 0, serial)
    assert 'noise' not in line and 'urad/um' in line and str(tmp_path / 'absent') in line
    sim = SimDeviceBackend(0.5, 1.0, device_noise(1e-5, 0.0, 0.0))
    assert 'noise std inclinometer 1e-05 rad' in startup_line(dict(values, backend='sim'), 0, sim)


def test_default_dynamics_reproduce_the_white_instant_readings_of_a_seed():
    # Before sensor dynamics the sim read exact + N(0, 1) x std, one draw of 4 per read.
    sim = make_sim((STDS[0], STDS[2], STDS[3]), seed=11)
    twin = np.random.default_rng(11)
    exact = TRUE.sensors.device_readings(device_readings(TRUE, POSE[None])[0])
    sim.observe_true_pose(POSE)
    for k in range(20):
        np.testing.assert_array_equal(
            sim.read(k * 0.005).readings(), exact + twin.normal(0.0, 1.0, size=4) * STDS
        )


def test_sim_dynamics_come_from_the_node_parameters_per_sensor():
    sim = SimDeviceBackend.from_config(
        default_geometry_path('true'),
        rng=np.random.default_rng(0),
        inclinometer_response_time=0.3,
        lvdt_response_time=0.01,
        inclinometer_noise_std=0.0,
        encoder_noise_std=0.0,
        lvdt_noise_std=0.0,
    )
    sim.observe_true_pose(POSE)
    before = sim.read(0.0).readings()
    moved = POSE + np.array([0.01, 0.01, 0.01, 0.0, 0.0, 0.05])
    sim.observe_true_pose(moved)
    after = TRUE.sensors.device_readings(device_readings(TRUE, moved[None])[0])
    reading = sim.read(0.3).readings()
    # Inclinometer (tau 0.3 s) at 1 - 1/e of its step; encoder instant; LVDT (tau 0.01 s) there.
    np.testing.assert_allclose(
        reading[:2], before[:2] + (1 - math.exp(-1)) * (after[:2] - before[:2]), atol=1e-12
    )  # rad
    assert reading[2] == after[2]
    assert reading[3] == pytest.approx(after[3], abs=1e-12)  # m
    assert 'inclinometer response 0.3 s' in sim.describe()


def test_negative_response_time_is_a_backend_error():
    with pytest.raises(BackendError, match='response time must be finite and >= 0 s'):
        SimDeviceBackend(1.0, 1.5, response_times=(-1.0, 0.0, 0.0))


def test_the_physics_backend_publishes_each_reading_once_with_its_stamp_and_sensor_errors():
    from gsp_device_driver.backends import PhysicsDeviceBackend

    backend = PhysicsDeviceBackend.from_config(
        true_geometry_file=default_geometry_path('true'), rng=np.random.default_rng(0)
    )
    assert backend_class('physics') is PhysicsDeviceBackend
    assert backend.read_available(1.0) == []
    truth = device_readings(TRUE, np.stack([POSE, POSE + 0.001]))
    backend.observe_device_truth(0.5, truth[0])
    backend.observe_device_truth(0.51, truth[1])
    samples = backend.read_available(1.0)
    assert [sample.stamp_s for sample in samples] == [0.5, 0.51]
    for sample, ideal in zip(samples, truth, strict=True):
        # rad, rad, rad, m: the true device's offsets and LVDT gain error, no noise configured
        np.testing.assert_allclose(
            sample.readings(), TRUE.sensors.device_readings(ideal), rtol=0.0, atol=1e-12
        )
    assert backend.read_available(1.1) == []
    with pytest.raises(ValueError, match='4 finite values'):
        backend.observe_device_truth(0.6, [0.0, math.nan, 0.0, 0.0])
