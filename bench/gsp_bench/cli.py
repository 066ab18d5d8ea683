"""What the experiments' console scripts share: one BLAS thread, and the common options."""

import argparse
import os
import sys

_BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


def reexec_with_single_threaded_blas():
    """Re-run this very command line with one BLAS thread, unless a thread count is set.

    The core's matrices are small (at most 44 x 44, or batches of 6 x 6): threaded BLAS only adds
    overhead, and on a loaded two-core machine its spinning threads make timings erratic. numpy
    reads the setting when it loads, hence a fresh process (``sys.orig_argv``: the console script
    or ``python -m module`` that started it). Set ``OPENBLAS_NUM_THREADS`` to opt out.
    """
    if any(name in os.environ for name in _BLAS_THREAD_VARIABLES):
        return
    environment = dict(os.environ, **{name: '1' for name in _BLAS_THREAD_VARIABLES})
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], environment)


def experiment_parser(prog, doc, output, quick_help):
    """An argument parser with the options every experiment has: ``--output`` and ``--quick``.

    ``doc``: the module docstring (its first paragraph is the description); ``output``: the
    default JSON path.
    """
    parser = argparse.ArgumentParser(prog=prog, description=doc.split('\n\n')[0])
    parser.add_argument('--output', default=output, help=f'JSON output (default {output})')
    parser.add_argument('--quick', action='store_true', help=quick_help)
    return parser
