"""The ``sensor_errors`` bench's model figure: no bias from the sensor errors, a Cramer-Rao
prediction that matches the measured errors, and where the excess comes from."""

import numpy as np
import pytest

from gsp_bench.nominal_sets import default_true_and_nominal
from gsp_bench.sensor_errors import (
    POSTURES,
    SAMPLES,
    SIGMAS,
    estimate_noise,
    exchange_for_pose_error,
    model_section,
    position_weight,
)
from gsp_kinematics.estimation.identifiability import posture_information
from gsp_kinematics.model.kinematics import Workspace, sample_valid_postures
from gsp_kinematics.planning.selection import select_postures


@pytest.fixture(scope='module')
def design():
    true, nominal = default_true_and_nominal()
    pool = sample_valid_postures(nominal, 300, np.random.default_rng(0), Workspace())
    chosen, _ = select_postures(
        nominal, pool, POSTURES, SIGMAS.averaged([SAMPLES]), free='extended'
    )
    validation = sample_valid_postures(nominal, 30, np.random.default_rng(1), Workspace())
    return true, nominal, pool, chosen, validation


def test_model_figure_is_variance_not_bias(design):
    true, nominal, pool, chosen, validation = design
    model = model_section(true, nominal, pool, chosen, validation, quick=True)
    # The sensor errors are fully modelled: the extended fit on them gives the same validation
    # error as on the same noise with ideal sensors, to a small fraction of the error itself.
    assert model['sensor_error_bias_mm_max'] < 0.05 * model['extended_validation_mm']
    # The excess over the 44 is the variance of the freed parameters: Cramer-Rao predicts it,
    # and predicts the measured mean errors (20 seeds scatter the means by about 7%).
    ratios = model['measured_over_predicted']
    assert set(ratios) == {'extended', 'ideal_sensors_paper'}
    for ratio in ratios.values():
        assert 0.75 < ratio < 1.25
    costs = model['predicted_over_paper']
    assert 1.0 < costs['kq1_to_kq6'] < costs['extended']
    assert 1.0 < costs['alpha0'] < costs['extended']
    assert costs['extended_on_postures_selected_for_validation'] < costs['extended']
    # The measured excess over the ideal 44 (ratio of medians over the seeds, its bootstrap 90 %
    # interval) is real, and its interval covers what Cramer-Rao predicts from the covariances
    # alone, without a noise draw (docs/sensor_errors.md).
    low, high = model['extended_over_ideal_bootstrap_p5_p95']
    assert 1.0 < low <= model['predicted_extended_over_ideal'] <= high
    assert model['paper_p_value_max'] < 0.01 and model['paper_over_extended'] > 5.0


def test_exchange_for_pose_error_leaves_no_improving_swap(nominal_sets):
    nominal = nominal_sets[1]
    pool = sample_valid_postures(nominal, 150, np.random.default_rng(3))
    indices, _ = select_postures(nominal, pool, 45)
    targets = sample_valid_postures(nominal, 40, np.random.default_rng(6))
    information = posture_information(nominal, pool)
    weight = position_weight(nominal, targets)

    def objective(chosen):
        return np.trace(weight @ np.linalg.inv(information[chosen].sum(axis=0)))

    refined = exchange_for_pose_error(nominal, pool, indices, targets, passes=20)
    assert len(set(refined.tolist())) == len(indices) and objective(refined) < objective(indices)
    # Converged: no single swap lowers the objective, scored directly (no Woodbury identity).
    outside = np.setdiff1d(np.arange(len(pool)), refined)
    best = objective(refined)
    for position in range(0, len(refined), 5):
        for candidate in outside[::4]:
            swapped = refined.copy()
            swapped[position] = candidate
            assert objective(swapped) >= best * (1.0 - 1e-9)


def test_noise_estimate_pools_within_posture_scatter():
    rng = np.random.default_rng(1)
    sigma = np.array([1e-6] * 6 + [2e-5, 2e-5, 3e-5, 4e-6])
    samples = rng.normal(0.0, 1.0, (60, 10, 10)) * sigma  # 60 postures, 10 samples each
    std = samples.std(axis=1, ddof=1)
    configured = {'leg_lengths': 1e-6, 'inclinometer': 2e-5, 'encoder': 3e-5, 'lvdt': 1e-6}
    estimates = estimate_noise(std, np.full(60, 10), configured)
    assert estimates['leg_lengths']['estimated'] == pytest.approx(1e-6, rel=0.1)
    assert not estimates['inclinometer']['warning']
    assert estimates['lvdt']['ratio'] == pytest.approx(4.0, rel=0.2)
    assert estimates['lvdt']['warning']
