"""The verdict describes what the controller runs (issue 33): the rigid geometry's held-out
accuracy (``gsp_kinematics.estimation.verdict.rigid_held_out``) against the realistic platform's physics,
a truth the model does not contain, and a rigid controller's acceptance judged on it
(``run.rigid.Verdicts`` picked by ``result_delivery`` once it knows the controller)."""

import asyncio
import statistics
import types

import numpy as np
import pytest

from gsp_bench.verdict import RUN_S, default_design, effect_cases, simulated_samples
from gsp_calibrator.node.result_delivery import ResultDelivery
from gsp_calibrator.run.identify import identify_with_settings
from gsp_calibrator.run.response import outcome_summary
from gsp_kinematics.estimation.rigid_fold import held_out_postures, linearised_model_errors
from gsp_kinematics.estimation.verdict.rigid_held_out import rigid_held_out
from gsp_kinematics.model.effects import REALISTIC, IdentifiedEffects
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.validation import pose_errors, simulate_commands
from gsp_msgs_py.geometry_parameters import EFFECT_PARAMETER_NAMES

SEEDS = range(3)
#: The realistic platform's four effects, freed with the payload given (as ``auto`` keeps them
#: there; fixed here so the test does not pay for the model choice).
VALUES = {
    'free_parameters': ['extended', 'compliance', 'backlash', 'thermal', 'joint_offsets'],
    'payload_mass': REALISTIC.payload_mass,
    'payload_centre_of_mass': list(REALISTIC.centre_of_mass),
}
#: Workspace postures of the truth (a seed of their own): the rigid error has a tail (a few
#: postures in a thousand near 1 mm on this platform) that 50 postures sample poorly.
TRUTH_POSTURES = 2000


@pytest.fixture(scope='module')
def design():
    return default_design(VALUES)


@pytest.fixture(scope='module')
def outcomes(design):
    return [
        identify_with_settings(design.settings, simulated_samples(design, REALISTIC, seed))
        for seed in SEEDS
    ]


def true_mm(design, controller):
    """Mean position error (mm) of ``controller`` on the realistic platform's physics over
    random workspace postures, spread over the run's span (as the held-out rows are)."""
    poses = sample_valid_postures(design.settings.nominal, TRUTH_POSTURES, np.random.default_rng(7))
    times = np.linspace(0.0, RUN_S, len(poses))
    run = simulate_commands(design.true, controller, poses, REALISTIC, times)
    return float(np.mean(pose_errors(poses[run.reachable], run.real_poses[run.reachable])[0]))


def test_the_rigid_held_out_figure_tracks_the_rigid_geometrys_true_accuracy(design, outcomes):
    folded, unfolded, inside = [], [], 0
    for outcome in outcomes:
        assert outcome.success and outcome.rigid_geometry is not None, outcome.message
        figure = outcome.rigid_accuracy['calibrated']['position_mm']
        true = true_mm(design, outcome.rigid_geometry)
        folded.append(figure['mean'] / true)
        low, high = figure['mean_interval_95']
        assert low < figure['mean'] < high
        inside += low <= true <= high
        # The same figure for a rigid geometry the fold did not make (the geometry run without
        # its effects, 2-3x worse): it follows what the controller runs, not the fit.
        geometry = outcome.geometry
        bare = geometry.replace(effects=IdentifiedEffects())
        systematic = linearised_model_errors(geometry, bare, held_out_postures(geometry))
        held_out = rigid_held_out(outcome.accuracy, *systematic)
        unfolded.append(held_out['calibrated']['position_mm']['mean'] / true_mm(design, bare))
    # The brief's figure (issue 33): within 25 % of the truth, median over the seeds (measured
    # 1.08, 1.26, 1.01; the identified model's systematic part runs ~10 % above the physics').
    assert abs(statistics.median(folded) - 1.0) <= 0.25, folded
    # The 95 % interval holds the truth (all three; seed 1 by 0.3 um).
    assert inside >= len(SEEDS) - 1, (inside, folded)
    # Without the systematic part the figure would be 0.3x the truth here.
    assert 0.67 <= statistics.median(unfolded) <= 1.5, unfolded


class Controller:
    """A controller's parameter services: it declares the effects (compensating) or not."""

    def __init__(self, compensating):
        self.declared = ['geometry.leg_offsets']
        self.declared += list(EFFECT_PARAMETER_NAMES) if compensating else []
        self.sent = None

    async def list(self, node_name, prefix, timeout_s, wait_for):
        return [name for name in self.declared if name.startswith(prefix + '.')], ''

    async def set(self, node_name, values, timeout_s, wait_for):
        self.sent = values
        return True, ''


