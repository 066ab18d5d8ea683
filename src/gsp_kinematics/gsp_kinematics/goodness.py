"""Does the model explain the data? Robust weights, outliers, noise estimates and the chi-square
goodness of fit of an identification (docs/sensor_errors.md says how to read the verdict).

Everything works on *normalised* residuals ``z = (measured - model) / sigma``: under the model and
the configured sigmas, each is a standard normal variable.
"""

import dataclasses
import math

import numpy as np
from scipy import special

#: Robust losses (cf. ``scipy.optimize.least_squares(loss=...)``).
LOSSES = ('linear', 'huber', 'cauchy')
#: A posture whose largest |z| exceeds this is reported as an outlier.
DEFAULT_OUTLIER_THRESHOLD = 5.0
#: p-value below which the model is rejected.
DEFAULT_SIGNIFICANCE = 0.01
#: Estimated / configured noise ratio beyond which (or below its inverse) a warning is given.
NOISE_WARNING_RATIO = 2.0


def robust_weights(normalised, loss, scale):
    """IRLS weights ``rho'(z^2)`` of each residual for ``loss`` with ``scale`` in sigmas.

    ``linear``: 1; ``huber``: ``min(1, scale / |z|)``; ``cauchy``: ``1 / (1 + (z / scale)^2)``.
    NaN residuals (postures left out) get weight 1.
    """
    z = np.abs(np.nan_to_num(np.asarray(normalised, dtype=float), nan=0.0)) / scale
    if loss == 'linear':
        return np.ones_like(z)
    if loss == 'huber':
        return np.minimum(1.0, 1.0 / np.maximum(z, 1e-300))
    if loss == 'cauchy':
        return 1.0 / (1.0 + z**2)
    raise ValueError(f'loss must be one of {LOSSES}, got {loss!r}')


def check_loss(loss, scale):
    if loss not in LOSSES:
        raise ValueError(f'loss must be one of {LOSSES}, got {loss!r}')
    if not (math.isfinite(scale) and scale > 0.0):
        raise ValueError(f'loss scale must be positive and finite (sigmas), got {scale}')


@dataclasses.dataclass(frozen=True)
class GoodnessOfFit:
    """Chi-square of the normalised residuals against its degrees of freedom."""

    chi2: float
    dof: int
    p_value: float
    excluded_postures: tuple = ()  #: outliers left out of the chi-square (robust fits only)

    @property
    def accepted(self):
        return self.dof > 0 and self.p_value >= DEFAULT_SIGNIFICANCE

    def as_dict(self):
        return {'chi2': self.chi2, 'dof': self.dof, 'p_value': self.p_value}


def goodness_of_fit(normalised, unknowns, excluded=()):
    """:class:`GoodnessOfFit` of residuals (M, k) (NaN rows: postures not used) with ``unknowns``
    estimated (free parameters, and the poses in the implicit formulation, 6 a posture used).

    ``excluded``: postures left out (outliers named by a robust fit); ``unknowns`` must already
    count only the postures kept."""
    normalised = np.array(normalised, dtype=float)
    if len(excluded):
        normalised[list(excluded)] = np.nan
    finite = np.isfinite(normalised)
    chi2 = float(np.sum(normalised[finite] ** 2))
    dof = int(np.count_nonzero(finite)) - int(unknowns)
    # chdtrc is scipy.stats.chi2.sf without the distribution machinery's overhead.
    p_value = float(special.chdtrc(dof, chi2)) if dof > 0 else math.nan
    return GoodnessOfFit(chi2, dof, p_value, tuple(int(m) for m in excluded))


def outlier_postures(normalised, threshold=DEFAULT_OUTLIER_THRESHOLD, columns=None):
    """Postures whose largest |z| exceeds ``threshold``, worst first:
    ``[{'posture', 'max_normalised_residual', 'sensor'}]``; ``columns`` names the residual columns."""
    normalised = np.abs(np.nan_to_num(np.asarray(normalised, dtype=float), nan=0.0))
    worst = normalised.max(axis=1) if normalised.size else np.zeros(0)
    report = []
    for m in np.argsort(-worst):
        if worst[m] <= threshold:
            break
        column = int(np.argmax(normalised[m]))
        report.append(
            {
                'posture': int(m),
                'max_normalised_residual': float(worst[m]),
                'sensor': columns[column] if columns else column,
            }
        )
    return report


