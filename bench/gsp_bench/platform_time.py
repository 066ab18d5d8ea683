"""``platform_time`` section of ``gsp_bench`` (docs/planning.md, docs/figures.md).

* ``selection_order_s``, ``route_s``, ``lower_bound_s``: the travel time of the default plan's
  60 selected postures from the home pose in selection order, in route order, and the route's
  lower bound (minimum spanning tree), with the realistic leg limits
  (:class:`gsp_kinematics.model.motion.MotionLimits`); ``route_ratio`` = route / selection order.
* ``predicted_s`` against ``measured_s``: a calibration through the nodes (``gsp_demo``,
  ``platform_sim`` moving at the realistic limits, the calibrator commanding the route):
  predicted travel + settle + sampling, against the wall time of the calibrate call
  (``summary.json`` ``calibration_s``, which also holds the start-up checks, the identification
  and the report).
* ``target_plan``: for a target of 1.5x the default plan's predicted mean position error, the
  plan of least platform time (:func:`gsp_calibrator.tools.plans.target_plan`) against the default plan.
"""

import sys

from gsp_bench.end_to_end import SETTLE_TIME_S, run_demo
from gsp_calibrator.tools import plans
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.motion import MotionLimits

MEASURED_POSTURES = 20
QUICK_MEASURED_POSTURES = 12
PAIRS_PER_POSTURE = 10
SENSOR_RATE_HZ = 200.0
TARGET_FACTOR = 1.5


def _plan_record(entry):
    return {
        'postures': entry['postures'],
        'pairs_per_posture': entry['pairs_per_posture'],
        'position_mm_mean': entry['predicted']['position_mm_mean'],
        'orientation_deg_mean': entry['predicted']['orientation_deg_mean'],
        'platform_s': entry['platform_time']['total_s'],
        'travel_s': entry['platform_time']['travel_s'],
        'settle_s': entry['platform_time']['settle_s'],
        'sampling_s': entry['platform_time']['sampling_s'],
    }


def measured_run(postures, limits, log):
    """A calibration through the nodes at ``limits``: predicted and measured platform time."""
    nominal = default_geometry('nominal')
    extra = [
        '--max-leg-speed',
        repr(limits.max_speed),
        '--max-leg-acceleration',
        repr(limits.max_acceleration),
    ]
    predicted = plans.plan(
        nominal,
        postures,
        PAIRS_PER_POSTURE,
        settle_s=SETTLE_TIME_S,
        sensor_rate_hz=SENSOR_RATE_HZ,
        limits=limits,
    )['platform_time']
    log(
        f'gsp_bench: platform_time: {postures}-posture calibration through the nodes at '
        f'{limits.max_speed:g} m/s (predicted {predicted["total_s"]:.0f} s) ...'
    )
    run = run_demo(
        postures,
        SENSOR_RATE_HZ,
        validation_postures=1,
        timeout=3.0 * predicted['total_s'] + 120.0,
        extra_args=extra,
    )
    summary = run['summary'] or {}
    measured = summary.get('calibration_s')
    record = {
        'postures': postures,
        'pairs_per_posture': PAIRS_PER_POSTURE,
        'predicted_s': predicted['total_s'],
        'predicted_parts_s': {
            key: predicted[key] for key in ('travel_s', 'settle_s', 'sampling_s')
        },
        'measured_s': measured,
        'postures_collected': len(run['samples'] or []),
        'max_param_error_mm': summary.get('max_param_error_mm'),
    }
    if measured:
        record['prediction_error'] = (predicted['total_s'] - measured) / measured
    if run['exit_code'] != 0:
        record['error'] = f'gsp_demo exited with {run["exit_code"]}: ' + run['output'][-800:]
    return record


def run(quick=False, log=None):
    """The section (see the module docstring)."""
    if log is None:

        def log(message):
            print(message, file=sys.stderr, flush=True)

    nominal = default_geometry('nominal')
    limits = MotionLimits()
    log('gsp_bench: platform_time: the default plan and its route ...')
    default = plans.plan(nominal, 60, PAIRS_PER_POSTURE, limits=limits)
    timing = default['platform_time']
    section = {
        'max_leg_speed_m_s': limits.max_speed,
        'max_leg_acceleration_m_s2': limits.max_acceleration,
        'postures': 60,
        'selection_order_s': timing['selection_order_travel_s'],
        'route_s': timing['travel_s'],
        'lower_bound_s': timing['lower_bound_travel_s'],
        'route_ratio': timing['travel_s'] / timing['selection_order_travel_s'],
        'route_over_bound': timing['travel_s'] / timing['lower_bound_travel_s'],
    }
    log('gsp_bench: platform_time: the plan aimed at 1.5x the default accuracy ...')
    target_mm = TARGET_FACTOR * default['predicted']['position_mm_mean']
    found = plans.target_plan(nominal, target_mm, limits=limits)
    section['target_plan'] = {
        'target_position_mm': target_mm,
        'default': _plan_record(default),
        'found': None if found['plan'] is None else _plan_record(found['plan']),
    }
    if found['plan'] is not None:
        section['target_plan']['platform_time_ratio'] = (
            found['plan']['platform_time']['total_s'] / timing['total_s']
        )
    section['calibration'] = measured_run(
        QUICK_MEASURED_POSTURES if quick else MEASURED_POSTURES, limits, log
    )
    for key in ('predicted_s', 'measured_s', 'prediction_error'):
        section[key] = section['calibration'].get(key)
    return section
