"""Noise from the data: redundancy numbers, the estimate of each channel's row noise (white and
correlated samples), the lack-of-fit F test and the studentised outliers of the verdict."""

import math

import numpy as np
import pytest

from gsp_kinematics import channels
from gsp_kinematics.estimation import goodness, noise_from_data
from gsp_kinematics.estimation._solver.redundancy import redundancy_flat, redundancy_with_poses
from gsp_kinematics.estimation.identification import identify
from gsp_kinematics.estimation.noise_estimate import ar1_std_of_mean
from gsp_kinematics.model.geometry import SensorErrors
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, NOISE_FIELDS, SensorNoise
from gsp_kinematics.model.validation import sensor_measurements

SAMPLES = 10
SENSORS = SensorErrors(
    leg_gain_errors=[3e-4, -2e-4, 4e-4, -3e-4, 1e-4, 2e-4],
    inclinometer_offsets=[math.radians(0.01), math.radians(-0.01)],
    encoder_offset=math.radians(0.02),
)
#: The device's noise: 3x the calibrator's default on legs and encoder, 0.5x on the others.
TRUTH = SensorNoise(
    leg_lengths=3 * DEFAULT_SENSOR_NOISE.leg_lengths,
    inclinometer=0.5 * DEFAULT_SENSOR_NOISE.inclinometer,
    encoder=3 * DEFAULT_SENSOR_NOISE.encoder,
    lvdt=0.5 * DEFAULT_SENSOR_NOISE.lvdt,
)


@pytest.fixture(scope='module')
def truth(exact):
    return exact.replace(sensors=SENSORS)


@pytest.fixture(scope='module')
def exact_readings(truth, moderate_postures):
    legs, readings = sensor_measurements(truth, moderate_postures)
    return np.concatenate([legs, readings], axis=1)


def ar1(rng, shape, rho):
    """Stationary AR(1) samples of unit variance along axis 1 (the samples of a window)."""
    white = rng.normal(size=shape)
    out = np.empty(shape)
    out[:, 0] = white[:, 0]
    for i in range(1, shape[1]):
        out[:, i] = rho * out[:, i - 1] + math.sqrt(1 - rho**2) * white[:, i]
    return out


def arrow_jacobian(jac_pose, jac_u):
    """The dense Jacobian of the implicit formulation's shape: a 6-column pose block a posture
    on the diagonal, the parameters' columns shared."""
    count, rows, parameters = jac_u.shape
    dense = np.zeros((count * rows, 6 * count + parameters))
    for m in range(count):
        dense[m * rows : (m + 1) * rows, 6 * m : 6 * m + 6] = jac_pose[m]
        dense[m * rows : (m + 1) * rows, 6 * count :] = jac_u[m]
    return dense


def draw(exact_readings, seed, correlation=None, samples=SAMPLES):
    """The windows (M, samples, 10) of a simulated run with :data:`TRUTH` noise;
    ``correlation``: ``{column: rho}`` of AR(1) samples."""
    rng = np.random.default_rng(seed)
    count = len(exact_readings)
    noise = rng.normal(size=(count, samples, 10))
    for column, rho in (correlation or {}).items():
        noise[:, :, column] = ar1(rng, (count, samples), rho)
    return exact_readings[:, None, :] + noise * TRUTH.channel_std()


def run(exact_readings, seed, correlation=None, samples=SAMPLES):
    """``(legs, readings, lag sums (M, 4, L))`` of a simulated run (:func:`draw`)."""
    drawn = draw(exact_readings, seed, correlation, samples)
    mean = drawn.mean(axis=1)
    return mean[:, :6], mean[:, 6:], noise_from_data.posture_lag_sums(drawn)


def estimated(nominal, moderate_postures, legs, readings, lag_sums, samples=SAMPLES):
    within = noise_from_data.within_row_noise(lag_sums, np.full(len(legs), samples))
    return noise_from_data.identify_with_estimated_noise(
        nominal,
        legs,
        readings,
        DEFAULT_SENSOR_NOISE.averaged([SAMPLES]),
        within,
        free='extended',
        pose_guesses=moderate_postures,
    )


