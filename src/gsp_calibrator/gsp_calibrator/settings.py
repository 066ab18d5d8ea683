"""Parameters of the ``calibrator`` node: names, defaults, units, checks (pure, no rclpy).

:data:`PARAMETERS` is the single source of the declarations (the node declares them with
:func:`gsp_msgs_py.parameter_specs.declare_parameters`; docs/parameters.md is generated from it);
:func:`check_parameters` gives the reason a set of values is rejected, at start-up and in the
set-parameters callback; :meth:`CalibratorSettings.from_values` turns accepted values into the
settings of one run.
"""

import dataclasses
import os
import re

from gsp_calibrator.upkeep.parameters import UPKEEP_PARAMETERS
from gsp_kinematics.acceptance import (
    DEFAULT_REQUIRED_IMPROVEMENT,
    DEFAULT_REQUIRED_ORIENTATION_DEG,
    DEFAULT_REQUIRED_POSITION_MM,
    Requirement,
)
from gsp_kinematics.cross_validation import DEFAULT_FOLDS
from gsp_kinematics.geometry import (
    ALL_PARAMETER_NAMES,
    GeometryError,
    default_geometry_path,
    load_geometry,
)
from gsp_kinematics.goodness import LOSSES
from gsp_kinematics.identification import (
    FORMULATIONS,
    PARAMETER_GROUPS,
    Options,
    resolve_free,
)
from gsp_kinematics.noise_from_data import DEFAULT_NOISE_SOURCE, NOISE_SOURCES
from gsp_kinematics.sensors.noise import DEFAULT_SENSOR_NOISE, SensorNoise
from gsp_kinematics.sensors.noise_estimate import DEFAULT_SETTLE_SIGMAS
from gsp_kinematics.travel.motion import MotionLimits
from gsp_msgs_py import parameter_specs
from gsp_msgs_py.parameter_specs import ParameterSpec, at_least, check_values, greater_than, one_of

_NODE_NAME = re.compile(r'^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$')


def check_free_parameters(value):
    """Reason ('' if none) why ``value`` (names and groups) is not a set of free parameters."""
    return _check_free(value)


def _check_free(value):
    names = list(value)
    if not names:
        return 'must name at least one parameter'
    unknown = [n for n in names if n not in ALL_PARAMETER_NAMES and n not in PARAMETER_GROUPS]
    if unknown:
        return (
            f'unknown parameter name(s) {unknown}; expected groups ({", ".join(PARAMETER_GROUPS)}) '
            'or names among A1x..A6z, B1x..B6z, Loff1..Loff6, D0, gamma, kq1..kq6, alpha0, '
            'beta0, phi0, kDm'
        )
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        return f'duplicated name(s) {duplicated}'
    return ''


def _check_geometry_file(value):
    if not str(value).strip():
        return 'must name a geometry file'
    try:
        load_geometry(value)
    except GeometryError as error:
        return str(error)
    return ''


_POSITIVE = greater_than(0.0, reason='must be a finite number > 0')


#: Values of the ``posture_order`` parameter.
POSTURE_ORDERS = ('route', 'selection')


def _positive(name, default, description, unit=''):
    """A parameter that must be a finite number > 0."""
    return ParameterSpec(name, default, description, unit=unit, constraints='> 0', check=_POSITIVE)


def _seconds(name, default, description):
    """A time in s that must be finite and >= 0."""
    return ParameterSpec(
        name,
        default,
        description,
        unit='s',
        constraints='>= 0',
        check=at_least(0.0, reason='must be finite and >= 0 s'),
    )


def _one_of(name, default, description, options):
    """A parameter that must be one of ``options``."""
    return ParameterSpec(
        name,
        default,
        description,
        constraints='one of ' + ', '.join(options),
        check=one_of(options),
    )


#: The per-sample noise of each sensor (a ``SensorNoise`` field and its parameter ``sigma_<field>``):
#: field, unit, what the sigma weighs.
_SIGMA_TABLE = (
    ('leg_lengths', 'm', 'Noise std of one leg-length sample (weight of the leg residuals)'),
    ('inclinometer', 'rad', 'Noise std of one inclinometer sample (alpha, beta)'),
    ('encoder', 'rad', 'Noise std of one encoder sample (phi)'),
    ('lvdt', 'm', 'Noise std of one LVDT sample (d_m)'),
)