def down_weighted_postures(weights, below=0.999):
    """``[{'posture', 'weight'}]``: postures whose smallest residual weight is below ``below``."""
    weights = np.asarray(weights, dtype=float)
    smallest = weights.min(axis=1) if weights.size else np.zeros(0)
    return [
        {'posture': int(m), 'weight': float(smallest[m])}
        for m in np.argsort(smallest)
        if smallest[m] < below
    ]


#: Channels of the noise estimate -> (columns of the leg/readings std table (M, 10)).
NOISE_CHANNELS = {
    'leg_lengths': slice(0, 6),
    'inclinometer': slice(6, 8),
    'encoder': slice(8, 9),
    'lvdt': slice(9, 10),
}


def estimate_noise(sample_std, n_samples, configured):
    """Per-sample noise of each sensor from the scatter within each posture.

    ``sample_std`` (M, 10): per posture, the sample standard deviation (ddof 1) of the 6 legs and
    the 4 readings over its ``n_samples`` (M,) samples; ``configured``: ``{channel: sigma}``.
    The pooled estimate ``sqrt(sum (n-1) s^2 / sum (n-1))`` is unbiased in the variance.
    Returns ``{channel: {'configured', 'estimated', 'ratio', 'warning'}}`` (only channels with
    data; ``warning`` when the ratio is beyond :data:`NOISE_WARNING_RATIO` either way).
    """
    sample_std = np.asarray(sample_std, dtype=float).reshape(-1, 10)
    degrees = np.clip(np.asarray(n_samples, dtype=float).reshape(-1) - 1.0, 0.0, None)
    estimates = {}
    for channel, columns in NOISE_CHANNELS.items():
        values = sample_std[:, columns]
        usable = np.all(np.isfinite(values), axis=1) & (degrees > 0)
        if not usable.any():
            continue
        variance = np.sum(degrees[usable, None] * values[usable] ** 2) / (
            np.sum(degrees[usable]) * values.shape[1]
        )
        estimated = math.sqrt(variance)
        sigma = float(configured[channel])
        ratio = estimated / sigma if sigma > 0 else math.inf
        estimates[channel] = {
            'configured': sigma,
            'estimated': estimated,
            'ratio': ratio,
            'warning': not (1.0 / NOISE_WARNING_RATIO <= ratio <= NOISE_WARNING_RATIO),
        }
    return estimates


def verdict(fit, outliers=(), noise=None, free_sensor_errors=False):
    """Plain text: does the model explain the data, and if not, the likely causes."""
    if fit.dof <= 0:
        return (
            'goodness of fit: not assessable (no degrees of freedom left: add postures or fix '
            'parameters)'
        )
    head = f'goodness of fit: chi2 {fit.chi2:.1f} for {fit.dof} dof, p = {fit.p_value:.3g}'
    if fit.accepted:
        return head + ': the model explains the data within the configured noise'
    causes = []
    ratio = fit.chi2 / fit.dof
    if outliers:
        causes.append(
            'outlier postures '
            + ', '.join(str(entry['posture']) for entry in outliers[:10])
            + ' (try loss: huber, or check those postures)'
        )
    if noise and any(entry['warning'] for entry in noise.values()):
        names = [name for name, entry in noise.items() if entry['warning']]
        causes.append(f'wrong sigmas: the estimated noise of {", ".join(names)} differs > 2x')
    if ratio > 1.0:
        causes.append(
            'residuals larger than the noise: an unmodelled error'
            + ('' if free_sensor_errors else ' (try free_parameters: extended)')
            + ' or sigmas set too small'
        )
    else:
        causes.append('residuals smaller than the noise: sigmas set too large')
    return f'{head} < {DEFAULT_SIGNIFICANCE}: the model does NOT explain the data. Likely: ' + (
        '; '.join(causes)
    )