def test_redundancy_numbers_are_the_hat_matrix_diagonal(rng):
    count, rows, parameters = 7, 10, 5
    jac_pose = rng.normal(size=(count, rows, 6))
    jac_u = rng.normal(size=(count, rows, parameters))
    dense = arrow_jacobian(jac_pose, jac_u)
    expected = 1.0 - np.diag(dense @ np.linalg.inv(dense.T @ dense) @ dense.T)
    inverse = np.linalg.inv(np.einsum('mki,mkj->mij', jac_pose, jac_pose))
    w = np.einsum('mki,mkj->mij', jac_pose, jac_u)
    reduced = np.einsum('mki,mkj->ij', jac_u, jac_u) - np.einsum('mji,mjk,mkl->il', w, inverse, w)
    found = redundancy_with_poses(jac_pose, jac_u, reduced)
    np.testing.assert_allclose(found.ravel(), expected, atol=1e-12)
    assert found.sum() == pytest.approx(count * rows - dense.shape[1], abs=1e-9)
    flat = redundancy_flat(jac_u)
    assert flat.sum() == pytest.approx(count * rows - parameters, abs=1e-9)


def test_white_noise_3x_and_half_is_estimated_per_channel(
    nominal_sets, moderate_postures, exact_readings
):
    legs, readings, lag_sums = run(exact_readings, seed=1)
    result, estimates, rows = estimated(
        nominal_sets[1], moderate_postures, legs, readings, lag_sums
    )
    assert result.converged
    truth_rows = TRUTH.averaged([SAMPLES])
    for channel in NOISE_FIELDS:
        assert estimates[channel].source == 'pooled'
        assert getattr(rows, channel) == pytest.approx(getattr(truth_rows, channel), rel=0.1)
    fit = result.goodness_of_fit
    assert fit.test == 'lack_of_fit' and fit.accepted, fit
    assert result.outliers == []
    # The same data with the configured (default) sigmas: rejected, blamed on the sigmas.
    configured = identify(
        nominal_sets[1],
        legs,
        readings,
        DEFAULT_SENSOR_NOISE.averaged([SAMPLES]),
        free='extended',
        pose_guesses=moderate_postures,
    )
    assert not configured.goodness_of_fit.accepted
    assert configured.outliers == []  # wrong sigmas scale a whole channel: no posture named
    record = noise_from_data.noise_record(
        noise_from_data.estimate_row_noise(
            configured,
            DEFAULT_SENSOR_NOISE.averaged([SAMPLES]),
            noise_from_data.within_row_noise(lag_sums, np.full(len(legs), SAMPLES)),
        ),
        DEFAULT_SENSOR_NOISE,
        np.full(len(legs), SAMPLES),
    )
    assert record['leg_lengths']['estimated'] == pytest.approx(TRUTH.leg_lengths, rel=0.1)
    text = goodness.fit_diagnosis(configured.goodness_of_fit, configured.outliers, record, True)
    assert 'wrong sigmas' in text and 'outlier' not in text
    assert 'leg_lengths' in text and 'encoder' in text


def test_correlated_samples_too_short_a_window_fall_back_to_between_and_are_accepted(
    nominal_sets, moderate_postures, exact_readings
):
    # The encoder's samples are strongly correlated (rho 0.95 a sample): the window's scatter
    # misses most of the noise of its mean, and 10 samples cannot show it (n_eff ~ 1): the
    # within estimate is a lower bound. The residuals between postures give the row noise, and
    # the lack-of-fit test leaves the encoder out, so the right model is accepted.
    rho = 0.95
    legs, readings, lag_sums = run(exact_readings, seed=2, correlation={8: rho})
    result, estimates, rows = estimated(
        nominal_sets[1], moderate_postures, legs, readings, lag_sums
    )
    true_row = ar1_std_of_mean(TRUTH.encoder, rho, SAMPLES)
    encoder = estimates['encoder']
    assert encoder.within_lower_bound and encoder.source == 'between'
    assert encoder.within < 0.8 * true_row  # the window alone: too optimistic
    # The between estimate's own spread is about 1 / sqrt(2 r) (r ~ 55): 30 % is > 3 sd.
    assert rows.encoder == pytest.approx(true_row, rel=0.3)
    assert estimates['leg_lengths'].source == 'pooled'
    assert not estimates['leg_lengths'].within_lower_bound
    fit = result.goodness_of_fit
    assert fit.test == 'lack_of_fit' and fit.accepted, fit