PARAMETERS = (
    ParameterSpec(
        'nominal_geometry_file',
        default_geometry_path('nominal'),
        'Geometry params file of the nominal (design) geometry the identification '
        'starts from; also used to choose reachable postures',
        constraints='a readable geometry params file',
        check=_check_geometry_file,
        default_text='gsp_kinematics/data/nominal_geometry.yaml (shipped)',
    ),
    ParameterSpec(
        'posture_count',
        60,
        'Postures selected and commanded per calibration',
        constraints='>= 1 and <= pool_size',
        check=at_least(1),
    ),
    ParameterSpec(
        'pool_size',
        600,
        'Random reachable postures the selection (condition-number criterion) chooses from',
        constraints='>= posture_count',
        check=at_least(1),
    ),
    ParameterSpec(
        'samples_per_posture',
        10,
        'Synchronised (leg lengths, device) samples averaged per posture',
        constraints='>= 1',
        check=at_least(1),
    ),
    _seconds(
        'sync_tolerance',
        0.0025,
        'Largest stamp difference of a leg-length sample and the device sample it is '
        'paired with (about half the sensor period)',
    ),
    _positive(
        'settle_timeout',
        5.0,
        "Longest wait for a commanded posture's 'settled' status after its first "
        'status; a posture that does not settle is skipped',
        unit='s',
    ),
    _seconds(
        'settle_lookback',
        0.0,
        'Span the settle rule judges each channel over, ending with the averaged window (at '
        "least that window): about 5 times the slowest sensor's response time; the "
        'readings are waited for until at rest over it (docs/sensor_errors.md)',
    ),
    _positive(
        'settle_sigmas',
        3.0,
        "Trend over the settle look-back, in stds of a settled span's trend, above which a "
        'channel is still moving (3: a settled white channel is called moving in 0.27 % of '
        'spans)',
    ),
    _positive(
        'topic_timeout',
        2.0,
        'Longest silence of a topic (or service) the run waits on before it ends with '
        'an error naming it',
        unit='s',
    ),
    ParameterSpec(
        'seed', 0, 'Seed of the random posture pool', constraints='>= 0', check=at_least(0)
    ),
    ParameterSpec(
        'free_parameters',
        ['extended'],
        'Parameters identified: groups paper (the 44: A1x..B6z, Loff1..Loff6, D0, gamma) and '
        'extended (the 44 and the identifiable sensor errors kq1..kq6, alpha0), and/or names '
        '(also beta0, phi0, kDm); the others keep their nominal values (docs/sensor_errors.md)',
        constraints='non-empty, known names or groups, no duplicates',
        check=_check_free,
    ),
    _one_of(
        'loss',
        'linear',
        'Loss of the fit: linear (least squares), huber or cauchy (robust to outlier postures; '
        'down-weighted postures are reported)',
        LOSSES,
    ),
    _positive(
        'loss_scale',
        Options().loss_scale,
        'Normalised residual (in sigmas) where the robust loss departs from least squares',
    ),
    ParameterSpec(
        'outlier_threshold',
        0.0,
        'A posture whose largest studentised residual (each residual over its own standard '
        'deviation under the noise the residuals show) exceeds this is reported; 0: the '
        'Bonferroni threshold at 1 % over all residuals (about 4.3 for 600)',
        constraints='>= 0',
        check=at_least(0.0),
    ),
    _one_of(
        'noise_source',
        DEFAULT_NOISE_SOURCE,
        'Where the weights, covariance, predicted accuracy and goodness of fit take the sensor '
        'noise from: estimated (from the run: the within-posture scatter and the '
        'between-posture residuals; the sigma_* only start the estimate) or configured (the '
        'sigma_* parameters); docs/sensor_errors.md',
        NOISE_SOURCES,
    ),
    _positive(
        'required_position_accuracy_mm',
        DEFAULT_REQUIRED_POSITION_MM,
        'The result is applied (apply_result) only if its mean position error, measured by the '
        'device on postures the fit did not use (cross-validation, measurement noise removed), '
        'is at most this (docs/verdict.md)',
        'mm',
    ),
    _positive(
        'required_orientation_accuracy_deg',
        DEFAULT_REQUIRED_ORIENTATION_DEG,
        'The result is applied only if its cross-validated mean error of the platform rotation '
        'phi (the rotation the device measures) is at most this',
        'deg',
    ),
    ParameterSpec(
        'required_improvement_over_nominal',
        DEFAULT_REQUIRED_IMPROVEMENT,
        'The result is applied only if its cross-validated mean position error is at least '
        "this many times smaller than the nominal geometry's on the same postures",
        constraints='>= 1',
        check=at_least(1.0, reason='must be finite and >= 1'),
    ),
    ParameterSpec(
        'cross_validation_folds',
        DEFAULT_FOLDS,
        'Folds of the cross-validation that measures the accuracy (each fold of postures is '
        'predicted by a fit without it); with fewer postures, each is left out alone',
        constraints='>= 2',
        check=at_least(2),
    ),
    _one_of(
        'formulation',
        'implicit',
        'Identification formulation: implicit (all sensors, poses as unknowns), fk '
        "(device residuals through FK) or paper (the paper's eq 11)",
        FORMULATIONS,
    ),
    *(
        _positive(f'sigma_{field}', getattr(DEFAULT_SENSOR_NOISE, field), text, unit)
        for field, unit, text in _SIGMA_TABLE
    ),
    _one_of(
        'posture_order',
        'route',
        "Order the postures are commanded in: route (the shortest travel from the platform's "
        'current posture, docs/planning.md) or selection (the order the selection found them)',
        POSTURE_ORDERS,
    ),
    _positive(
        'max_leg_speed',
        MotionLimits().max_speed,
        "The platform's leg speed limit, for the route's travel times",
        'm/s',
    ),
    _positive(
        'max_leg_acceleration',
        MotionLimits().max_acceleration,
        "The platform's leg acceleration limit, for the route's travel times",
        'm/s^2',
    ),
    ParameterSpec(
        'output_root',
        'runs',
        'Directory under which each run writes <UTC timestamp>/ (samples.csv, result.yaml)',
        constraints='non-empty path',
        check=lambda v: '' if str(v).strip() else 'must not be empty',
    ),
    ParameterSpec(
        'write_report_plots',
        True,
        'Draw the PNG plots of report.md (parameter and chain errors, residuals, accuracy map); '
        'false: result.json, report.md (saying the plots were skipped) and the CSVs only, '
        'which is much faster',
    ),
    ParameterSpec(
        'resume_run_directory',
        '',
        'Run directory /gsp/calibrator/resume continues; empty: the latest unfinished run under '
        'output_root (see docs/faults.md)',
    ),
    ParameterSpec(
        'apply_result',
        False,
        'After a successful calibration, set the geometry.* parameters of '
        'platform_node_name (its controller) through its parameter service',
    ),
    ParameterSpec(
        'platform_node_name',
        'platform_sim',
        'Node whose geometry.* parameters apply_result sets',
        constraints='a valid node name',
        check=lambda v: '' if _NODE_NAME.match(str(v)) else 'is not a valid node name',
    ),
    *UPKEEP_PARAMETERS,
    parameter_specs.diagnostics_period_spec(),
)
PARAMETER_SPECS = {spec.name: spec for spec in PARAMETERS}
DEFAULTS = {spec.name: spec.default for spec in PARAMETERS}


