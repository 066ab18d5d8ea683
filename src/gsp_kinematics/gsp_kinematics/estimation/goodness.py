"""Does the model explain the data? Robust weights, studentised outliers, noise estimates and the
goodness of fit of an identification (docs/sensor_errors.md says how to read the verdict)."""

import dataclasses
import math

import numpy as np
from scipy import special

from gsp_kinematics import channels

#: Robust losses (cf. ``scipy.optimize.least_squares(loss=...)``).
LOSSES = ('linear', 'huber', 'cauchy')
#: Outlier threshold on the studentised residuals; None: Bonferroni at DEFAULT_SIGNIFICANCE over
#: all residuals (:func:`bonferroni_threshold`).
DEFAULT_OUTLIER_THRESHOLD = None
#: Redundancy number below which a residual is not judged (the fit follows it: nothing to see).
MIN_REDUNDANCY = 1e-3
#: Goodness-of-fit tests: sigmas given, sigmas estimated with a pure-error estimate, neither.
FIT_TESTS = ('chi2', 'lack_of_fit', 'none')
#: p-value below which the model is rejected.
DEFAULT_SIGNIFICANCE = 0.01
#: Estimated / configured noise ratio beyond which (or below its inverse) a warning is given.
NOISE_WARNING_RATIO = 2.0


def robust_weights(normalised, loss, scale):
    """IRLS weights ``rho'(z^2)`` of each residual for ``loss`` (``linear``: 1; ``huber``,
    ``cauchy``) with ``scale`` in sigmas; NaN residuals (postures left out) get weight 1."""
    z = np.abs(np.nan_to_num(np.asarray(normalised, dtype=float), nan=0.0)) / scale
    if loss == 'linear':
        return np.ones_like(z)
    if loss == 'huber':
        return np.minimum(1.0, 1.0 / np.maximum(z, 1e-300))
    if loss == 'cauchy':
        return 1.0 / (1.0 + z**2)
    raise ValueError(f'loss must be one of {LOSSES}, got {loss!r}')


def validate_loss(loss, scale):
    if loss not in LOSSES:
        raise ValueError(f'loss must be one of {LOSSES}, got {loss!r}')
    if not (math.isfinite(scale) and scale > 0.0):
        raise ValueError(f'loss scale must be positive and finite (sigmas), got {scale}')


@dataclasses.dataclass(frozen=True)
class GoodnessOfFit:
    """A goodness-of-fit test of the residuals (``test`` in :data:`FIT_TESTS`: ``chi2``,
    ``lack_of_fit`` (F with ``(dof, pure_error_dof)``) or ``none``; docs/sensor_errors.md)."""

    chi2: float
    dof: float
    p_value: float
    excluded_postures: tuple = ()  #: outliers left out of the chi-square (robust fits only)
    test: str = 'chi2'
    pure_error_dof: float = math.nan  #: within-posture degrees of freedom (lack_of_fit)

    @property
    def accepted(self):
        if self.test == 'none':
            return self.dof > 0
        return self.dof > 0 and self.p_value >= DEFAULT_SIGNIFICANCE

    @property
    def f_statistic(self):
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    def as_dict(self):
        record = {'test': self.test, 'chi2': self.chi2, 'dof': self.dof, 'p_value': self.p_value}
        if self.test == 'lack_of_fit':
            record.update(f_statistic=self.f_statistic, pure_error_dof=self.pure_error_dof)
        return record


def goodness_of_fit(normalised, unknowns, excluded=()):
    """:class:`GoodnessOfFit` of residuals (M, k) (NaN rows: postures not used) with ``unknowns``
    estimated (counting only the postures kept); ``excluded``: postures left out."""
    normalised = np.array(normalised, dtype=float)
    if len(excluded):
        normalised[list(excluded)] = np.nan
    finite = np.isfinite(normalised)
    chi2 = float(np.sum(normalised[finite] ** 2))
    dof = int(np.count_nonzero(finite)) - int(unknowns)
    # chdtrc is scipy.stats.chi2.sf without the distribution machinery's overhead.
    p_value = float(special.chdtrc(dof, chi2)) if dof > 0 else math.nan
    return GoodnessOfFit(chi2, dof, p_value, tuple(int(m) for m in excluded))


def lack_of_fit(between, redundancy, pure_error_dof, excluded=()):
    """Lack-of-fit F test: ``between`` (the sum of the squared residuals in units of the
    within-posture noise of the averaged rows) over its ``redundancy`` against an independent
    within-posture estimate with ``pure_error_dof`` degrees of freedom: F(redundancy, dof)."""
    statistic = between / redundancy if redundancy > 0 else math.nan
    # fdtrc is scipy.stats.f.sf without the distribution machinery's overhead.
    p_value = (
        float(special.fdtrc(redundancy, pure_error_dof, statistic)) if redundancy > 0 else math.nan
    )
    return GoodnessOfFit(
        float(between),
        float(redundancy),
        p_value,
        tuple(int(m) for m in excluded),
        'lack_of_fit',
        float(pure_error_dof),
    )


