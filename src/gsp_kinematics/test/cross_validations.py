"""Hand-set cross-validations for the core's tests (no identification behind them)."""

import numpy as np

from gsp_kinematics.estimation.verdict.cross_validation import CrossValidation


def validation_of(position, folds, **corrections):
    """A CrossValidation of position errors ``position`` (M, 3) m, no phi error or noise, the
    nominal geometry 10 times worse; ``corrections``: e.g. its position_unseen."""
    count = len(position)
    return CrossValidation(
        folds=folds,
        fold_of_posture=np.arange(count) % folds,
        position_error=position,
        phi_error=np.zeros(count),
        position_noise=np.zeros(count),
        phi_noise=np.zeros(count),
        nominal_position_error=10 * position,
        nominal_phi_error=np.zeros(count),
        failed_folds=(),
        duration_s=0.0,
        **corrections,
    )