# --- command-line options of a run (gsp_demo, gsp_plan) ------------------------------------------


def add_run_options(parser, seed_help='seed of the posture pool'):
    """Add to ``parser`` the options of a run that mirror the parameters above, with their
    defaults: ``--postures``, ``--pool-size``, ``--samples-per-posture``, ``--seed``, ``--free``
    and ``--formulation``. Check the parsed values with :func:`run_options_error`."""
    add = parser.add_argument
    for option, name, help_text in (
        ('--postures', 'posture_count', 'postures commanded'),
        ('--pool-size', 'pool_size', 'random postures the selection picks from'),
        ('--samples-per-posture', 'samples_per_posture', 'samples averaged per posture'),
        ('--seed', 'seed', seed_help),
    ):
        add(option, type=int, default=DEFAULTS[name], help=f'{help_text} ({DEFAULTS[name]})')
    add(
        '--free',
        nargs='+',
        default=list(DEFAULTS['free_parameters']),
        metavar='NAME',
        help='free parameters: groups paper or extended, and/or names (default: extended)',
    )
    add('--formulation', choices=FORMULATIONS, default=DEFAULTS['formulation'])


def run_options_error(args):
    """Reason ('' if none) why the options of :func:`add_run_options` in ``args`` are invalid.

    ``args.free`` also takes comma-separated names: it is split in place first.
    """
    for name in ('postures', 'pool_size', 'samples_per_posture'):
        if getattr(args, name) < 1:
            return f'--{name.replace("_", "-")} must be >= 1'
    args.free = [n.strip() for value in args.free for n in value.split(',') if n.strip()]
    reason = check_free_parameters(args.free)
    return f'--free: {reason}' if reason else ''


def check_combination(values):
    """Reason ('' if none) why a complete ``{name: value}`` set is inconsistent
    (``posture_count <= pool_size``); the ``validate`` of ``declare_parameters``."""
    if values['posture_count'] > values['pool_size']:
        return (
            f'posture_count ({values["posture_count"]}) must not exceed pool_size '
            f'({values["pool_size"]})'
        )
    return ''


def check_parameters(changes, current=None):
    """Reason ('' if none) why ``changes`` ({name: value}) on top of ``current`` are invalid.

    Each changed value is checked alone, then the combination (``posture_count <= pool_size``);
    the ``validate`` of ``watch_parameters``.
    """
    return check_values(PARAMETER_SPECS, changes) or check_combination(
        {**(DEFAULTS if current is None else current), **changes}
    )


