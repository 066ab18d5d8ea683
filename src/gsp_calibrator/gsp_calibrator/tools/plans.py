"""Calibration plans (pure, no ROS): the predicted accuracy and platform time of a plan, a sweep
over posture counts and pairs per posture, and the plan of least platform time that reaches a
target accuracy. ``gsp_plan`` (:mod:`.planning`) is their command line; docs/planning.md."""

import dataclasses
import math

import numpy as np

from gsp_calibrator.run.postures import (
    DEFAULT_FREE,
    PLAN_SENSOR_RATE_HZ,
    PLAN_SETTLE_S,
    CalibrationError,
    choose_postures,
    selection_formulation,
)
from gsp_calibrator.settings import DEFAULTS
from gsp_kinematics.estimation.identifiability import (
    analyse_identifiability,
    posture_information,
    unidentifiable_parameters,
)
from gsp_kinematics.estimation.identification import DEFAULT_FORMULATION, resolve_free
from gsp_kinematics.estimation.prediction import accuracy_summary, predict_accuracy
from gsp_kinematics.model.kinematics import Workspace, home_pose
from gsp_kinematics.model.motion import MotionLimits
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoise
from gsp_kinematics.planning.effect_plan import augment_route, effect_identifiability
from gsp_kinematics.planning.route import plan_route

DEFAULT_SWEEP_POSTURES = (15, 20, 30, 45, 60, 90, 120)
DEFAULT_SWEEP_SAMPLES = (1, 5, 10, 20)
#: Posture counts :func:`target_plan` considers (the 44 parameters need at least 11).
DEFAULT_TARGET_POSTURES = (12, 15, 20, 25, 30, 40, 50, 60, 75, 90, 120)
#: Most pairs per posture a target plan averages: 0.5 s at 200 Hz. Averaging more assumes white
#: sensor noise for longer than a real sensor's drift allows.
MAX_PAIRS_PER_POSTURE = 100


def design_prediction(nominal, poses, pairs_per_posture, design):
    """Rank, unidentifiable combinations and predicted accuracy of commanding ``poses``."""
    row_sigmas = design.sigmas.averaged([pairs_per_posture])
    free_mask = resolve_free(design.free)
    information = posture_information(
        nominal, poses, row_sigmas, free_mask, selection_formulation(design.formulation)
    ).sum(axis=0)
    analysis = analyse_identifiability(information, free_mask)
    plan = {
        'rank': analysis['rank'],
        'parameters': analysis['parameters'],
        'condition_number': analysis['condition_number'],
        'unidentifiable': analysis['unidentifiable'],
        'unidentifiable_parameters': unidentifiable_parameters(analysis),
        'predicted': None,
    }
    if analysis['rank'] == analysis['parameters']:
        covariance = np.linalg.inv(information)
        prediction = predict_accuracy(nominal, covariance, free_mask, design.workspace)
        plan['predicted'] = {
            **accuracy_summary(prediction),
            'worst_cell': prediction['worst_cell'],
            'statistic': prediction['statistic'],
            'assumes': prediction['assumes'],
        }
    return plan


def platform_time(nominal, poses, pairs_per_posture, settle_s, sensor_rate_hz, limits):
    """Predicted platform time (s) of commanding ``poses`` in route order from the home pose:
    ``{'total_s', 'travel_s', 'settle_s', 'sampling_s', 'selection_order_travel_s',
    'lower_bound_travel_s', 'order'}``."""
    route = plan_route(nominal, home_pose(), poses, limits)
    count = len(poses)
    settle, sampling = count * settle_s, count * pairs_per_posture / sensor_rate_hz
    return {
        'total_s': route.travel_s + settle + sampling,
        'travel_s': route.travel_s,
        'settle_s': settle,
        'sampling_s': sampling,
        'selection_order_travel_s': route.selection_order_s,
        'lower_bound_travel_s': route.lower_bound_s,
        'order': route.order.tolist(),
    }


@dataclasses.dataclass(frozen=True)
class Design:
    """What the calibrator's selection and model depend on, besides the counts."""

    sigmas: SensorNoise = DEFAULT_SENSOR_NOISE  #: per-sample sensor noise (m, rad)
    free: tuple = DEFAULT_FREE  #: free parameter and group names (the calibrator's default)
    formulation: str = DEFAULT_FORMULATION
    workspace: Workspace = Workspace()
    pool_size: int = DEFAULTS['pool_size']
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class EffectPlan:
    """The effect groups a calibration will free and what their plan needs
    (:func:`gsp_kinematics.planning.effect_plan.augment_route`; docs/platform_effects.md)."""

    groups: tuple = ()
    revisit_every: int | None = None  #: thermal: postures between reference revisits
    revisit_interval_s: float | None = None  #: thermal: platform time between revisits (s)
    min_arrivals: int = 1  #: backlash: arrivals each way per leg
    payload_mass: float = 0.0  #: compliance: the payload (kg) the user gives
    centre_of_mass: tuple = (0.0, 0.0, 0.0)  #: its centre of mass, platform frame (m)
    thermal_time_constant_s: float = 0.0  #: thermal: first-order warming (s; 0: linear)


