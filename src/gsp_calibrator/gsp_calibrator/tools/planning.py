"""``gsp_plan``: plan a calibration before moving the platform (pure, no ROS).
See docs/planning.md#gsp_plan."""

import argparse
import math
import sys

from gsp_calibrator.run.postures import (
    PLAN_SENSOR_RATE_HZ,
    PLAN_SETTLE_S,
    CalibrationError,
    route_effect_groups,
)
from gsp_calibrator.settings import add_run_options, run_options_error
from gsp_calibrator.tools import plans
from gsp_kinematics.estimation.identification import IdentificationError
from gsp_kinematics.fileio import atomic_write_text, json_safe, to_json
from gsp_kinematics.model.effects import EFFECT_GROUPS
from gsp_kinematics.model.geometry import GeometryError, default_geometry_path, load_geometry
from gsp_kinematics.model.kinematics import Workspace
from gsp_kinematics.model.motion import MotionLimits
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoise


def plot_sweep(path, result):
    """Predicted mean position and orientation error against posture count, one curve per
    pairs-per-posture (log scale)."""
    from gsp_calibrator.report.plots import new_figure, save_figure

    figure = new_figure(10, 4.2, left=0.1, right=0.98, top=0.88, bottom=0.13, wspace=0.3)
    panels = {
        'position_mm_mean': 'position error (mm)',
        'orientation_deg_mean': 'orientation error (deg)',
    }
    for column, (key, label) in enumerate(panels.items()):
        axes = figure.add_subplot(1, 2, column + 1)
        for samples in result['pairs_per_posture']:
            rows = [r for r in result['rows'] if r['pairs_per_posture'] == samples]
            points = [(r['postures'], r['predicted'][key]) for r in rows if r['predicted']]
            if points:
                x, y = zip(*points, strict=True)
                axes.plot(x, y, 'o-', label=f'{samples} samples/posture')
        axes.set_yscale('log')
        axes.set_xlabel('postures')
        axes.set_ylabel(f'predicted mean {label}')
        axes.grid(True, which='both', alpha=0.3)
        axes.legend(fontsize=8)
    figure.suptitle('Predicted accuracy after calibration (Cramér-Rao, selected postures)')
    return save_figure(figure, path)


