"""The ``upkeep`` section of ``make bench`` (docs/upkeep.md): the one-minute check and the drift
between calibrations, on the benches' pure simulation path (:mod:`.bench_sensor_errors`: the
shipped real platform with its sensor errors, the calibrator's 60 postures and 10 samples,
Table 3's first noise level, the ``extended`` parameters).

A seed is a pair of runs of one platform (two calibrations, or a calibration and a check), either
unchanged or with a 20 um change of one leg offset of its truth between them.
"""

import dataclasses

import numpy as np

from gsp_kinematics import drift
from gsp_kinematics.geometry import PARAMETER_INDEX, Geometry

from .bench_sensor_errors import calibrator_design, collect, fit

#: The calibrator's default free parameters.
FREE = 'extended'
#: The size of the change the figures detect (m).
CHANGE_M = 20e-6


def changed_truth(true, name, delta):
    """``true`` with parameter ``name`` moved by ``delta`` (SI)."""
    vector = true.to_full_vector()
    vector[PARAMETER_INDEX[name]] += delta
    return Geometry.from_full_vector(vector, true.limits)


@dataclasses.dataclass(frozen=True)
class UpkeepDesign:
    """The shipped platform, its nominal controller and the calibrator's selected postures."""

    true: object
    nominal: object
    pool: np.ndarray
    poses: np.ndarray  #: the 60 selected postures

    @classmethod
    def default(cls):
        true, nominal, pool, chosen, _ = calibrator_design()
        return cls(true, nominal, pool, pool[chosen])

    def identify(self, true, seed):
        """The ``IdentificationResult`` of a simulated calibration of the platform ``true``
        (noise by ``seed``)."""
        legs, readings, _, commanded = collect(true, self.nominal, self.poses, seed)
        result = fit(self.nominal, legs, readings, commanded, FREE)
        if not result.converged:
            raise RuntimeError(f'the simulated calibration of seed {seed} did not converge')
        return result

    def calibrate(self, true, seed):
        """:meth:`identify` as a ``drift.Calibration``."""
        return drift.Calibration.from_result(self.identify(true, seed), label=f'seed {seed}')
