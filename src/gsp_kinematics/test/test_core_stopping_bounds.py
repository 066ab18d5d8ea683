"""The figures a run that stops when it is good enough judges (``upkeep.stopping.accuracy_bounds``)
against the verdict's, on held-out errors set by hand (docs/upkeep.md)."""

import math

import numpy as np
import pytest
from cross_validations import validation_of
from scipy import stats

from gsp_kinematics.estimation.verdict import acceptance
from gsp_kinematics.upkeep import stopping

Z95 = float(stats.norm.ppf(0.95))


def _summary(errors_mm, workspace=None):
    """A cross-validation summary of per-posture position errors ``errors_mm`` (mm, along x), no
    noise, no phi error; ``workspace`` (M,) bool: the workspace postures' rows."""
    count = len(errors_mm)
    position = np.zeros((count, 3))
    position[:, 0] = 1e-3 * np.asarray(errors_mm, dtype=float)
    validation = validation_of(position, 4)
    return validation.summary(workspace)


def _mean_bound(errors_mm):
    errors = np.asarray(errors_mm, dtype=float)
    return errors.mean(), errors.mean() + Z95 * errors.std(ddof=1) / math.sqrt(errors.size)


SELECTED_MM = [4.0, 5.0, 6.0, 5.5, 4.5]  # the workspace's extremes: larger held-out errors
WORKSPACE_MM = [0.5, 1.0, 1.5, 0.8, 1.2]  # drawn at random over the workspace


def test_with_workspace_postures_a_run_judges_what_the_verdict_judges():
    """The judged position is the larger of the workspace and the selected postures' means (the
    verdict's ``judged_accuracy``), its bound over those postures' own spread: a run never stops
    on the workspace figure alone, which the verdict would then reject."""
    workspace = np.array([False] * 5 + [True] * 5)
    summary = _summary(SELECTED_MM + WORKSPACE_MM, workspace)
    bounds = stopping.accuracy_bounds(summary, 0.95, 0.0)
    judged_mm, _ = acceptance.judged_accuracy(summary)
    mean, bound = _mean_bound(SELECTED_MM)
    assert bounds.position_mm == pytest.approx(judged_mm) == pytest.approx(mean)
    assert bounds.position_bound_mm == pytest.approx(bound)
    # met by the workspace figure (1 mm) and its bound, not by what the verdict judges (5 mm)
    assert not bounds.meets(stopping.StoppingRule(required_position_mm=4.0))


def test_the_workspace_bound_is_over_the_workspace_postures():
    """When the workspace postures' figure is the larger, its bound is their mean plus z
    standard errors over them, not over every posture."""
    workspace = np.array([False] * 5 + [True] * 5)
    summary = _summary(WORKSPACE_MM + SELECTED_MM, workspace)  # now the workspace is worse
    bounds = stopping.accuracy_bounds(summary, 0.95, 0.0)
    mean, bound = _mean_bound(SELECTED_MM)
    assert bounds.position_mm == pytest.approx(mean)
    assert bounds.position_bound_mm == pytest.approx(bound)


def test_without_workspace_postures_the_bound_is_over_every_posture():
    summary = _summary(SELECTED_MM + WORKSPACE_MM)
    bounds = stopping.accuracy_bounds(summary, 0.95, None)
    mean, bound = _mean_bound(SELECTED_MM + WORKSPACE_MM)
    assert bounds.position_mm == pytest.approx(mean)
    assert bounds.position_bound_mm == pytest.approx(bound)
    assert bounds.predicted_mm == math.inf


def test_one_workspace_posture_is_not_enough_to_stop():
    workspace = np.array([False] * 5 + [True])
    summary = _summary(SELECTED_MM + [0.1], workspace)
    assert stopping.accuracy_bounds(summary, 0.95, 0.0) == stopping.UNKNOWN
