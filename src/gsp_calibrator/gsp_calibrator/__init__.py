"""gsp_calibrator: the calibrator node, its collection protocol, run data, replay, upkeep and user tools (see docs/architecture.md)."""

import os

# The matrices are at most 44 x 44: a BLAS thread per core only spins. numpy reads these when it
# loads, and this package's console scripts run this first; a count the user set stays.
for _name in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_name, '1')