def _positive_ints(text):
    try:
        values = [int(part) for part in text.split(',') if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a comma-separated list, got {text!r}') from None
    if not values or any(value < 1 for value in values):
        raise argparse.ArgumentTypeError(f'expected values >= 1, got {text!r}')
    return values


def parse_arguments(argv=None):
    parser = argparse.ArgumentParser(
        prog='gsp_plan',
        description='Predict the accuracy, identifiability and duration of a calibration before '
        'moving the platform (no ROS needed).',
    )
    add = parser.add_argument
    add('--geometry', default=default_geometry_path('nominal'), help='nominal geometry params file')
    add_run_options(parser, seed_help="the calibrator's seed of the posture pool")
    noise = DEFAULT_SENSOR_NOISE
    add(
        '--sigma-leg-lengths-um', type=float, default=noise.leg_lengths * 1e6, help='leg sensor, µm'
    )
    add('--sigma-inclinometer-deg', type=float, default=math.degrees(noise.inclinometer))
    add('--sigma-encoder-deg', type=float, default=math.degrees(noise.encoder))
    add('--sigma-lvdt-um', type=float, default=noise.lvdt * 1e6, help='LVDT, µm')
    workspace = Workspace()
    add('--xy-range-mm', type=float, default=workspace.xy_range * 1e3, help='+- x and y (400)')
    add('--z-min-mm', type=float, default=workspace.z_min * 1e3)
    add('--z-max-mm', type=float, default=workspace.z_max * 1e3)
    add('--rotation-range-deg', type=float, default=math.degrees(workspace.rotation_range))
    add('--settle-s', type=float, default=PLAN_SETTLE_S, help='settle time per posture, s (0.02)')
    add(
        '--sensor-rate-hz',
        type=float,
        default=PLAN_SENSOR_RATE_HZ,
        help=f'synchronised pair rate, Hz ({PLAN_SENSOR_RATE_HZ:g})',
    )
    add('--output', default=None, help='write the plan (or the sweep) as JSON here')
    add('--sweep', action='store_true', help='sweep posture counts and pairs per posture')
    add('--sweep-postures', type=_positive_ints, default=plans.DEFAULT_SWEEP_POSTURES)
    add('--sweep-samples', type=_positive_ints, default=plans.DEFAULT_SWEEP_SAMPLES)
    add('--target-position-um', type=float, default=None, help='sweep: wanted mean position error')
    add('--target-orientation-deg', type=float, default=None, help='sweep: wanted mean orientation')
    add('--plot', default=None, help='sweep plot PNG (default: beside --output, else gsp_plan.png)')
    limits = MotionLimits()
    add('--max-leg-speed-mm-s', type=float, default=limits.max_speed * 1e3, help='leg speed limit')
    add(
        '--max-leg-acceleration-mm-s2',
        type=float,
        default=limits.max_acceleration * 1e3,
        help='leg acceleration limit',
    )
    add('--target-position-mm', type=float, default=None, help='plan for this mean position error')
    add(
        '--target-postures',
        type=_positive_ints,
        default=plans.DEFAULT_TARGET_POSTURES,
        help='posture counts a target plan considers',
    )
    add('--max-pairs-per-posture', type=int, default=plans.MAX_PAIRS_PER_POSTURE)
    _add_effect_options(add)
    args = parser.parse_args(argv)
    reason = run_options_error(args)
    if reason:
        parser.error(reason)
    for name in [name for name in vars(args) if name.startswith(('sigma_', 'max_leg_'))]:
        if not (math.isfinite(getattr(args, name)) and getattr(args, name) > 0):
            parser.error(f'--{name.replace("_", "-")} must be a finite number > 0')
    if not args.z_min_mm < args.z_max_mm or args.xy_range_mm <= 0 or args.rotation_range_deg < 0:
        parser.error(
            'workspace: need --z-min-mm < --z-max-mm, --xy-range-mm > 0 and '
            '--rotation-range-deg >= 0'
        )
    return args


def _add_effect_options(add):
    """The options of the effect groups' plan (docs/platform_effects.md)."""
    add(
        '--effects',
        nargs='+',
        default=[],
        choices=list(EFFECT_GROUPS),
        metavar='GROUP',
        help='effect groups the calibration will free: the plan adds what they need and gives '
        f'their identifiability and Cramér-Rao bound ({", ".join(EFFECT_GROUPS)})',
    )
    add(
        '--revisit-every',
        type=int,
        default=None,
        help='thermal: postures between revisits (0: the end only)',
    )
    add('--revisit-interval-s', type=float, default=None, help='thermal: seconds between revisits')
    add('--min-arrivals', type=int, default=1, help='backlash: arrivals each way per leg (1)')
    add('--payload-mass-kg', type=float, default=0.0, help='compliance: the payload (kg)')
    add(
        '--centre-of-mass-mm',
        type=float,
        nargs=3,
        default=[0.0, 0.0, 0.0],
        metavar=('X', 'Y', 'Z'),
        help='compliance: the payload centre of mass, platform frame (mm)',
    )
    add('--thermal-time-constant-s', type=float, default=0.0, help='thermal: warming (0: linear)')


def effect_plan_from(args):
    """The ``plans.EffectPlan`` of the command line: the ``--effects`` groups, else those the
    calibrator's route adds postures for with ``--free`` (``auto``: thermal and backlash,
    ``postures.effect_route``); None when neither."""
    groups = tuple(args.effects)
    if not groups and args.formulation == 'implicit':
        groups = tuple(route_effect_groups(args.free_parameters))
    if not groups:
        return None
    return plans.EffectPlan(
        groups=groups,
        revisit_every=args.revisit_every,
        revisit_interval_s=args.revisit_interval_s,
        min_arrivals=args.min_arrivals,
        payload_mass=args.payload_mass_kg,
        centre_of_mass=tuple(v / 1e3 for v in args.centre_of_mass_mm),
        thermal_time_constant_s=args.thermal_time_constant_s,
    )


def _effects_text(entry):
    route = entry['route']
    lines = [
        f'effects {" ".join(entry["groups"])}: {route["added_postures"]} postures added '
        f'({route["reference_revisits"]} reference revisits, {route["approach_insertions"]} for '
        f'the approach directions), platform time +{route["added_s"]:.1f} s'
    ]
    if route['one_way_legs']:
        legs = ' '.join(str(leg) for leg in route['one_way_legs'])
        lines.append(f'legs arriving from one direction only: {legs}')
    for group, found in entry['identifiability'].items():
        if 'error' in found:
            lines.append(f'{group}: {found["error"]}')
        elif not found['identifiable']:
            lines.append(
                f'{group}: NOT identifiable (rank {found["rank"]} of {found["parameters"]})'
            )
        else:
            worst = max(found['worst_correlations'], key=lambda w: abs(w['correlation']))
            lines.append(
                f'{group}: rank {found["rank"]} of {found["parameters"]}, Cramér-Rao '
                f'{max(found["crb_leg_um"]):.2g} um of leg at most, worst correlation '
                f'{worst["parameter"]}-{worst["with"]} {worst["correlation"]:+.2f}'
            )
    return '\n'.join(lines)


def design_from(args):
    """The ``plans.Design`` of the command line."""
    sigmas = SensorNoise(
        leg_lengths=args.sigma_leg_lengths_um * 1e-6,
        inclinometer=math.radians(args.sigma_inclinometer_deg),
        encoder=math.radians(args.sigma_encoder_deg),
        lvdt=args.sigma_lvdt_um * 1e-6,
    )
    workspace = Workspace(
        xy_range=args.xy_range_mm / 1e3,
        z_min=args.z_min_mm / 1e3,
        z_max=args.z_max_mm / 1e3,
        rotation_range=math.radians(args.rotation_range_deg),
    )
    return plans.Design(
        sigmas=sigmas,
        free=tuple(args.free_parameters),
        formulation=args.formulation,
        workspace=workspace,
        pool_size=args.pool_size,
        seed=args.seed,
    )


def _summary_text(entry):
    predicted = entry['predicted']
    lines = [
        f'{entry["postures"]} postures x {entry["pairs_per_posture"]} samples: rank '
        f'{entry["rank"]} of {entry["parameters"]}, calibration {entry["calibration_s"]:.1f} s'
    ]
    if predicted:
        lines.append(
            f'predicted after calibration: position {predicted["position_mm_mean"]:.3g} mm mean '
            f'({predicted["position_mm_p95"]:.3g} p95), orientation '
            f'{predicted["orientation_deg_mean"]:.3g} deg mean'
        )
        lines.append(f'the prediction assumes {predicted["assumes"]}')
    for entry_ in entry['unidentifiable']:
        lines.append(f'not identifiable: {entry_["combination"]}')
    timing = entry['platform_time']
    lines.append(
        f'platform time {timing["total_s"]:.1f} s: travel {timing["travel_s"]:.1f} s in route '
        f'order (selection order {timing["selection_order_travel_s"]:.1f} s, lower bound '
        f'{timing["lower_bound_travel_s"]:.1f} s), settle {timing["settle_s"]:.1f} s, sampling '
        f'{timing["sampling_s"]:.1f} s\nroute (selection indices): '
        + ' '.join(str(index) for index in timing['order'])
    )
    if entry.get('effects'):
        lines.append(_effects_text(entry['effects']))
    return '\n'.join(lines)


def _target_text(result):
    best, target = result['plan'], result['target']
    wanted = []
    if target['position_mm'] is not None:
        wanted.append(f'position {target["position_mm"]:g} mm')
    if target['orientation_deg'] is not None:
        wanted.append(f'orientation {target["orientation_deg"]:g} deg')
    wanted = ', '.join(wanted)
    if best is None:
        reach = result['best_reachable']
        if reach is None:
            return f'no plan reaches {wanted}: no posture count is identifiable'
        return (
            f'no plan within the pool reaches {wanted}; the best reaches position '
            f'{reach["position_mm_mean"]:.3g} mm, orientation {reach["orientation_deg_mean"]:.3g} '
            f'deg mean ({reach["postures"]} postures x {reach["pairs_per_posture"]} samples)'
        )
    return f'least platform time reaching {wanted}:\n' + _summary_text(best)


def _inputs(args, design, limits):
    """The plan's inputs, as written beside it (SI units)."""
    return {
        'geometry': str(args.geometry),
        'sigmas': design.sigmas.channels(),
        'workspace': {
            'xy_range_m': design.workspace.xy_range,
            'z_min_m': design.workspace.z_min,
            'z_max_m': design.workspace.z_max,
            'rotation_range_rad': design.workspace.rotation_range,
        },
        'settle_s': args.settle_s,
        'sensor_rate_hz': args.sensor_rate_hz,
        'pool_size': args.pool_size,
        'seed': args.seed,
        'formulation': args.formulation,
        'free': args.free_parameters,
        'max_leg_speed_m_s': limits.max_speed,
        'max_leg_acceleration_m_s2': limits.max_acceleration,
        'effects': args.effects,
    }


def _sweep_document(args, nominal, design, timing):
    """``--sweep``: the sweep (printed and plotted), with the cheapest design meeting a target."""
    result = plans.sweep(nominal, args.sweep_postures, args.sweep_samples, design, **timing)
    document = {'sweep': result}
    print(plans.sweep_table(result))
    if args.target_position_um is not None or args.target_orientation_deg is not None:
        best = plans.cheapest_meeting(result, args.target_position_um, args.target_orientation_deg)
        document['target'] = {
            'position_um': args.target_position_um,
            'orientation_deg': args.target_orientation_deg,
            'cheapest': best,
        }
        print(
            'no swept design meets the target'
            if best is None
            else f'cheapest design meeting the target: {best["postures"]} postures x '
            f'{best["pairs_per_posture"]} samples ({best["calibration_s"]:.1f} s)'
        )
    plot_path = args.plot or (
        f'{args.output.rsplit(".", 1)[0]}.png' if args.output else 'gsp_plan.png'
    )
    plot_sweep(plot_path, result)
    document['plot'] = plot_path
    print(f'plot: {plot_path}')
    return document


def main(argv=None):
    """Console script ``gsp_plan``."""
    args = parse_arguments(argv)
    try:
        nominal = load_geometry(args.geometry)
        design = design_from(args)
        limits = MotionLimits(args.max_leg_speed_mm_s / 1e3, args.max_leg_acceleration_mm_s2 / 1e3)
        timing = {
            'settle_s': args.settle_s,
            'sensor_rate_hz': args.sensor_rate_hz,
            'limits': limits,
        }
        if args.target_position_mm is not None or (
            not args.sweep and args.target_orientation_deg is not None
        ):
            result = plans.target_plan(
                nominal,
                args.target_position_mm,
                args.target_orientation_deg,
                design,
                args.target_postures,
                args.max_pairs_per_posture,
                **timing,
            )
            print(_target_text(result))
        elif args.sweep:
            result = _sweep_document(args, nominal, design, timing)
        else:
            effects = effect_plan_from(args)
            count, pairs = args.posture_count, args.pairs_per_posture
            result = plans.plan(nominal, count, pairs, design, effects=effects, **timing)
            print(_summary_text(result))
        document = {'inputs': _inputs(args, design, limits), **result}
    except (GeometryError, CalibrationError, IdentificationError, RuntimeError, OSError) as error:
        print(f'gsp_plan: error: {error}', file=sys.stderr)
        return 2
    if args.output:
        atomic_write_text(args.output, to_json(json_safe(document)))
        print(f'plan: {args.output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