def test_correlated_samples_in_long_windows_give_the_row_noise_within(
    nominal_sets, moderate_postures, exact_readings
):
    # The inclinometer's samples are AR(1) with rho 0.6 over 60-sample windows (n_eff ~ 15):
    # the effective sample count gives the std of the row within postures, and the F test
    # against it accepts the right model.
    rho, samples = 0.6, 60
    legs, readings, lag_sums = run(exact_readings, 4, {6: rho, 7: rho}, samples)
    within = noise_from_data.within_row_noise(lag_sums, np.full(len(legs), samples))
    inclinometer = within['inclinometer']
    true_row = ar1_std_of_mean(TRUTH.inclinometer, rho, samples)
    assert not inclinometer.lower_bound
    assert inclinometer.row == pytest.approx(true_row, rel=0.10)
    # The white formula s / sqrt(n) would be 2x too optimistic.
    assert TRUTH.inclinometer / math.sqrt(samples) < 0.6 * true_row
    windows = 2 * len(legs)
    assert inclinometer.dof == pytest.approx(windows * (inclinometer.n_eff - 1))
    assert inclinometer.n_eff == pytest.approx((1 - rho) / (1 + rho) * samples, rel=0.3)
    result, estimates, rows = estimated(
        nominal_sets[1], moderate_postures, legs, readings, lag_sums, samples
    )
    assert estimates['inclinometer'].source == 'pooled'
    assert rows.inclinometer == pytest.approx(true_row, rel=0.10)
    assert result.goodness_of_fit.test == 'lack_of_fit' and result.goodness_of_fit.accepted


def test_white_samples_give_the_pooled_scatter_over_sqrt_n(exact_readings):
    drawn = draw(exact_readings, seed=6)
    within = noise_from_data.within_row_noise(
        noise_from_data.posture_lag_sums(drawn), np.full(len(drawn), SAMPLES)
    )
    std = drawn.std(axis=1, ddof=1)  # the pooled scatter, built independently
    for channel, columns in goodness.NOISE_CHANNELS.items():
        sigma = math.sqrt(np.mean(std[:, columns] ** 2))
        dof = std[:, columns].size * (SAMPLES - 1)
        assert within[channel].row == pytest.approx(sigma / math.sqrt(SAMPLES), rel=1e-12)
        assert within[channel].dof == pytest.approx(dof, rel=1e-12)
        assert within[channel].n_eff == pytest.approx(SAMPLES, rel=1e-12)
        assert not within[channel].lower_bound


def test_lack_of_fit_holds_its_level_and_rejects_an_unmodelled_error(rng):
    """The F test against the within-posture pure error: about 1 % rejections under the model
    (2000 linear fits of the implicit formulation's shape, vectorised), every one with an error
    the model lacks."""
    count, rows, parameters, seeds = 30, 10, 20, 2000
    jac_pose = rng.normal(size=(count, rows, 6))
    jac_u = rng.normal(size=(count, rows, parameters))
    dense = arrow_jacobian(jac_pose, jac_u)
    projector = np.eye(count * rows) - dense @ np.linalg.pinv(dense)
    redundancy = np.diag(projector).reshape(count, rows)
    columns = list(channels.CHANNEL_NAMES)
    within_dof = {'leg_lengths': 6 * count * 9, 'inclinometer': 2 * count * 9}
    within_dof.update(encoder=count * 9, lvdt=count * 9)
    # A fixed systematic error of one noise sigma per residual that the model cannot follow.
    unmodelled = np.random.default_rng(5).normal(size=count * rows)

    def p_values(bias):
        noise = rng.normal(size=(seeds, count * rows)) + bias
        residuals = (noise @ projector.T).reshape(seeds, count, rows)
        found = []
        for seed in range(seeds):
            components = goodness.variance_components(residuals[seed], redundancy, columns)
            within = {
                channel: noise_from_data.WithinNoise(math.sqrt(rng.chisquare(dof) / dof), dof)
                for channel, dof in within_dof.items()
            }
            stand_in = _Fit(components)
            found.append(
                noise_from_data.fit_test(stand_in, SensorNoise(1.0, 1.0, 1.0, 1.0), within)
            )
        return np.array([fit.p_value for fit in found])

    rate = np.mean(p_values(0.0) < goodness.DEFAULT_SIGNIFICANCE)
    assert 0.002 <= rate <= 0.022  # 1 % +- 3.5 binomial sd over 2000
    assert np.mean(p_values(unmodelled) < goodness.DEFAULT_SIGNIFICANCE) > 0.99


