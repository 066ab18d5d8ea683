"""The rigid geometry of a calibration that identified effects (pure): for a controller that
runs the geometry alone, the identified effects folded into the 44 parameters
(:func:`gsp_kinematics.effects.rigid_fold.fold_effects`), written to ``result_rigid.yaml`` and
applied instead of ``result.yaml`` to such a controller (:mod:`gsp_calibrator.result_delivery`),
with its predicted accuracy beside the compensated one (docs/platform_effects.md)."""

import numpy as np

from gsp_calibrator.run.directory import RIGID_RESULT_FILE
from gsp_kinematics.effects.rigid_fold import fold_effects, rigid_accuracy


def rigid_result(outcome):
    """``(rigid Geometry, record)`` of a successful ``run.identify.CalibrationOutcome`` whose
    geometry carries identified effects, else ``(None, None)``. The record (the ``rigid`` entry
    of ``result.json``'s ``effects``): the predicted accuracy of a rigid controller running it
    (:func:`rigid_accuracy`, the compensated prediction's mean as its random part), the file,
    and the groups such a controller does not compensate."""
    geometry = outcome.geometry
    if not outcome.success or geometry is None or geometry.effects.none:
        return None, None
    try:
        rigid = fold_effects(geometry)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as error:
        # No workspace posture of this geometry (its limits), or a singular fit: the rigid
        # controller then gets the geometry without its effects (result_delivery).
        return None, {'file': None, 'failure': f'no rigid geometry: {error}'}
    random = ((outcome.prediction or {}).get('random') or {}).get('position_mm') or {}
    compensated = float(random.get('mean', 0.0))
    record = {
        'file': RIGID_RESULT_FILE,
        'predicted': rigid_accuracy(geometry, rigid, compensated),
        'compensated_predicted_position_mm': compensated if random else None,
        'not_compensated': geometry.effects.groups(),
    }
    return rigid, record
