"""``gsp_paper``: the command line of the paper reproduction (:mod:`.paper`), its printed report
and the Figs. 6-8 plots."""

import itertools
import os
import sys
from pathlib import Path

import numpy as np

from gsp_kinematics.estimation.identification import FORMULATIONS
from gsp_kinematics.fileio import write_json

from . import paper
from .cli import experiment_parser, reexec_with_single_threaded_blas
from .paper import NOISE_FORMULATIONS, PaperConfig, run
from .tables import load_tables, table3


def plot_parameter_errors(row, path):
    """Figs. 6-8 style: initial errors as dots, final as crosses, one column per parameter."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    names = [entry['name'] for entry in row['parameters']]
    initial = np.array([entry['initial_error'] for entry in row['parameters']])
    final = np.array([entry['final_error'] for entry in row['parameters']])
    positions = np.arange(len(names))
    figure, axes = plt.subplots(figsize=(13, 4.5), constrained_layout=True)
    axes.axhline(0.0, color='0.4', linewidth=0.8)
    axes.plot(
        positions, initial, 'o', markersize=4, color='tab:blue', label='initial error (nominal set)'
    )
    axes.plot(
        positions, final, 'x', markersize=7, color='tab:red', label='final error (identified)'
    )
    axes.set_xticks(positions, names, rotation=90, fontsize=8)
    axes.set_xlim(-0.7, len(names) - 0.3)
    axes.set_xlabel('identification parameter')
    axes.set_ylabel('error (mm; deg for gamma)')
    axes.set_title(
        f'Errors in individual parameters (nominal set {row["set"]}): '
        f'max final error {row["max_param_error_mm"]:.1e} mm, {row["max_param_error_deg"]:.1e} deg'
    )
    axes.grid(axis='y', alpha=0.3)
    axes.legend(loc='upper right')
    figure.savefig(path, dpi=110)
    plt.close(figure)


def format_report(document):
    lines = []
    for row in document['noise_free']:
        lines.append(
            f'\nNominal set {row["set"]} (noise-free, {row["formulation"]}, condition {row["condition_number"]:.1f}, '
            f'{row["iterations"]} iterations, {row["message"]})'
        )
        lines.append(
            f'  {"param":>6} {"initial":>10} {"final":>10}    {"param":>6} {"initial":>10} {"final":>10}'
        )
        entries = row['parameters']
        half = (len(entries) + 1) // 2
        for left, right in itertools.zip_longest(entries[:half], entries[half:]):
            text = (
                f'  {left["name"]:>6} {left["initial_error"]:>10.4f} {left["final_error"]:>10.1e}'
            )
            if right:
                text += f'    {right["name"]:>6} {right["initial_error"]:>10.4f} {right["final_error"]:>10.1e}'
            lines.append(text)
        lines.append(
            f'  max |final error|: {row["max_param_error_mm"]:.2e} mm, gamma {row["max_param_error_deg"]:.2e} deg '
            f'(converged: {row["converged"]})'
        )
    initial = document['initial']
    lines.append(
        '\nTable 3: mean errors over the validation postures (position mm / orientation deg)'
    )
    lines.append(
        f'  initial (nominal set {initial["nominal_set"]}): {initial["position_mm"]:.4f} / {initial["orientation_deg"]:.4f}'
        f'   paper: {initial["paper_position_mm"]:.4f} / {initial["paper_orientation_deg"]:.4f}'
    )
    header = f'  {"noise deg":>9} {"noise mm":>8} {"formulation":>11} {"seeds":>5} {"position":>9} {"CR":>9} {"paper":>8} {"ratio":>6}   {"orient.":>8} {"CR":>8} {"paper":>8} {"ratio":>6}'
    if initial.get('unreachable_validation_postures'):
        lines.append(
            f'  ({initial["unreachable_validation_postures"]} of {initial["validation_postures"]} validation postures '
            'cannot be assembled by the real platform under the nominal controller: left out)'
        )
    lines.append(header)
    for row in document['noise']:
        lines.append(
            f'  {row["angle_noise_deg"]:>9.3f} {row["length_noise_mm"]:>8.3f} {row["formulation"]:>11} {row["seeds"]:>5} '
            f'{row["position_mm"]:>9.5f} {row["cramer_rao_position_mm"]:>9.5f} {row["paper_position_mm"]:>8.4f} {row["position_ratio_to_paper"]:>6.2f}   '
            f'{row["orientation_deg"]:>8.5f} {row["cramer_rao_orientation_deg"]:>8.5f} {row["paper_orientation_deg"]:>8.4f} {row["orientation_ratio_to_paper"]:>6.2f}'
        )
    return '\n'.join(lines)


def build_parser():
    """The command line of ``gsp_paper`` (a flat table of options)."""
    parser = experiment_parser(
        'gsp_paper', paper.__doc__, 'results/paper.json', 'smaller pool and 3 seeds (a smoke run)'
    )
    parser.add_argument(
        '--seeds', type=int, default=20, help='noise draws per Table 3 level (default 20)'
    )
    parser.add_argument(
        '--plot-dir', default='results', help='where the Figs. 6-8 PNGs go (default results)'
    )
    parser.add_argument('--no-plots', action='store_true', help='skip the PNGs')
    parser.add_argument(
        '--select-once',
        action='store_true',
        help='one posture selection (default sigmas) for every noise level instead of one per level',
    )
    parser.add_argument(
        '--jobs', type=int, default=min(2, os.cpu_count() or 1), help='worker processes (default 2)'
    )
    parser.add_argument(
        '--pool', type=int, default=None, help='random valid postures to select from (default 600)'
    )
    parser.add_argument('--seed', type=int, default=0, help='base random seed')
    parser.add_argument(
        '--skip-matched',
        action='store_true',
        help='skip the search for a platform matching the paper (paper_matched)',
    )
    parser.add_argument(
        '--matched-evaluations',
        type=int,
        default=120,
        help='paper_matched: evaluations per search start (default 120)',
    )
    parser.add_argument(
        '--sets', default='1,2,3', help='nominal sets of the noise-free study (default 1,2,3)'
    )
    parser.add_argument(
        '--tables',
        default=None,
        help="the paper's tables.yaml (default: the copy shipped in gsp_bench)",
    )
    parser.add_argument(
        '--formulations',
        default=','.join(NOISE_FORMULATIONS),
        help=f'comma-separated formulations for the noise study (of {", ".join(FORMULATIONS)})',
    )
    return parser


def main(argv=None):
    if argv is None:
        reexec_with_single_threaded_blas()
    parser = build_parser()
    args = parser.parse_args(argv)
    formulations = tuple(name.strip() for name in args.formulations.split(',') if name.strip())
    unknown = [name for name in formulations if name not in FORMULATIONS]
    if unknown or not formulations:
        parser.error(f'unknown formulation(s) {unknown}; expected some of {FORMULATIONS}')
    if args.seeds < 1:
        parser.error('--seeds must be at least 1')
    try:
        sets = tuple(sorted({int(item) for item in args.sets.split(',') if item.strip()}))
    except ValueError:
        sets = ()
    if not sets or not set(sets) <= {1, 2, 3}:
        parser.error(f'--sets must list nominal sets among 1, 2, 3 (got {args.sets!r})')
    seeds = min(args.seeds, 3) if args.quick and args.seeds == 20 else args.seeds
    pool = args.pool or (250 if args.quick else 600)
    config = PaperConfig(
        seeds=seeds,
        pool_size=pool,
        sets=sets,
        formulations=formulations,
        select_per_level=not args.select_once,
        seed=args.seed,
        jobs=max(1, args.jobs),
    )
    tables, source = load_tables(args.tables)
    print(f'gsp_paper: tables from {source}', flush=True)
    document = run(config, tables=tables, log=lambda text: print(text, flush=True))
    document['tables_source'] = source
    if not args.skip_matched:
        from . import paper_matched

        def rerun_table3(exact):
            """Table 3 on the matched candidate ``exact``: nominal set 1 only."""
            return run(
                PaperConfig(
                    seeds=config.seeds,
                    pool_size=config.pool_size,
                    postures=config.postures,
                    validation_postures=config.validation_postures,
                    sets=(1,),
                    formulations=config.formulations,
                    select_per_level=config.select_per_level,
                    seed=config.seed,
                    jobs=config.jobs,
                ),
                tables=tables,
                log=lambda text: print(text, flush=True),
                exact=exact,
            )

        document['paper_matched'] = paper_matched.run(
            config,
            rerun_table3,
            table3(tables)[0],
            log=lambda text: print(text, flush=True),
            max_evaluations=max(1, args.matched_evaluations),
        )
    if not args.no_plots:
        plot_dir = Path(args.plot_dir)
        plot_dir.mkdir(parents=True, exist_ok=True)
        document['plots'] = []
        for row in document['noise_free']:
            path = plot_dir / f'paper_fig{5 + row["set"]}_set{row["set"]}_parameter_errors.png'
            plot_parameter_errors(row, path)
            document['plots'].append(str(path))
    write_json(args.output, document)
    print(format_report(document))
    print(
        f'\nwrote {args.output} in {document["duration_s"]:.1f} s'
        + (f'; plots: {", ".join(document["plots"])}' if document.get('plots') else '')
    )
    return 0 if all(row['converged'] for row in document['noise_free']) else 1


if __name__ == '__main__':
    sys.exit(main())