def effect_plan(nominal, poses, pairs_per_posture, design, effects, dwell_s, limits):
    """The route through ``poses`` (route order) augmented for ``effects`` (an
    :class:`EffectPlan`): what it adds and costs, and per group its identifiability and
    Cramér-Rao bound at the design's noise averaged over the samples."""
    route = augment_route(
        nominal,
        poses,
        effects.groups,
        start_pose=home_pose(),
        revisit_every=effects.revisit_every,
        revisit_interval_s=effects.revisit_interval_s,
        dwell_s=dwell_s,
        limits=limits,
        min_arrivals=effects.min_arrivals,
    )
    groups = effect_identifiability(
        nominal,
        route.poses,
        route.design(
            effects.payload_mass,
            effects.centre_of_mass,
            thermal_time_constant_s=effects.thermal_time_constant_s,
        ),
        effects.groups,
        design.sigmas.averaged([pairs_per_posture]),
        design.free,
    )
    return {'groups': list(effects.groups), 'route': route.to_dict(), 'identifiability': groups}


def select(nominal, postures, pairs_per_posture, design=Design()):
    """The calibrator's posture selection for these settings (``choose_postures``)."""
    return choose_postures(
        nominal,
        postures,
        design.pool_size,
        design.seed,
        design.sigmas.averaged([pairs_per_posture]),
        design.free,
        design.formulation,
        design.workspace,
    )


def plan(
    nominal,
    postures=DEFAULTS['posture_count'],
    pairs_per_posture=DEFAULTS['pairs_per_posture'],
    design=Design(),
    settle_s=PLAN_SETTLE_S,
    sensor_rate_hz=PLAN_SENSOR_RATE_HZ,
    selection=None,
    limits=MotionLimits(),
    effects=None,
):
    """One plan (a JSON-ready dict); ``selection``: a ``run.postures.PostureSelection`` of these
    settings to reuse (the sweep shares one per posture count); ``limits``: the legs' motion
    limits of the platform time; ``effects``: an :class:`EffectPlan` whose groups add the plan's
    ``effects`` entry (:func:`effect_plan`)."""
    if pairs_per_posture < 1:
        raise CalibrationError(f'pairs per posture must be >= 1, got {pairs_per_posture}')
    if not (sensor_rate_hz > 0 and settle_s >= 0):
        raise CalibrationError('the sensor rate must be > 0 Hz and the settle time >= 0 s')
    if selection is None:
        selection = select(nominal, postures, pairs_per_posture, design)
    prediction = design_prediction(nominal, selection.poses, pairs_per_posture, design)
    timing = platform_time(
        nominal, selection.poses, pairs_per_posture, settle_s, sensor_rate_hz, limits
    )
    extra = {}
    if effects is not None and effects.groups:
        ordered = selection.poses[timing['order']]
        dwell_s = settle_s + pairs_per_posture / sensor_rate_hz
        extra['effects'] = effect_plan(
            nominal, ordered, pairs_per_posture, design, effects, dwell_s, limits
        )
    return {
        'postures': int(postures),
        'pairs_per_posture': int(pairs_per_posture),
        **prediction,
        # The physical minimum of the collection.
        'calibration_s': postures * (settle_s + pairs_per_posture / sensor_rate_hz),
        'platform_time': timing,
        'selection': {
            'pool_size': selection.pool_size,
            'seed': selection.seed,
            'condition_number': selection.condition_number,
            'duration_s': selection.duration_s,
            'poses': selection.poses.tolist(),
        },
        **extra,
    }


def sweep(nominal, posture_counts, samples, design=Design(), **timing):
    """Plans over ``posture_counts`` x ``samples`` (without the poses): ``{'rows': [...]}``;
    ``timing``: ``settle_s``, ``sensor_rate_hz`` and ``limits`` of :func:`plan`."""
    rows = []
    for count in posture_counts:
        # Averaging scales every sigma alike: the selection does not depend on the samples.
        selection = select(nominal, count, samples[0], design)
        for pairs_per_posture in samples:
            entry = plan(nominal, count, pairs_per_posture, design, selection=selection, **timing)
            entry.pop('selection')
            entry['platform_time'].pop('order')
            rows.append(entry)
    return {
        'posture_counts': list(posture_counts),
        'pairs_per_posture': list(samples),
        'rows': rows,
    }


