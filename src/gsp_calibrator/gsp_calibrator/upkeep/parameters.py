"""The calibrator parameters of keeping a platform calibrated (docs/upkeep.md): appended to the
calibrator's table (``settings.PARAMETERS``)."""

import re

from gsp_msgs_py.parameter_specs import ParameterSpec

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
)
