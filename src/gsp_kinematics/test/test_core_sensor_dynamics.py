"""Sensor dynamics of the simulated device: first-order response, AR(1) noise, white defaults."""

import math

import numpy as np
import pytest

from gsp_kinematics.model.sensor_dynamics import SensorDynamics, SensorDynamicsError

DT = 0.005  # s, the device's 200 Hz


def test_step_response_reaches_one_minus_1_over_e_at_tau():
    tau = 0.3  # s, a slow inclinometer
    dynamics = SensorDynamics([tau, 0.0], 0.0, 2)
    before, after = np.array([0.01, 0.01]), np.array([0.02, 0.02])  # rad
    dynamics.step(0.0, before, np.zeros(2), np.random.default_rng(0))
    steps = round(tau / DT)
    for k in range(1, steps + 1):
        reading = dynamics.step(k * DT, after, np.zeros(2), np.random.default_rng(0))
    # Channel 0 lags: 1 - 1/e of the step at t = tau; channel 1 (tau 0) is at once.
    expected = before[0] + (1.0 - math.exp(-1.0)) * (after[0] - before[0])
    assert reading[0] == pytest.approx(expected, abs=1e-12)  # rad
    assert reading[1] == after[1]


def test_the_lag_of_an_angle_on_the_circle_takes_the_short_way():
    dynamics = SensorDynamics(0.1, 0.0, 1, circular=[True])
    rng = np.random.default_rng(0)
    dynamics.step(0.0, [math.pi - 0.01], [0.0], rng)
    reading = dynamics.step(0.1, [-math.pi + 0.01], [0.0], rng)[0]
    # 0.02 rad the short way, of which exp(-1) is left: not a sweep through 0.
    assert abs(reading) > math.pi - 0.02


def test_coloured_noise_has_the_configured_std_and_exponential_autocorrelation():
    chains, steps, sigma, tc = 4000, 80, 2e-5, 0.05  # independent devices, s
    dynamics = SensorDynamics(0.0, tc, 1)
    rng = np.random.default_rng(7)
    noise = np.stack(
        [dynamics.step(k * DT, np.zeros((chains, 1)), [sigma], rng)[:, 0] for k in range(steps)]
    )  # (steps, chains)
    # Across independent chains each figure is an iid estimate: std's relative standard
    # error 1/sqrt(2 chains), a correlation's (1 - rho^2)/sqrt(chains). Tolerance: 5 of them.
    for t in (0, steps - 1):  # stationary from the first step on
        assert noise[t].std() == pytest.approx(sigma, rel=5 / math.sqrt(2 * chains))
    for lag in (1, 5, 20):
        expected = math.exp(-lag * DT / tc)
        measured = np.corrcoef(noise[30], noise[30 + lag])[0, 1]
        assert measured == pytest.approx(expected, abs=5 * (1 - expected**2) / math.sqrt(chains))


def test_defaults_are_the_white_instant_readings_bit_for_bit():
    true = np.array([0.01, -0.02, 0.3, 0.004])
    stds = np.array([1.7e-5, 1.7e-5, 1.7e-5, 1e-6])
    dynamics, rng, twin = SensorDynamics(0.0, 0.0, 4), np.random.default_rng(3), None
    twin = np.random.default_rng(3)
    for k in range(50):
        values = true + 1e-3 * k  # the pose moves between steps
        reading = dynamics.step(k * DT, values, stds, rng)
        np.testing.assert_array_equal(reading, values + twin.normal(0.0, 1.0, size=4) * stds)


@pytest.mark.parametrize('response, correlation', [(-0.1, 0.0), (0.0, math.nan), (math.inf, 0)])
def test_bad_time_constants_are_refused_by_name(response, correlation):
    with pytest.raises(SensorDynamicsError, match='time must be finite and >= 0 s'):
        SensorDynamics(response, correlation, 2)
