"""``gsp_compare``: the drift between two calibrations of a platform (or a calibration and a check)."""

import argparse
import sys

from gsp_calibrator.files.calibration_files import CalibrationFileError, load_calibration
from gsp_kinematics.fileio import write_json
from gsp_kinematics.upkeep import drift

EXIT_UNCHANGED = 0
EXIT_CHANGED = 1
EXIT_BAD_INPUT = 2
#: Parameters listed besides the significant ones: the largest |w|.
LARGEST = 5


def build_parser():
    parser = argparse.ArgumentParser(
        prog='gsp_compare', description=__doc__.split('\n\n')[0].split(': ', 1)[1]
    )
    parser.add_argument('first', help='the earlier run directory, result.json or check.json')
    parser.add_argument('second', help='the later one')
    parser.add_argument(
        '--level',
        type=float,
        default=drift.DEFAULT_LEVEL,
        help='family-wise significance level (default %(default)s)',
    )
    parser.add_argument('--json', metavar='FILE', help='write the whole comparison as JSON')
    return parser


def _effect_text(effect):
    position, orientation = effect['position_mm'], effect['orientation_deg']
    return (
        f'{position["mean"]:.4f} / {position["p95"]:.4f} / {position["max"]:.4f} mm, '
        f'{orientation["mean"]:.5f} / {orientation["p95"]:.5f} / {orientation["max"]:.5f} deg'
    )


def format_comparison(data):
    """The comparison as text: the global test, the significant changes, the largest |w|, the
    effect on the pose (mean / p95 / max over the workspace)."""
    test = data['global_test']
    lines = [
        f'drift from {data["first"]} to {data["second"]}',
        f'  {len(data["parameters"])} parameters in common; level {data["level"]:g} '
        f'(family-wise); {data["test"]}',
        f'  global test: chi2 {test["statistic"]:.1f} on {test["dof"]} dof, '
        f'p = {test["p_value"]:.3g}: {"CHANGED" if test["changed"] else "no significant change"}',
    ]
    for entry in data['significant']:
        lines.append(
            f'  significant: {entry["parameter"]} {entry["change_report"]:+.4f} '
            f'+- {entry["sigma_report"]:.4f} {entry["unit"]} (w = {entry["w"]:.1f})'
        )
    ranked = sorted(data['parameters'].items(), key=lambda item: -abs(item[1]['w']))
    lines.append('  largest |w| (change +- marginal 1 sigma):')
    for name, entry in ranked[:LARGEST]:
        lines.append(
            f'    {name:7s} {entry["change_report"]:+.4f} +- {entry["sigma_report"]:.4f} '
            f'{entry["unit"]}  z = {entry["z"]:+.2f}  w = {entry["w"]:+.2f}'
        )
    effect = data.get('effect') or {}
    if 'all' in effect:
        lines.append(
            f'  effect on the pose over {effect["all"]["postures"]} postures (mean / p95 / max):'
        )
        lines.append(f'    whole change:        {_effect_text(effect["all"])}')
        lines.append(
            '    its uncertainty:     '
            f'{effect["all"]["uncertainty_position_mm_mean"]:.4f} mm, '
            f'{effect["all"]["uncertainty_orientation_deg_mean"]:.5f} deg (mean, 1 sigma)'
        )
        if 'significant' in effect:
            lines.append(f'    significant changes: {_effect_text(effect["significant"])}')
    return '\n'.join(lines)


def main(argv=None):
    arguments = build_parser().parse_args(argv)
    if not 0.0 < arguments.level < 1.0:
        print(f'gsp_compare: --level must be in (0, 1), got {arguments.level}', file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        first = load_calibration(arguments.first)
        second = load_calibration(arguments.second)
        data = drift.compare(first, second, arguments.level)
    except (CalibrationFileError, ValueError) as error:
        print(f'gsp_compare: {error}', file=sys.stderr)
        return EXIT_BAD_INPUT
    print(format_comparison(data))
    if arguments.json:
        write_json(arguments.json, data)
    return EXIT_CHANGED if data['significant'] or data['global_test']['changed'] else EXIT_UNCHANGED


if __name__ == '__main__':
    sys.exit(main())
