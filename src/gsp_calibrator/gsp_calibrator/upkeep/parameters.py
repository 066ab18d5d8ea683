"""The calibrator parameters of keeping a platform calibrated (docs/upkeep.md): appended to the
calibrator's table (``settings.PARAMETERS``)."""

import math
import re

from gsp_msgs_py.parameter_specs import ParameterSpec, at_least

#: A platform id: letters, digits, '-', '_', '.' (it names the platform in the history).
_PLATFORM_ID = re.compile(r'^[A-Za-z0-9_.-]{1,64}$')

UPKEEP_PARAMETERS = (
    ParameterSpec(
        'platform_id',
        'default',
        'Which platform this calibrator calibrates and checks: every calibration and check is '
        'indexed under it in <output_root>/history.sqlite (gsp_history), and a check checks its '
        'latest accepted calibration',
        constraints="1-64 of letters, digits, '-', '_', '.'",
        check=lambda v: '' if _PLATFORM_ID.match(str(v)) else 'must be 1-64 of [A-Za-z0-9_.-]',
        subsets=frozenset(('stored',)),  # settings.STORED (settings imports this table)
    ),
    ParameterSpec(
        'check_geometry_file',
        '',
        'The geometry /gsp/calibrator/check checks (a result.yaml; its run directory gives the '
        "covariance and noise); empty: platform_id's latest accepted calibration under "
        'output_root',
    ),
    ParameterSpec(
        'stop_when_accurate',
        False,
        'A calibration stops as soon as its cross-validated accuracy meets the required '
        'accuracy (required_position_accuracy_mm, required_orientation_accuracy_deg) with '
        'stop_confidence; if the planned postures are not enough, it adds pool postures by '
        'information per second of travel (docs/upkeep.md)',
        subsets=frozenset(('stored',)),
    ),
    ParameterSpec(
        'stop_confidence',
        0.95,
        'With stop_when_accurate: the one-sided confidence of the bound on the cross-validated '
        'mean position error that must meet the requirement',
        constraints='0.5 <= c < 1',
        check=lambda v: (
            ''
            if isinstance(v, float) and 0.5 <= v < 1 and math.isfinite(v)
            else 'must be in [0.5, 1)'
        ),
        subsets=frozenset(('stored',)),
    ),
    ParameterSpec(
        'stop_minimum_postures',
        30,
        'With stop_when_accurate: the rows are first judged after this many postures (fewer '
        'give an optimistic cross-validation on a real platform: docs/upkeep.md)',
        constraints='>= 2',
        check=at_least(2),
        subsets=frozenset(('stored',)),
    ),
    ParameterSpec(
        'stop_every',
        2,
        'With stop_when_accurate: postures between two judgements (each identifies and '
        'cross-validates the rows so far in a worker thread while the next posture is collected)',
        constraints='>= 1',
        check=at_least(1),
        subsets=frozenset(('stored',)),
    ),
    ParameterSpec(
        'stop_max_added',
        60,
        'With stop_when_accurate: pool postures added at most after the planned ones',
        constraints='>= 0',
        check=at_least(0),
        subsets=frozenset(('stored',)),
    ),
    ParameterSpec(
        'reuse_rows_from',
        '',
        "A run directory (a check's, or another run's) whose samples.csv rows a new calibration "
        'identifies with its own (rows of the same platform and device); empty: none',
    ),
)
