"""``gsp_history``: the history of a platform's calibrations and checks (docs/upkeep.md)."""

import argparse
import sys
from pathlib import Path

from gsp_calibrator.files import history
from gsp_calibrator.files.calibration_files import CalibrationFileError

EXIT_OK = 0
EXIT_BAD_INPUT = 2


def build_parser():
    parser = argparse.ArgumentParser(prog='gsp_history', description=__doc__.split('\n\n')[0])
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        '--database', help='the history file (default: <root>/history.sqlite)', default=None
    )
    common.add_argument('--root', default='runs', help='the runs folder (default %(default)s)')
    commands = parser.add_subparsers(dest='command', required=True)

    def add_parser(name, **options):
        return commands.add_parser(name, parents=[common], **options)

    listing = add_parser('list', help='the runs, oldest first')
    listing.add_argument('--platform', help='only this platform')
    listing.add_argument('--kind', choices=history.KINDS, help='only calibrations or checks')
    add_parser('platforms', help='the platform ids and their number of runs')
    add = add_parser('add', help='index one run directory')
    add.add_argument('run_dir')
    add.add_argument('--platform', help="default: the run's platform_id, else 'default'")
    rebuild = add_parser('rebuild', help='index every run directory under --root')
    rebuild.add_argument('--platform', help="default: each run's platform_id")
    plot = add_parser('plot', help='accuracy and the parameters that moved, over time')
    plot.add_argument('--platform', default=history.DEFAULT_PLATFORM)
    plot.add_argument('--output', default='history.png')
    plot.add_argument('--required-mm', type=float, help='draw the required accuracy')
    return parser


def _number(value, digits):
    return '-' if value is None else f'{value:.{digits}f}'


def format_runs(found):
    """One line per run: time, platform, kind, verdict, accuracy and its source, the changes."""
    lines = ['time (UTC)                 platform    kind         verdict          mm       deg']
    for entry in found:
        changes = ', '.join(
            f'{c["parameter"]} {c["change_report"]:+.4f} {c["unit"]}' for c in entry['changes']
        )
        lines.append(
            f'{entry["time_utc"][:25]:26s} {entry["platform"][:11]:11s} {entry["kind"]:12s} '
            f'{(entry["verdict"] or "-")[:15]:15s} {_number(entry["position_mm"], 4):>8s} '
            f'{_number(entry["orientation_deg"], 5):>9s} ({entry["accuracy_source"] or "-"})'
            + (f'  moved: {changes}' if changes else '')
        )
        lines.append(f'    {entry["run_dir"]}')
    return '\n'.join(lines)


def _run(arguments, path):
    if arguments.command == 'add':
        run_id = history.record(path, arguments.run_dir, arguments.platform)
        print(format_runs([entry for entry in history.runs(path) if entry['id'] == run_id]))
    elif arguments.command == 'rebuild':
        indexed, skipped = history.rebuild(path, arguments.root, arguments.platform)
        print(f'indexed {len(indexed)} run directories into {path}')
        for run_dir, reason in skipped:
            print(f'  skipped {run_dir}: {reason}')
    elif arguments.command == 'platforms':
        for platform, count in history.platforms(path):
            print(f'{platform}: {count} runs')
    elif arguments.command == 'plot':
        from gsp_calibrator.upkeep.history_plot import plot_history

        print(plot_history(path, arguments.platform, arguments.output, arguments.required_mm))
    else:
        print(format_runs(history.runs(path, arguments.platform, arguments.kind)))


def main(argv=None):
    arguments = build_parser().parse_args(argv)
    path = Path(arguments.database or history.database_path(arguments.root))
    if arguments.command in ('list', 'platforms', 'plot') and not path.exists():
        print(f'gsp_history: no history at {path}', file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        _run(arguments, path)
    except (history.HistoryError, CalibrationFileError, ValueError) as error:
        print(f'gsp_history: {error}', file=sys.stderr)
        return EXIT_BAD_INPUT
    return EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