_SENSOR_OF_CHANNEL = {channel.name: channel.sensor for channel in channels.CHANNELS}


def channel_columns(columns):
    """``{channel: [column indices]}`` of the residual columns named ``columns``."""
    grouped = {}
    for index, name in enumerate(columns):
        grouped.setdefault(_SENSOR_OF_CHANNEL[name], []).append(index)
    return grouped


def variance_components(normalised, redundancy, columns, weights=None):
    """``{channel: (q, r)}``: the weighted sum of squared normalised residuals ``q`` and the sum of
    redundancy numbers ``r`` of each channel's residuals (finite ones). ``q / r`` estimates the
    channel's variance factor, ``(true sigma / sigma used)^2`` (Förstner's estimate)."""
    normalised = np.asarray(normalised, dtype=float)
    squared = normalised**2 if weights is None else np.asarray(weights) * normalised**2
    components = {}
    for channel, indices in channel_columns(columns).items():
        z2, r = squared[:, indices], np.asarray(redundancy)[:, indices]
        finite = np.isfinite(z2) & np.isfinite(r)
        components[channel] = (float(np.sum(z2[finite])), float(np.sum(r[finite])))
    return components


def studentised(normalised, redundancy, columns, components):
    """Studentised residuals ``z / sqrt(r f)`` (M, k): each residual over its own standard
    deviation, with ``f = q / r`` its channel's variance factor (:func:`variance_components`).
    Residuals with a redundancy below :data:`MIN_REDUNDANCY` (the fit follows them) give 0."""
    factors = np.ones(len(columns))
    for channel, indices in channel_columns(columns).items():
        q, r = components[channel]
        factors[indices] = q / r if r > 0 and q > 0 else 1.0
    redundancy = np.asarray(redundancy, dtype=float)
    usable = np.nan_to_num(redundancy, nan=0.0) >= MIN_REDUNDANCY
    scale = np.sqrt(np.where(usable, redundancy, 1.0) * factors)
    return np.where(usable, np.asarray(normalised, dtype=float) / scale, 0.0)


def bonferroni_threshold(count, significance=DEFAULT_SIGNIFICANCE):
    """|t| beyond which one of ``count`` standard normal residuals is an outlier at the family-wise
    ``significance`` (two-sided Bonferroni)."""
    return float(special.ndtri(1.0 - significance / (2.0 * max(int(count), 1))))


def outlier_postures(normalised, threshold=DEFAULT_OUTLIER_THRESHOLD, columns=None):
    """Postures whose largest |t| (studentised residuals, :func:`studentised`) exceeds
    ``threshold`` (None: :func:`bonferroni_threshold` over the finite residuals), worst first:
    ``[{'posture', 'max_studentised_residual', 'sensor'}]``; ``columns`` names the residual columns."""
    normalised = np.asarray(normalised, dtype=float)
    if threshold is None:
        threshold = bonferroni_threshold(np.count_nonzero(np.isfinite(normalised)))
    normalised = np.abs(np.nan_to_num(normalised, nan=0.0))
    worst = normalised.max(axis=1) if normalised.size else np.zeros(0)
    report = []
    for m in np.argsort(-worst):
        if worst[m] <= threshold:
            break
        column = int(np.argmax(normalised[m]))
        report.append(
            {
                'posture': int(m),
                'max_studentised_residual': float(worst[m]),
                'sensor': columns[column] if columns else column,
            }
        )
    return report


#: Nearest postures (in pose space) whose residuals a posture's are compared with.
NEIGHBOURS = 5
#: The neighbour test's threshold when the model does not explain the data, in multiples of the
#: studentised test's: a real platform's residual field changes faster than 60 postures sample
#: it (docs/verdict.md); a bad row stands out by far more.
NEIGHBOUR_THRESHOLD_FACTOR = 3.0
#: Metres per radian when postures are compared in pose space (a rotation of 1 rad moves the
#: platform's joints by about half a metre).
POSE_SCALE_M_PER_RAD = 0.5


def neighbour_deviations(normalised, poses, neighbours=NEIGHBOURS):
    """Each posture's residuals (M, k) minus the mean of its ``neighbours`` nearest postures' in
    pose space (``poses`` (M, 6), angles at :data:`POSE_SCALE_M_PER_RAD`), in units of the robust
    scale (1.4826 MAD) of these differences per column. NaN rows stay NaN."""
    normalised = np.asarray(normalised, dtype=float)
    scaled = np.array(poses, dtype=float)
    scaled[:, 3:] *= POSE_SCALE_M_PER_RAD
    usable = np.all(np.isfinite(normalised), axis=1)
    distance = np.linalg.norm(scaled[:, None, :] - scaled[None, :, :], axis=2)
    distance[:, ~usable] = np.inf
    np.fill_diagonal(distance, np.inf)
    count = max(1, min(int(neighbours), int(usable.sum()) - 1))
    nearest = np.argsort(distance, axis=1)[:, :count]
    deviations = normalised - np.nanmean(normalised[nearest], axis=1)
    deviations[~usable] = np.nan
    if usable.sum() < 3:
        return np.zeros_like(deviations)
    centre = np.nanmedian(deviations, axis=0)
    scale = 1.4826 * np.nanmedian(np.abs(deviations - centre), axis=0)
    scale = np.where(scale > 0.0, scale, 1.0)
    return deviations / scale