def deliver(outcome, controller):
    delivery = ResultDelivery.__new__(ResultDelivery)
    delivery.node = types.SimpleNamespace(get_logger=lambda: types.SimpleNamespace(info=print))
    delivery.publisher = types.SimpleNamespace(publish=lambda message: None)
    delivery.parameter_setter = controller
    settings = types.SimpleNamespace(
        apply_result=True,
        platform_node_name='controller',
        topic_timeout=1.0,
        controller_effects='auto',
    )
    return asyncio.run(
        delivery.deliver(settings, outcome.geometry, outcome.verdicts, outcome.rigid_geometry, None)
    )


def test_a_rigid_controller_is_judged_on_the_rigid_figure(design, outcomes):
    first = outcomes[0]
    # The default requirement accepts both: the rigid controller gets the rigid geometry.
    controller = Controller(compensating=False)
    success, note = deliver(first, controller)
    assert success and note.endswith('the verdict describes the rigid geometry'), note
    compensating = first.accuracy['calibrated']['position_mm']['mean']
    rigid = first.rigid_accuracy['calibrated']['position_mm']['mean']
    assert rigid > 1.2 * compensating, (rigid, compensating)
    # A requirement between the two (the predictions too: the verdict checks them).
    required = float(np.sqrt(compensating * rigid))
    settings = default_design({**VALUES, 'required_position_accuracy_mm': required}).settings
    outcome = identify_with_settings(settings, simulated_samples(design, REALISTIC, SEEDS[0]))
    assert outcome.accepted and not outcome.rigid_judgement.accepted
    # Both verdicts in the summary (the response without apply_result, the log, report.md).
    summary = outcome_summary(outcome)
    assert '\ncalibration accepted: meets the required accuracy' in summary
    assert '\nrigid controller (result_rigid.yaml): calibration NOT accepted' in summary
    assert 'accuracy rigid geometry (held out): position mean (mm) ' in summary

    controller = Controller(compensating=True)
    success, note = deliver(outcome, controller)
    assert success and controller.sent is not None, note
    assert note.endswith('the verdict describes the compensating geometry'), note

    controller = Controller(compensating=False)
    success, note = deliver(outcome, controller)
    assert not success and controller.sent is None, note
    assert note.startswith(
        'NOT applied to /controller: it runs the rigid geometry (result_rigid.yaml): it does '
        'not declare the geometry.effects.* parameters, and the verdict of the rigid geometry '
        'does not accept it: position'
    ), note


def test_the_rigid_section_sets_the_best_rigid_geometry_beside_the_fits_noise(design):
    """``rigid_over_best_and_ideal``: a rigid geometry as good as the best one, identified at the
    plan's noise, has the best's error and the ideal platform's (the fit's) added as
    independent errors; its truth at that level reads 1 where ``rigid_over_best`` reads more."""
    import math

    from gsp_bench import rigid_fold

    best_mm, floor_mm = 0.00276, 0.0031
    level = math.hypot(best_mm, floor_mm)
    runs = [
        {
            'rigid_true_mm': level * factor,
            'rigid_true_at_end_mm': level * factor,
            'rigid_cv_mm': level,
            'rigid_cv_interval_mm': [0.5 * level, 2 * level],
        }
        for factor in (0.9, 1.0, 1.1)
    ]
    backlash = effect_cases()['backlash']
    figures = rigid_fold.rigid_figures(design, backlash, runs, best_mm, floor_mm)
    assert figures['rigid_over_best_and_ideal'] == pytest.approx(1.0)
    assert figures['rigid_over_best'] == pytest.approx(level / best_mm)


def test_the_rigid_section_has_no_ratio_to_a_best_geometry_without_error(design):
    """Thermal growth alone: at the run's end a rigid geometry describes the platform exactly
    (the best there is 0 mm), so the ratio to it is NaN, not a division by rounding noise."""
    import math

    from gsp_bench import rigid_fold

    runs = [
        {
            'rigid_true_mm': 0.007,
            'rigid_true_at_end_mm': 0.003,
            'rigid_cv_mm': 0.007,
            'rigid_cv_interval_mm': [0.004, 0.01],
        }
    ]
    figures = rigid_fold.rigid_figures(design, effect_cases()['thermal'], runs, 0.0053)
    assert figures['best_at_end_mm'] < 1e-9
    assert math.isnan(figures['rigid_at_end_over_best_at_end'])
    assert figures['rigid_over_best'] == pytest.approx(0.007 / 0.0053)