def _meets(predicted, position_mm, orientation_deg):
    return bool(predicted) and (
        (position_mm is None or predicted['position_mm_mean'] <= position_mm)
        and (orientation_deg is None or predicted['orientation_deg_mean'] <= orientation_deg)
    )


def target_plan(
    nominal,
    position_mm=None,
    orientation_deg=None,
    design=Design(),
    posture_counts=DEFAULT_TARGET_POSTURES,
    max_samples=MAX_PAIRS_PER_POSTURE,
    settle_s=PLAN_SETTLE_S,
    sensor_rate_hz=PLAN_SENSOR_RATE_HZ,
    limits=MotionLimits(),
):
    """The plan of least predicted platform time whose predicted mean errors reach the targets
    (mm, deg): ``{'plan': plan or None, 'candidates': [...], 'best_reachable': {...}}``."""
    if position_mm is None and orientation_deg is None:
        raise CalibrationError('a target needs a position (mm) or an orientation (deg)')
    timing = {'settle_s': settle_s, 'sensor_rate_hz': sensor_rate_hz, 'limits': limits}
    targets = {'position_mm_mean': position_mm, 'orientation_deg_mean': orientation_deg}
    candidates, best, best_reachable = [], None, None
    for count in sorted(c for c in posture_counts if c <= design.pool_size):
        selection = select(nominal, count, 1, design)
        single = design_prediction(nominal, selection.poses, 1, design)['predicted']
        if not single:
            continue  # rank-deficient: no count of samples helps
        ratios = [
            (single[key] / target) ** 2 for key, target in targets.items() if target is not None
        ]
        reachable = {key: single[key] / math.sqrt(max_samples) for key in targets}
        if (
            best_reachable is None
            or reachable['position_mm_mean'] < best_reachable['position_mm_mean']
        ):
            best_reachable = {'postures': count, 'pairs_per_posture': max_samples, **reachable}
        samples = max(1, math.ceil(max(ratios) * (1.0 - 1e-12)))
        if samples > max_samples:
            continue
        entry = plan(nominal, count, samples, design, selection=selection, **timing)
        if not _meets(entry['predicted'], position_mm, orientation_deg):  # rounding
            entry = plan(nominal, count, samples + 1, design, selection=selection, **timing)
        candidates.append(
            {
                'postures': count,
                'pairs_per_posture': entry['pairs_per_posture'],
                'platform_s': entry['platform_time']['total_s'],
                'position_mm_mean': entry['predicted']['position_mm_mean'],
                'orientation_deg_mean': entry['predicted']['orientation_deg_mean'],
            }
        )
        if best is None or entry['platform_time']['total_s'] < best['platform_time']['total_s']:
            best = entry
    return {
        'target': {'position_mm': position_mm, 'orientation_deg': orientation_deg},
        'plan': best,
        'candidates': candidates,
        'best_reachable': best_reachable,
        'max_pairs_per_posture': max_samples,
    }


def cheapest_meeting(result, position_um=None, orientation_deg=None):
    """The sweep row with the shortest calibration whose predicted means meet the targets
    (position in µm, orientation in deg); None if no row does."""
    position_mm = None if position_um is None else position_um / 1000.0
    meeting = [r for r in result['rows'] if _meets(r['predicted'], position_mm, orientation_deg)]
    return min(meeting, key=lambda row: (row['calibration_s'], row['postures']), default=None)


def sweep_table(result):
    """The sweep as a text table (mm, deg, s)."""
    lines = [
        f'{"postures":>8} {"samples":>7} {"rank":>9} {"position mm":>12} '
        f'{"p95 mm":>10} {"orient. deg":>12} {"time s":>8}'
    ]
    for row in result['rows']:
        predicted = row['predicted'] or {}

        def number(key, predicted=predicted):
            value = predicted.get(key)
            return '-' if value is None else f'{value:.3g}'

        lines.append(
            f'{row["postures"]:>8} {row["pairs_per_posture"]:>7} '
            f'{row["rank"]:>4}/{row["parameters"]:<4} {number("position_mm_mean"):>12} '
            f'{number("position_mm_p95"):>10} {number("orientation_deg_mean"):>12} '
            f'{row["calibration_s"]:>8.1f}'
        )
    return '\n'.join(lines)