def isolated_outliers(outliers, normalised, poses, threshold=DEFAULT_OUTLIER_THRESHOLD):
    """The entries of ``outliers`` (:func:`outlier_postures`) whose postures also stand out from
    their neighbours (:func:`neighbour_deviations` of ``normalised`` beyond the threshold;
    ``threshold`` None: Bonferroni), each with its ``neighbour_deviation``."""
    if not outliers:
        return []
    deviations = neighbour_deviations(normalised, poses)
    if threshold is None:
        threshold = bonferroni_threshold(np.count_nonzero(np.isfinite(deviations)))
    kept = []
    for entry in outliers:
        worst = float(np.nanmax(np.abs(deviations[entry['posture']]), initial=0.0))
        if worst > threshold:
            kept.append({**entry, 'neighbour_deviation': worst})
    return kept


def outliers_beside_model_error(outliers, residual_count, threshold=None):
    """The entries of :func:`isolated_outliers` that stand out from their neighbours by
    :data:`NEIGHBOUR_THRESHOLD_FACTOR` times ``threshold`` (None: Bonferroni over
    ``residual_count``): the outliers of a fit whose model does not explain the data."""
    if threshold is None:
        threshold = bonferroni_threshold(residual_count)
    limit = NEIGHBOUR_THRESHOLD_FACTOR * threshold
    return [entry for entry in outliers if entry.get('neighbour_deviation', math.inf) > limit]


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
NOISE_CHANNELS = channels.SENSOR_SLICES


def noise_warning(estimated, configured):
    """``(ratio, warning)``: estimated / configured, and whether it is beyond
    :data:`NOISE_WARNING_RATIO` either way."""
    ratio = estimated / configured if configured > 0 else math.inf
    return ratio, not (1.0 / NOISE_WARNING_RATIO <= ratio <= NOISE_WARNING_RATIO)


def _head(fit):
    """The verdict's first clause: the test, its statistic and p-value."""
    if fit.test == 'lack_of_fit':
        return (
            f'goodness of fit (lack-of-fit F test, noise estimated from the run): '
            f'F {fit.f_statistic:.3f} for ({fit.dof:.0f}, {fit.pure_error_dof:.0f}) dof, '
            f'p = {fit.p_value:.3g}'
        )
    return f'goodness of fit: chi2 {fit.chi2:.1f} for {fit.dof:.0f} dof, p = {fit.p_value:.3g}'


def fit_diagnosis(fit, outliers=(), noise=None, free_sensor_errors=False):
    """Plain text: does the model explain the data, and if not, the likely causes (``outliers``:
    :func:`outlier_postures`; ``noise``: ``{channel: {'warning', ...}}``)."""
    if fit.dof <= 0:
        return (
            'goodness of fit: not assessable (no degrees of freedom left: add postures or fix '
            'parameters)'
        )
    if fit.test == 'none':
        return (
            'goodness of fit: not testable (the noise was estimated from these residuals and no '
            'within-posture scatter was recorded to test it against)'
        )
    head = _head(fit)
    if fit.accepted:
        source = 'estimated' if fit.test == 'lack_of_fit' else 'configured'
        return head + f': the model explains the data within the {source} noise'
    causes = []
    if outliers:
        causes.append(
            'outlier postures '
            + ', '.join(str(entry['posture']) for entry in outliers[:10])
            + ' (try loss: huber, or check those postures)'
        )
    wrong = [name for name, entry in (noise or {}).items() if entry.get('warning')]
    if fit.test == 'chi2' and wrong:
        causes.append(
            f'wrong sigmas: the noise of {", ".join(wrong)} estimated from the data differs > '
            f'{NOISE_WARNING_RATIO:g}x from the configured one (noise_source: estimated)'
        )
    hint = '' if free_sensor_errors else ' (try free_parameters: extended)'
    if fit.test == 'lack_of_fit':
        causes.append(
            'residuals between postures larger than the noise within them: an unmodelled error'
            + hint
            + " or sensor noise correlated over longer than a posture's averaging window"
        )
    elif fit.chi2 > fit.dof:
        causes.append(
            'residuals larger than the noise: an unmodelled error'
            + hint
            + ' or sigmas set too small'
        )
    else:
        causes.append('residuals smaller than the noise: sigmas set too large')
    return f'{head} < {DEFAULT_SIGNIFICANCE}: the model does NOT explain the data. Likely: ' + (
        '; '.join(causes)
    )
