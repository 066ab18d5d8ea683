"""The rigid geometry of a calibration that identified effects, for a controller that runs the
geometry alone: the effects folded in, with its accuracy and verdict (pure;
docs/platform_effects.md, docs/verdict.md)."""

import dataclasses

import numpy as np

from gsp_calibrator.files.run_directory import RIGID_RESULT_FILE
from gsp_kinematics.estimation.rigid_fold import (
    fold_effects,
    held_out_postures,
    linearised_model_errors,
    rigid_accuracy,
)
from gsp_kinematics.estimation.verdict import acceptance
from gsp_kinematics.estimation.verdict.rigid_held_out import rigid_held_out

#: Prefixed to the rigid geometry's verdict lines.
RIGID_VERDICT_PREFIX = 'rigid controller (result_rigid.yaml): '


@dataclasses.dataclass(frozen=True)
class Verdicts:
    """The compensating geometry's and the rigid one's ``acceptance.Verdict`` (``rigid`` None:
    the compensating verdict stands for both), for the delivery to pick from."""

    compensating: object
    rigid: object = None

    def of(self, compensates):
        """``(Verdict, which)`` of what a controller that ``compensates`` (or not) runs."""
        if compensates or self.rigid is None:
            return self.compensating, 'compensating'
        return self.rigid, 'rigid'

    @property
    def any_accepted(self):
        """Some controller would get an accepted geometry."""
        return any(v is not None and v.accepted for v in (self.compensating, self.rigid))


def rigid_result(outcome):
    """``(rigid Geometry, record)`` of a successful ``CalibrationOutcome`` whose geometry has
    identified effects, else ``(None, None)``; the record: ``result.json``'s ``effects.rigid``.
    Fills the outcome's ``rigid_accuracy`` and ``rigid_judgement`` (:func:`judge_rigid`)."""
    geometry = outcome.geometry
    if not outcome.success or geometry is None or geometry.effects.none:
        return None, None
    try:
        rigid = fold_effects(geometry)
        poses = held_out_postures(geometry)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as error:
        # No workspace posture of this geometry (its limits), or a singular fit: the rigid
        # controller then gets the geometry without its effects (result_delivery).
        return None, {'file': None, 'failure': f'no rigid geometry: {error}'}
    systematic = linearised_model_errors(geometry, rigid, poses)
    random = ((outcome.prediction or {}).get('random') or {}).get('position_mm') or {}
    compensated = float(random.get('mean', 0.0))
    record = {
        'file': RIGID_RESULT_FILE,
        'predicted': rigid_accuracy(geometry, rigid, compensated, poses, systematic[0]),
        'compensated_predicted_position_mm': compensated if random else None,
        'not_compensated': geometry.effects.groups(),
    }
    judge_rigid(outcome, systematic, record['predicted'])
    return rigid, record


def judge_rigid(outcome, systematic, predicted):
    """The rigid geometry's held-out accuracy (the compensating one's with its ``systematic``
    ``(position mm, phi deg)`` errors) and its verdict against the same requirement."""
    if not outcome.accuracy or outcome.requirement is None:
        return
    outcome.rigid_accuracy = rigid_held_out(outcome.accuracy, *systematic)
    headline = {'position_mm_mean': predicted['position_mm']['mean']}
    verdict = acceptance.judge(
        outcome.rigid_accuracy, outcome.requirement, outcome.unmodelled, headline
    )
    lines = (RIGID_VERDICT_PREFIX + verdict.lines[0],) + verdict.lines[1:2]
    outcome.rigid_judgement = dataclasses.replace(verdict, lines=lines)