@dataclasses.dataclass(frozen=True)
class CalibratorSettings:
    """The settings of one calibration run (a snapshot of the parameters)."""

    nominal_geometry_file: str
    nominal: object  #: the loaded nominal Geometry
    posture_count: int
    pool_size: int
    samples_per_posture: int
    sync_tolerance: float  #: s
    settle_timeout: float  #: s
    topic_timeout: float  #: s
    seed: int
    free_parameters: tuple
    formulation: str
    sigmas: SensorNoise  #: per-sample noise std (m, rad)
    output_root: str
    resume_run_directory: str
    apply_result: bool
    platform_node_name: str
    loss: str = 'linear'
    loss_scale: float = Options().loss_scale  #: sigmas
    outlier_threshold: float = 0.0  #: studentised; 0: Bonferroni at 1 %
    noise_source: str = DEFAULT_NOISE_SOURCE  #: 'estimated' or 'configured'
    required_position_accuracy_mm: float = DEFAULT_REQUIRED_POSITION_MM
    required_orientation_accuracy_deg: float = DEFAULT_REQUIRED_ORIENTATION_DEG
    required_improvement_over_nominal: float = DEFAULT_REQUIRED_IMPROVEMENT
    cross_validation_folds: int = DEFAULT_FOLDS
    posture_order: str = 'route'
    max_leg_speed: float = MotionLimits().max_speed  #: m/s
    max_leg_acceleration: float = MotionLimits().max_acceleration  #: m/s^2
    settle_lookback: float = 0.0  #: s
    settle_sigmas: float = DEFAULT_SETTLE_SIGMAS
    write_report_plots: bool = True
    platform_id: str = 'default'  #: the history's platform (docs/upkeep.md)
    check_geometry_file: str = ''  #: what a check checks ('': the latest calibration)

    @property
    def motion_limits(self):
        """The platform's leg limits the route is planned with."""
        return MotionLimits(self.max_leg_speed, self.max_leg_acceleration)

    @property
    def free_count(self):
        """Number of free parameters (the groups expanded)."""
        return int(resolve_free(self.free_parameters).sum())

    @property
    def requirement(self):
        """What the result must achieve to be applied (``acceptance.Requirement``)."""
        return Requirement.from_parameters(vars(self))

    def identify_options(self):
        """The core's ``Options`` for this run's loss and outlier threshold."""
        return Options(
            loss=self.loss,
            loss_scale=self.loss_scale,
            outlier_threshold=self.outlier_threshold or None,
        )

    def describe(self):
        """One line for the log: the nominal file, counts, formulation and output root."""
        return (
            f'nominal {self.nominal_geometry_file}, {self.posture_count} postures from a pool of '
            f'{self.pool_size}, {self.samples_per_posture} samples each, {self.formulation} '
            f'formulation, {self.free_count} free parameters, output under '
            f'{os.path.abspath(self.output_root)}'
        )

    @classmethod
    def from_values(cls, values):
        """Settings from ``{name: value}`` (defaults for missing names); ValueError if invalid."""
        merged = dict(DEFAULTS)
        merged.update(values)
        reason = check_parameters(merged, merged)
        if reason:
            raise ValueError(reason)
        return cls(
            nominal_geometry_file=str(merged['nominal_geometry_file']),
            nominal=load_geometry(merged['nominal_geometry_file']),
            posture_count=int(merged['posture_count']),
            pool_size=int(merged['pool_size']),
            samples_per_posture=int(merged['samples_per_posture']),
            sync_tolerance=float(merged['sync_tolerance']),
            settle_timeout=float(merged['settle_timeout']),
            topic_timeout=float(merged['topic_timeout']),
            seed=int(merged['seed']),
            free_parameters=tuple(merged['free_parameters']),
            formulation=str(merged['formulation']),
            sigmas=SensorNoise.from_parameters(merged),
            output_root=str(merged['output_root']),
            resume_run_directory=str(merged['resume_run_directory']),
            apply_result=bool(merged['apply_result']),
            platform_node_name=str(merged['platform_node_name']).lstrip('/'),
            loss=str(merged['loss']),
            loss_scale=float(merged['loss_scale']),
            outlier_threshold=float(merged['outlier_threshold']),
            noise_source=str(merged['noise_source']),
            required_position_accuracy_mm=float(merged['required_position_accuracy_mm']),
            required_orientation_accuracy_deg=float(merged['required_orientation_accuracy_deg']),
            required_improvement_over_nominal=float(merged['required_improvement_over_nominal']),
            cross_validation_folds=int(merged['cross_validation_folds']),
            posture_order=str(merged['posture_order']),
            max_leg_speed=float(merged['max_leg_speed']),
            max_leg_acceleration=float(merged['max_leg_acceleration']),
            settle_lookback=float(merged['settle_lookback']),
            settle_sigmas=float(merged['settle_sigmas']),
            write_report_plots=bool(merged['write_report_plots']),
            platform_id=str(merged['platform_id']),
            check_geometry_file=str(merged['check_geometry_file']),
        )
