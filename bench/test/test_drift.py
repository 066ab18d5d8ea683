"""Drift between two simulated calibrations (gsp_kinematics.upkeep.drift on the benches' pure path)."""

import numpy as np
import pytest

from gsp_bench.upkeep import UpkeepDesign, changed_truth
from gsp_kinematics.upkeep import drift


@pytest.fixture(scope='module')
def design():
    return UpkeepDesign.default()


def test_two_calibrations_of_an_unchanged_platform_show_no_significant_change(design):
    first = design.calibrate(design.true, seed=11)
    second = design.calibrate(design.true, seed=12)
    data = drift.compare(first, second)
    assert not data['global_test']['changed'], data['global_test']
    assert data['significant'] == []
    # The effect of the (noise) change is of the order of the calibrations' own accuracy.
    assert data['effect']['all']['position_mm']['mean'] < 0.01


def test_a_20_um_leg_offset_change_is_named_with_its_size(design):
    first = design.calibrate(design.true, seed=11)
    second = design.calibrate(changed_truth(design.true, 'Loff3', 20e-6), seed=12)
    data = drift.compare(first, second)
    assert data['global_test']['changed']
    named = [entry['parameter'] for entry in data['significant']]
    assert named[0] == 'Loff3', data['significant']
    assert named == ['Loff3'], data['significant']
    change = data['significant'][0]
    assert change['unit'] == 'mm'
    assert abs(change['change_report'] - 0.020) < 3 * change['sigma_report'] + 1e-4
    # Its effect on the pose: of the order of the 20 um (a leg's change, amplified by the
    # platform's Jacobian in some postures).
    effect = data['effect']['significant']['position_mm']
    assert 0.005 < effect['mean'] < 0.04 and effect['max'] < 0.08


def test_a_check_compares_with_the_calibration_it_checked(design):
    # A calibration's subset as a second "calibration": the common parameters are compared.
    first = design.calibrate(design.true, seed=11)
    names = ('Loff1', 'Loff2')
    estimates, covariance = first.subset(names)
    subset = drift.Calibration(names, estimates + [0.0, 30e-6], covariance, first.geometry)
    data = drift.compare(first, subset)
    assert set(data['parameters']) == set(names)
    assert [entry['parameter'] for entry in data['significant']] == ['Loff2']
    assert np.isclose(data['parameters']['Loff2']['change_si'], 30e-6, atol=1e-12)
