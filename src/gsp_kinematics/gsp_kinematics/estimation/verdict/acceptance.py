"""Whether a calibration is good enough to apply: against what the user needs (pure)
(docs/verdict.md)."""

import dataclasses
import math

#: Default requirement: mean position error (mm) and mean phi error (deg) on held-out postures,
#: and how many times better than the nominal geometry the calibration must be.
DEFAULT_REQUIRED_POSITION_MM = 0.1
DEFAULT_REQUIRED_ORIENTATION_DEG = 0.01
DEFAULT_REQUIRED_IMPROVEMENT = 10.0


@dataclasses.dataclass(frozen=True)
class Requirement:
    """What the user needs: the cross-validated mean errors (position mm, phi deg) at most
    these, and at least ``improvement`` times better than the nominal geometry (position)."""

    position_mm: float = DEFAULT_REQUIRED_POSITION_MM
    orientation_deg: float = DEFAULT_REQUIRED_ORIENTATION_DEG
    improvement: float = DEFAULT_REQUIRED_IMPROVEMENT

    def as_dict(self):
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class Verdict:
    """``accepted``: apply the result; ``failures``: each condition that failed and by how much;
    ``lines``: the verdict as plain text lines (the first says applied or not and why)."""

    accepted: bool
    failures: tuple
    lines: tuple
    improvement: float  #: nominal / calibrated cross-validated mean position error

    @property
    def text(self):
        return '\n'.join(self.lines)

    def as_dict(self):
        return {
            'accepted': self.accepted,
            'failures': list(self.failures),
            'improvement_over_nominal': self.improvement,
            'text': self.text,
        }


def _mm(value):
    return f'{value:.3g} mm' if value >= 0.01 else f'{1000.0 * value:.3g} um'


def interval_text(figure, unit='mm'):
    """``' (95 %: 1.7-6.7 um)'`` of a held-out figure's ``mean_interval_95`` (``figure``: a
    ``{mean, mean_interval_95, ...}`` of :meth:`~gsp_kinematics.estimation.verdict.cross_validation.CrossValidation.summary`,
    in ``unit``: mm, shown as its mean is, or deg); '' without one."""
    interval = figure.get('mean_interval_95')
    if not interval or not all(math.isfinite(v) for v in interval):
        return ''
    low, high = interval
    if unit != 'mm':
        return f' (95 %: {low:.2g}-{high:.2g} {unit})'
    if figure['mean'] >= 0.01:
        return f' (95 %: {low:.3g}-{high:.3g} mm)'
    return f' (95 %: {1000.0 * low:.2g}-{1000.0 * high:.2g} um)'


def unmodelled_text(unmodelled):
    """``'about 16 um rms in the legs, 3 urad in the inclinations'`` of the channels that show
    an unmodelled part (a SensorNoise of row stds, m and rad); '' when none does."""
    if unmodelled is None:
        return ''
    parts = []
    for value, unit, where in (
        (unmodelled.leg_lengths, 'um', 'in the legs'),
        (unmodelled.inclinometer, 'urad', 'in the inclinations'),
        (unmodelled.encoder, 'urad', 'in phi'),
        (unmodelled.lvdt, 'um', 'in the link length'),
    ):
        if value > 0.0:
            parts.append(f'{1e6 * value:.2g} {unit} rms {where}')
    return ', '.join(parts)


def accuracy_line(accuracy, predicted=None):
    """One line of the cross-validated accuracy (:meth:`gsp_kinematics.estimation.verdict.cross_validation.CrossValidation.summary`), the nominal
    baseline and the prediction (``{position_mm_mean, ...}`` or None)."""
    calibrated, nominal = accuracy['calibrated'], accuracy['nominal']
    where = f'{accuracy["postures"]} postures'
    if accuracy.get('measured_on') == 'workspace':
        where = f'{accuracy["postures"]} workspace postures drawn at random'
    line = (
        f'accuracy measured by the device on held-out postures ({accuracy["folds"]}-fold '
        f'cross-validation, {where}, measurement noise removed): '
        f'position {_mm(calibrated["position_mm"]["mean"])} mean'
        f'{interval_text(calibrated["position_mm"])}, '
        f'{_mm(calibrated["position_mm"]["p95"])} p95; phi '
        f'{calibrated["phi_deg"]["mean"]:.2g} deg mean{interval_text(calibrated["phi_deg"], "deg")}; '
        'nominal geometry '
        f'{_mm(nominal["position_mm"]["mean"])}'
    )
    if predicted and predicted.get('position_mm_mean') is not None:
        line += f'; predicted {_mm(predicted["position_mm_mean"])}'
    selected = accuracy.get('selected')
    if selected:
        position = selected['calibrated']['position_mm']
        line += (
            f"; on the {selected['postures']} selected postures (the workspace's extremes) "
            f'{_mm(position["mean"])}{interval_text(position)}'
        )
    return line


