"""gsp_calibrator: the calibrator node, its collection protocol, run data, replay, upkeep and user tools (see docs/architecture.md)."""

import os

# The identification's matrices are 6 x 6 to 44 x 44: a BLAS thread per core only spins, and
# on a loaded machine costs CPU the nodes need. numpy reads these when it loads, and every
# console script of this package imports it here first; a count the user set stays.
for _name in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_name, '1')
