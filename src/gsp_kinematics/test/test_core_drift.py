"""gsp_kinematics.upkeep.drift on synthetic changes with a known covariance (no simulation)."""

import numpy as np
import pytest

from gsp_kinematics.model.geometry import ALL_PARAMETER_NAMES
from gsp_kinematics.upkeep import drift

NAMES = ALL_PARAMETER_NAMES[36:42] + ('D0', 'gamma')  # Loff1..6, D0, gamma


def correlated_covariance(rng, size, sigma=3e-6):
    """A covariance with strong correlations (as a leg offset has with its joints)."""
    basis = rng.normal(size=(size, 4 * size))
    basis[0] += 3.0 * basis[2]  # parameters 0 and 2 correlate at about 0.95
    return sigma**2 * (basis @ basis.T) / (4 * size)


def test_without_a_change_the_test_rejects_at_about_its_level():
    rng = np.random.default_rng(5)
    covariance = correlated_covariance(rng, len(NAMES))
    zero = drift.Calibration(NAMES, np.zeros(len(NAMES)), covariance / 2)
    draws, changed, named = 1000, 0, 0
    factor = np.linalg.cholesky(covariance)  # the change: both calibrations' noise
    for _ in range(draws):
        second = drift.Calibration(NAMES, factor @ rng.normal(size=len(NAMES)), covariance / 2)
        data = drift.compare(zero, second)
        changed += data['global_test']['changed']
        named += bool(data['significant'])
    # Family-wise 1 %: binomial(1000, 0.01) lies in [2, 21] with probability > 0.999.
    assert 2 <= changed <= 21
    assert named <= changed


def test_a_change_of_one_correlated_parameter_is_named_and_estimated():
    rng = np.random.default_rng(6)
    covariance = correlated_covariance(rng, len(NAMES))
    first = drift.Calibration(NAMES, np.zeros(len(NAMES)), covariance / 2)
    weight = np.linalg.inv(covariance)
    conditional = 1.0 / np.sqrt(weight[2, 2])
    shift = np.zeros(len(NAMES))
    shift[2] = 12 * conditional  # Loff3, 12 conditional sigmas
    factor = np.linalg.cholesky(covariance)
    second = drift.Calibration(NAMES, shift + factor @ rng.normal(size=len(NAMES)), covariance / 2)
    data = drift.compare(first, second)
    assert [entry['parameter'] for entry in data['significant']] == ['Loff3']
    found = data['significant'][0]
    assert abs(found['change_report'] / 1e3 - shift[2]) < 4 * found['sigma_report'] / 1e3
    assert data['unexplained']['p_value'] >= drift.DEFAULT_LEVEL


def test_a_calibration_with_mismatched_sizes_is_refused_with_its_shapes():
    with pytest.raises(ValueError, match='2 names need 2 estimates'):
        drift.Calibration(('Loff1', 'Loff2'), np.zeros(3), np.eye(2))
    with pytest.raises(ValueError, match='unknown parameter names'):
        drift.Calibration(('Loff9',), np.zeros(1), np.eye(1))


def test_report_units():
    assert drift.report_scale('Loff1') == (1e3, 'mm')
    assert drift.report_scale('gamma')[1] == 'deg' and drift.report_scale('alpha0')[1] == 'deg'
    assert drift.report_scale('kq1') == (1e6, 'ppm')