def judged_accuracy(accuracy):
    """``(position mm, phi deg)`` the requirement is checked against: the held-out means, and
    with workspace postures the larger of theirs and the selected postures' (docs/verdict.md)."""
    position = accuracy['calibrated']['position_mm']['mean']
    phi = accuracy['calibrated']['phi_deg']['mean']
    selected = (accuracy.get('selected') or {}).get('calibrated')
    if selected:
        position = max(position, selected['position_mm']['mean'])
        phi = max(phi, selected['phi_deg']['mean'])
    return position, phi


def _failures(accuracy, requirement, improvement, predicted):
    """The conditions ``accuracy`` (and the ``predicted`` headline) fail, each saying by how
    much."""
    position, phi = judged_accuracy(accuracy)
    failures = []
    if not accuracy['postures'] or not math.isfinite(position):
        return ['the accuracy could not be measured: no held-out posture was predicted']
    if position > requirement.position_mm:
        failures.append(
            f'position {_mm(position)} exceeds the required {_mm(requirement.position_mm)} '
            f'({position / requirement.position_mm:.3g}x)'
        )
    if math.isfinite(phi) and phi > requirement.orientation_deg:
        failures.append(
            f'phi {phi:.3g} deg exceeds the required {requirement.orientation_deg:.3g} deg '
            f'({phi / requirement.orientation_deg:.3g}x)'
        )
    if not improvement >= requirement.improvement:
        failures.append(
            f'only {improvement:.3g} times better than the nominal geometry (required '
            f'{requirement.improvement:.3g}x)'
        )
    # Held-out postures only test where the run went: the covariance says whether the postures
    # identify the model everywhere else in the workspace.
    expected = (predicted or {}).get('position_mm_mean')
    if expected is not None and not expected <= requirement.position_mm:
        failures.append(
            f'the postures do not identify the model over the workspace: predicted position '
            f'error {_mm(expected)} exceeds the required {_mm(requirement.position_mm)} '
            f'({expected / requirement.position_mm:.3g}x; add postures that tilt and change '
            'height, gsp_plan)'
        )
    return failures


def judge(accuracy, requirement=Requirement(), unmodelled=None, predicted=None):
    """The :class:`Verdict` of a calibration whose cross-validated ``accuracy`` is
    :meth:`gsp_kinematics.estimation.verdict.cross_validation.CrossValidation.summary`, with the model's ``unmodelled`` part (SensorNoise of row
    stds or None) and the ``predicted`` headline (or None)."""
    position = accuracy['calibrated']['position_mm']['mean']
    nominal = accuracy['nominal']['position_mm']['mean']
    improvement = nominal / position if position > 0 else math.inf
    if not math.isfinite(nominal):
        improvement = math.nan
    failures = _failures(accuracy, requirement, improvement, predicted)
    head = (
        'calibration accepted: meets the required accuracy '
        f'({_mm(requirement.position_mm)}, {requirement.orientation_deg:g} deg) and is '
        f'{improvement:.3g} times better than the nominal geometry'
        if not failures
        else 'calibration NOT accepted (written, not applied): ' + '; '.join(failures)
    )
    lines = [head, accuracy_line(accuracy, predicted)]
    unexplained = unmodelled_text(unmodelled)
    if unexplained:
        lines.append(
            f'WARNING: the model leaves about {unexplained} unexplained; the calibration is still '
            f'{improvement:.3g} times better than the nominal geometry'
        )
    return Verdict(not failures, tuple(failures), tuple(lines), improvement)