class _Fit:
    """What :func:`noise_from_data.fit_test` reads of a fit: its variance components."""

    goodness_of_fit = None

    def __init__(self, components):
        self._components = components

    def variance_components(self):
        return self._components


def test_a_real_outlier_is_named_and_noise_is_not(nominal_sets, moderate_postures, exact_readings):
    legs, readings, lag_sums = run(exact_readings, seed=3)
    legs[17, 2] += 20 * TRUTH.leg_lengths / math.sqrt(SAMPLES)  # 20 sigma of the row on leg 3
    result, _, _ = estimated(nominal_sets[1], moderate_postures, legs, readings, lag_sums)
    assert [entry['posture'] for entry in result.outliers] == [17]
    assert not result.goodness_of_fit.accepted
    assert 'outlier postures 17' in goodness.fit_diagnosis(result.goodness_of_fit, result.outliers)


def test_bonferroni_threshold():
    assert goodness.bonferroni_threshold(1) == pytest.approx(2.5758, abs=1e-4)
    assert goodness.bonferroni_threshold(600) == pytest.approx(4.3054, abs=1e-3)


def test_unknown_noise_source_is_named():
    with pytest.raises(noise_from_data.NoiseSourceError, match="'guessed'"):
        noise_from_data.validate_noise_source('guessed')


def test_a_channel_without_scatter_has_no_within_posture_estimate(exact_readings):
    drawn = draw(exact_readings[:20], seed=7)
    drawn[:, :, 8] = 1.0  # an encoder that reads one count all window long
    within = noise_from_data.within_row_noise(
        noise_from_data.posture_lag_sums(drawn), np.full(20, SAMPLES)
    )
    assert set(within) == {'leg_lengths', 'inclinometer', 'lvdt'}


def test_a_first_fit_given_is_the_first_round_and_left_as_it_was(
    nominal_sets, moderate_postures, exact_readings, monkeypatch
):
    """The model choice hands its fit of the chosen model to the estimated-noise rounds: it is
    not fitted again (one identification fewer), the result is that of fitting it again, and
    the given fit keeps its own goodness of fit."""
    legs, readings, lag_sums = run(exact_readings, seed=2)
    within = noise_from_data.within_row_noise(lag_sums, np.full(len(legs), SAMPLES))
    start = DEFAULT_SENSOR_NOISE.averaged([SAMPLES])
    weights = noise_from_data.within_sigmas(within, start)
    first = identify(
        nominal_sets[1], legs, readings, weights, free='extended', pose_guesses=moderate_postures
    )
    own_fit = first.goodness_of_fit
    options = {'free': 'extended', 'pose_guesses': moderate_postures}
    calls = []

    def counted(*args, **kwargs):
        calls.append(1)
        return identify(*args, **kwargs)

    monkeypatch.setattr(noise_from_data, 'identify', counted)
    reused, _, rows = noise_from_data.identify_with_estimated_noise(
        nominal_sets[1], legs, readings, start, within, first, **options
    )
    reused_calls = len(calls)
    fitted, _, fitted_rows = noise_from_data.identify_with_estimated_noise(
        nominal_sets[1], legs, readings, start, within, **options
    )
    assert reused_calls == len(calls) - reused_calls - 1
    deviations = fitted.standard_deviations[fitted.free]
    difference = reused.parameters[fitted.free] - fitted.parameters[fitted.free]
    assert np.all(np.abs(difference) <= 1e-3 * deviations), difference / deviations
    for channel in NOISE_FIELDS:
        assert getattr(rows, channel) == pytest.approx(getattr(fitted_rows, channel), rel=1e-6)
    assert first.goodness_of_fit is own_fit
