"""Parameters of the ``calibrator`` node: names, defaults, units, checks (pure, no rclpy).

:data:`PARAMETERS` declares each parameter once (docs/parameters.md is generated from it); the
settings (:class:`CalibratorSettings`), subsets and command-line options derive from it.
"""

import dataclasses
import functools
import math
import os
import re

from gsp_calibrator.settings_fields import ParameterFields
from gsp_kinematics.estimation.goodness import LOSSES
from gsp_kinematics.estimation.identification import (
    DEFAULT_FORMULATION,
    FORMULATIONS,
    Options,
    free_parameters_error,
    resolve_free,
)
from gsp_kinematics.estimation.noise_estimate import DEFAULT_REST_SIGMAS
from gsp_kinematics.estimation.noise_from_data import (
    DEFAULT_NOISE_SOURCE,
    NOISE_SOURCES,
    noise_source_error,
)
from gsp_kinematics.estimation.verdict.acceptance import (
    DEFAULT_REQUIRED_IMPROVEMENT,
    DEFAULT_REQUIRED_ORIENTATION_DEG,
    DEFAULT_REQUIRED_POSITION_MM,
    Requirement,
)
from gsp_kinematics.estimation.verdict.cross_validation import DEFAULT_FOLDS
from gsp_kinematics.model.geometry import GeometryError, default_geometry_path, load_geometry
from gsp_kinematics.model.motion import DEFAULT_PAIRS_PER_POSTURE, MotionLimits
from gsp_kinematics.model.sensor_noise import (
    DEFAULT_SENSOR_NOISE,
    NOISE_FIELDS,
    NOISE_UNITS,
)
from gsp_msgs_py import parameter_specs
from gsp_msgs_py.noise_parameters import (
    ASSUMED_NOISE_PARAMETER,
    noise_from_parameters,
    noise_parameter_names,
)
from gsp_msgs_py.parameter_specs import (
    ParameterSpec,
    at_least,
    greater_than,
    is_finite_number,
    one_of,
    validate_values,
)

_NODE_NAME = re.compile(r'^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$')
#: A platform id: letters, digits, '-', '_', '.' (it names the platform in the history).
_PLATFORM_ID = re.compile(r'^[A-Za-z0-9_.-]{1,64}$')


#: The subsets of :data:`PARAMETERS` (a spec's ``subsets``).
#: Stored with a run (the recording's options): the rebuild and ``gsp_reidentify`` read them back.
STORED = 'stored'
#: Decide the posture selection (``state.json``; a resume refuses a change of one).
SELECTION = 'selection'
#: Options of ``gsp_demo`` and ``gsp_plan`` (:func:`add_run_options`).
RUN_COMMAND_LINE = 'run_command_line'
#: Options of ``gsp_reidentify`` (default: as stored with the run).
REIDENTIFY_COMMAND_LINE = 'reidentify_command_line'
#: The command-line option of a parameter whose option is not ``--<name with dashes>``.
_OPTION_NAMES = {'posture_count': '--postures', 'free_parameters': '--free'}
_RUN = frozenset((STORED, SELECTION, RUN_COMMAND_LINE))
#: The acceptance options: stored with the run, and a re-identification may judge it again.
_JUDGED = frozenset((STORED, REIDENTIFY_COMMAND_LINE))


def _validate_geometry_file(value):
    if not str(value).strip():
        return 'must name a geometry file'
    try:
        load_geometry(value)
    except GeometryError as error:
        return str(error)
    return ''


def is_number(value):
    """True for an int or float, infinities included (bools and strings are not numbers)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _positive(name, default, description, unit='', subsets=frozenset()):
    """A parameter that must be a finite number > 0."""
    return ParameterSpec(
        name,
        default,
        description,
        unit=unit,
        constraints='> 0',
        check=greater_than(0.0, reason='must be a finite number > 0'),
        subsets=subsets,
    )


def _seconds(name, default, description, subsets=frozenset()):
    """A time in s that must be finite and >= 0."""
    return ParameterSpec(
        name,
        default,
        description,
        unit='s',
        constraints='>= 0',
        check=at_least(0.0, reason='must be finite and >= 0 s'),
        subsets=subsets,
    )


def _one_of(name, default, description, options, subsets=frozenset(), check=None):
    """A parameter that must be one of ``options`` (``check``: the check that says so)."""
    return ParameterSpec(
        name,
        default,
        description,
        constraints='one of ' + ', '.join(options),
        check=check or one_of(options),
        subsets=subsets,
    )


#: What each sensor's assumed noise ``sigma_<sensor>`` weighs (its unit is the sensor's).
_SIGMA_TEXT = {
    'leg_lengths': 'Noise std of one leg-length sample (weight of the leg residuals)',
    'inclinometer': 'Noise std of one inclinometer sample (alpha, beta)',
    'encoder': 'Noise std of one encoder sample (phi)',
    'lvdt': 'Noise std of one LVDT sample (d_m)',
}

PARAMETERS = (
    ParameterSpec(
        'nominal_geometry_file',
        default_geometry_path('nominal'),
        'Geometry params file of the nominal (design) geometry the identification '
        'starts from; also used to choose reachable postures',
        constraints='a readable geometry params file',
        check=_validate_geometry_file,
        default_text='gsp_kinematics/data/nominal_geometry.yaml (shipped)',
        subsets=frozenset((STORED,)),
    ),
    ParameterSpec(
        'posture_count',
        60,
        'Postures selected and commanded per calibration',
        constraints='>= 1 and <= pool_size',
        check=at_least(1),
        subsets=_RUN,
    ),
    ParameterSpec(
        'pool_size',
        600,
        'Random reachable postures the selection (condition-number criterion) chooses from',
        constraints='>= posture_count',
        check=at_least(1),
        subsets=_RUN,
    ),
    ParameterSpec(
        'workspace_postures',
        0,  # none by default (docs/verdict.md)
        'Workspace postures drawn at random (seeded by seed) and commanded with the selected '
        'ones: the measured accuracy is their cross-validated error (plus the device uncertainty), '
        'the selected postures figure beside it, the requirement judged on the larger '
        '(docs/verdict.md); 0: measured on the selected postures',
        constraints='>= 0',
        check=at_least(0),
        subsets=_RUN,
    ),
    ParameterSpec(
        'pairs_per_posture',
        DEFAULT_PAIRS_PER_POSTURE,
        'Synchronised (leg lengths, device) samples averaged per posture',
        constraints='>= 1',
        check=at_least(1),
        subsets=frozenset((STORED, RUN_COMMAND_LINE, REIDENTIFY_COMMAND_LINE)),
    ),
    _seconds(
        'sync_tolerance',
        0.0025,
        'Largest stamp difference of a leg-length sample and the device sample it is '
        'paired with (about half the sensor period)',
        subsets=frozenset((STORED, REIDENTIFY_COMMAND_LINE)),
    ),
    _positive(
        'settle_timeout',
        5.0,
        "Longest wait for a commanded posture's 'settled' status after its first "
        'status, besides its planned move (the travel time at max_leg_speed and '
        'max_leg_acceleration); a posture that does not settle is skipped',
        unit='s',
    ),
    _positive(
        'max_posture_error',
        0.05,
        'Largest distance between the platform position the device measures (eq 9, nominal '
        'geometry) and the commanded one; beyond it the run stops with an error, that row not '
        'kept: the platform is not where it was sent (another assembly after passing near a '
        "singularity, a swapped or miswired sensor). Above the nominal geometry's error and "
        "the inclinometer's mounting offset (1 deg: 15-20 mm)",
        unit='m',
        subsets=frozenset((STORED, REIDENTIFY_COMMAND_LINE)),
    ),
    _seconds(
        'rest_lookback',
        0.25,
        'Span the rest rule judges each channel over, ending with the averaged window (at '
        'least that window): the readings are averaged only once at rest over it (no trend, '
        'no scatter beyond their noise), whatever the platform says; at least 5 times the '
        "slowest sensor's response time and a few periods of the platform's ringing "
        '(docs/sensor_errors.md)',
        subsets=frozenset((STORED,)),
    ),
    ParameterSpec(
        'rest_sigmas',
        DEFAULT_REST_SIGMAS,
        "Trend over the rest look-back, in stds of a settled span's trend, above which a "
        'channel is still moving (3: a settled white channel is called moving in 0.27 % of '
        'spans); its scatter is judged at the same rate; .inf turns the rest rule off',
        constraints='> 0 (.inf: off)',
        # Not greater_than: infinity is the documented way to switch the rule off.
        check=lambda v: '' if is_number(v) and v > 0.0 else 'must be > 0 (.inf: off)',
        subsets=frozenset((STORED,)),
    ),
    _positive(
        'topic_timeout',
        2.0,
        'Longest silence of a topic (or service) the run waits on before it ends with '
        'an error naming it',
        unit='s',
    ),
    _positive(
        'startup_timeout',
        10.0,
        'Longest wait, as a run starts, for platform_sim to listen and publish its status and '
        'for each sensor topic to speak: nodes started with the calibrator (a launch file) '
        'may still be discovering each other',
        unit='s',
    ),
    ParameterSpec(
        'seed',
        0,
        'Seed of the random posture pool',
        constraints='>= 0',
        check=at_least(0),
        subsets=_RUN,
    ),
    ParameterSpec(
        'free_parameters',
        ['auto'],
        'Parameters identified: groups paper (the 44: A1x..B6z, Loff1..Loff6, D0, gamma) and '
        'extended (the 44 and the identifiable sensor errors kq1..kq6, alpha0), and/or names '
        '(also beta0, phi0, kDm); the others keep their nominal values (docs/sensor_errors.md). '
        'Effect groups compliance, backlash, thermal, joint_offsets (implicit formulation), or '
        'auto: the plain model (the other names, default extended) and the effect groups the '
        'data show help on postures the fit did not see (a significance test, never a held-out '
        'error above the plain model; the plain model alone in the fk and paper formulations); '
        'thermal, backlash and auto add to the route what they need: reference revisits, '
        'approach postures (docs/platform_effects.md)',
        constraints='non-empty, known names or groups, no duplicates, auto without effect groups',
        check=free_parameters_error,
        subsets=_RUN | {REIDENTIFY_COMMAND_LINE},
    ),
    ParameterSpec(
        'payload_mass',
        0.0,
        'Mass the legs carry (moving platform and payload) for the compliance group: the device '
        'identifies the compliance times this mass; 0: unknown, the compliance is identified for '
        'a reference 1 kg at payload_centre_of_mass (the compliance times the load over it, '
        'which compensates the load of the run; the result says so; docs/platform_effects.md)',
        unit='kg',
        constraints='>= 0',
        check=at_least(0.0, reason='must be finite and >= 0 kg'),
        subsets=_JUDGED,
    ),
    ParameterSpec(
        'payload_centre_of_mass',
        [0.0, 0.0, 0.0],
        "Centre of mass of the load in the platform frame (x, y, z), for the legs' forces (also "
        'where the reference mass sits when payload_mass is 0)',
        unit='m',
        constraints='3 finite numbers',
        check=lambda v: (
            ''
            if len(list(v)) == 3 and all(is_finite_number(x) for x in v)
            else 'must be 3 finite numbers (m)'
        ),
        subsets=frozenset((STORED,)),
    ),
    ParameterSpec(
        'leg_mass',
        [0.0] * 6,
        'Mass of each leg (a uniform bar between its joints) for the compliance group: the '
        "legs' own weight loads them too (docs/platform_effects.md); 0: massless legs",
        unit='kg',
        constraints='6 finite numbers >= 0',
        check=lambda v: (
            ''
            if len(list(v)) == 6 and all(is_finite_number(x) and x >= 0.0 for x in v)
            else 'must be 6 finite masses >= 0 kg'
        ),
        subsets=frozenset((STORED,)),
    ),
    _one_of(
        'loss',
        'linear',
        'Loss of the fit: linear (least squares), huber or cauchy (robust to outlier postures; '
        'down-weighted postures are reported)',
        LOSSES,
        subsets=frozenset((STORED, REIDENTIFY_COMMAND_LINE)),
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
        frozenset((STORED, REIDENTIFY_COMMAND_LINE)),
        check=noise_source_error,
    ),
    _positive(
        'required_position_accuracy_mm',
        DEFAULT_REQUIRED_POSITION_MM,
        'The result is applied (apply_result) only if its mean position error, measured by the '
        'device on postures the fit did not use (cross-validation, measurement noise removed), '
        'is at most this (docs/verdict.md)',
        'mm',
        _JUDGED,
    ),
    _positive(
        'required_orientation_accuracy_deg',
        DEFAULT_REQUIRED_ORIENTATION_DEG,
        'The result is applied only if its cross-validated mean error of the platform rotation '
        'phi (the rotation the device measures) is at most this',
        'deg',
        _JUDGED,
    ),
    ParameterSpec(
        'required_improvement_over_nominal',
        DEFAULT_REQUIRED_IMPROVEMENT,
        'The result is applied only if its cross-validated mean position error is at least '
        "this many times smaller than the nominal geometry's on the same postures",
        constraints='>= 1',
        check=at_least(1.0, reason='must be finite and >= 1'),
        subsets=_JUDGED,
    ),
    ParameterSpec(
        'cross_validation_folds',
        DEFAULT_FOLDS,
        'Folds of the cross-validation that measures the accuracy (each fold of postures is '
        'predicted by a fit without it); with fewer postures, each is left out alone',
        constraints='>= 2',
        check=at_least(2),
        subsets=_JUDGED,
    ),
    _one_of(
        'formulation',
        DEFAULT_FORMULATION,
        'Identification formulation: implicit (all sensors, poses as unknowns), fk '
        "(device residuals through FK) or paper (the paper's eq 11)",
        FORMULATIONS,
        subsets=_RUN | {REIDENTIFY_COMMAND_LINE},
    ),
    *(
        _positive(
            ASSUMED_NOISE_PARAMETER.format(sensor),
            getattr(DEFAULT_SENSOR_NOISE, sensor),
            _SIGMA_TEXT[sensor],
            NOISE_UNITS[sensor],
            frozenset((STORED, SELECTION, REIDENTIFY_COMMAND_LINE)),
        )
        for sensor in NOISE_FIELDS
    ),
    _one_of(
        'posture_order',
        'route',
        "Order the postures are commanded in: route (the shortest travel from the platform's "
        'current posture, docs/planning.md) or selection (the order the selection found them)',
        ('route', 'selection'),
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
    ParameterSpec(
        'controller_effects',
        'auto',
        'Whether the controller at platform_node_name compensates the identified effects '
        '(docs/platform_effects.md): compensated (it receives the geometry and its '
        'geometry.effects.*), rigid (it runs the geometry alone: it receives the best rigid '
        'geometry, the effects folded in), auto (compensated when it declares geometry.effects.* '
        'parameters, asked through its list_parameters service before the apply)',
        constraints='auto, compensated or rigid',
        check=one_of(('auto', 'compensated', 'rigid')),
    ),
    # keeping a platform calibrated (docs/upkeep.md)
    ParameterSpec(
        'platform_id',
        'default',
        'Which platform this calibrator calibrates and checks: every calibration and check is '
        'indexed under it in <output_root>/history.sqlite (gsp_history), and a check checks its '
        'latest accepted calibration',
        constraints="1-64 of letters, digits, '-', '_', '.'",
        check=lambda v: '' if _PLATFORM_ID.match(str(v)) else 'must be 1-64 of [A-Za-z0-9_.-]',
        subsets=frozenset((STORED,)),
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
        subsets=frozenset((STORED,)),
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
        subsets=frozenset((STORED,)),
    ),
    ParameterSpec(
        'stop_minimum_postures',
        30,
        'With stop_when_accurate: the rows are first judged after this many postures (fewer '
        'give an optimistic cross-validation on a real platform: docs/upkeep.md)',
        constraints='>= 2',
        check=at_least(2),
        subsets=frozenset((STORED,)),
    ),
    ParameterSpec(
        'stop_every',
        2,
        'With stop_when_accurate: postures between two judgements (each identifies and '
        'cross-validates the rows so far in a worker thread while the next posture is collected)',
        constraints='>= 1',
        check=at_least(1),
        subsets=frozenset((STORED,)),
    ),
    ParameterSpec(
        'stop_max_added',
        60,
        'With stop_when_accurate: pool postures added at most after the planned ones',
        constraints='>= 0',
        check=at_least(0),
        subsets=frozenset((STORED,)),
    ),
    ParameterSpec(
        'reuse_rows_from',
        '',
        "A run directory (a check's, or another run's) whose samples.csv rows a new calibration "
        'identifies with its own (rows of the same platform and device); empty: none',
    ),
    parameter_specs.diagnostics_period_spec(),
)
PARAMETER_SPECS = {spec.name: spec for spec in PARAMETERS}
DEFAULTS = {spec.name: spec.default for spec in PARAMETERS}


def names_in(subset):
    """The names of the parameters in ``subset`` (:data:`STORED`...), in table order."""
    return tuple(spec.name for spec in PARAMETERS if subset in spec.subsets)


STORED_PARAMETERS = names_in(STORED)
SELECTION_PARAMETERS = names_in(SELECTION)
#: The calibrator's parameter of each ``acceptance.Requirement`` field.
REQUIREMENT_PARAMETERS = {
    'position_mm': 'required_position_accuracy_mm',
    'orientation_deg': 'required_orientation_accuracy_deg',
    'improvement': 'required_improvement_over_nominal',
}


def requirement_from_parameters(values):
    """The ``Requirement`` of the parameters ``values`` (a missing one: the core's default)."""
    return Requirement(
        **{f: float(values[name]) for f, name in REQUIREMENT_PARAMETERS.items() if name in values}
    )


#: The assumed noise parameters ``sigma_<sensor>`` (together, the settings' ``sigmas``).
SIGMA_PARAMETERS = noise_parameter_names(ASSUMED_NOISE_PARAMETER)


def option_name(name):
    """The command-line option of parameter ``name`` (``--pool-size``, ``--free``...)."""
    return _OPTION_NAMES.get(name, '--' + name.replace('_', '-'))


def option_value(name, value):
    """``value`` of parameter ``name`` given on a command line or stored with a run, checked by
    the parameter's own check and converted to the parameter's type; ValueError naming the option
    otherwise. ``free_parameters`` also takes comma-separated names."""
    default = DEFAULTS[name]
    try:
        if isinstance(default, list):
            value = [n.strip() for item in value for n in str(item).split(',') if n.strip()]
        elif not isinstance(default, str):
            value = type(default)(value)
    except (TypeError, ValueError):
        raise ValueError(
            f'{option_name(name)}: {value!r} rejected, not a {type(default).__name__}'
        ) from None
    reason = PARAMETER_SPECS[name].check(value) if PARAMETER_SPECS[name].check else ''
    if reason:
        raise ValueError(f'{option_name(name)}: {value!r} rejected, {reason}')
    return value


# --- command-line options of a run (gsp_demo, gsp_plan) ------------------------------------------


def add_run_options(parser, seed_help='seed of the posture pool'):
    """Add to ``parser`` the options of a run (:data:`RUN_COMMAND_LINE`) with the parameters'
    defaults; check the parsed values with :func:`run_options_error`."""
    for name in names_in(RUN_COMMAND_LINE):
        default = DEFAULTS[name]
        help_text = seed_help if name == 'seed' else PARAMETER_SPECS[name].description
        if isinstance(default, list):
            kind = {'nargs': '+', 'default': list(default), 'metavar': 'NAME'}
            help_text += f' (default: {" ".join(default)})'
        else:
            kind = {'type': type(default), 'default': default}
            help_text += f' ({default})'
        parser.add_argument(option_name(name), dest=name, help=help_text, **kind)


def run_options_error(args):
    """Reason ('' if none) why the options of :func:`add_run_options` in ``args`` are invalid;
    each value converted in place (:func:`option_value`)."""
    try:
        for name in names_in(RUN_COMMAND_LINE):
            setattr(args, name, option_value(name, getattr(args, name)))
    except ValueError as error:
        return str(error)
    return ''


def validate_parameters(changes, current=None):
    """Reason ('' if none) why ``changes`` ({name: value}) on top of ``current`` are invalid:
    each changed value checked alone, then ``posture_count <= pool_size``."""
    values = {**(DEFAULTS if current is None else current), **changes}
    reason = validate_values(PARAMETER_SPECS, changes)
    if not reason and values['posture_count'] > values['pool_size']:
        reason = (
            f'posture_count ({values["posture_count"]}) must not exceed pool_size '
            f'({values["pool_size"]})'
        )
    return reason


@dataclasses.dataclass(frozen=True)
class CalibratorSettings(ParameterFields):
    """The settings of one run: a typed field per parameter (``settings_fields.py``; lists as
    tuples) and ``nominal``, the loaded nominal ``Geometry``; built by :meth:`from_values`."""

    @functools.cached_property
    def sigmas(self):
        """The assumed per-sample noise (``SensorNoise`` of the ``sigma_<sensor>``, m and rad)."""
        return noise_from_parameters(self.options(SIGMA_PARAMETERS))

    @property
    def motion_limits(self):
        """The platform's leg limits the route is planned with."""
        return MotionLimits(self.max_leg_speed, self.max_leg_acceleration)

    @property
    def commanded_posture_count(self):
        """Postures a new run commands: the selected and the workspace (validation) ones."""
        return int(self.posture_count) + int(self.workspace_postures)

    @property
    def free_count(self):
        """Number of free parameters (the groups expanded)."""
        return int(resolve_free(self.free_parameters).sum())

    def options(self, names):
        """``{name: value}`` of the parameters ``names`` (e.g. :data:`STORED_PARAMETERS`), as
        JSON gives them (lists, not tuples)."""
        return {
            name: list(value) if isinstance(value, tuple) else value
            for name, value in ((name, getattr(self, name)) for name in names)
        }

    @property
    def requirement(self):
        """What the result must achieve to be applied (``acceptance.Requirement``)."""
        return requirement_from_parameters(vars(self))

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
            f'{self.pool_size}, {self.pairs_per_posture} samples each, {self.formulation} '
            f'formulation, {self.free_count} free parameters, output under '
            f'{os.path.abspath(self.output_root)}'
        )

    @classmethod
    def from_values(cls, values):
        """Settings from ``{name: value}`` (defaults for missing names); ValueError if invalid."""
        merged = {**DEFAULTS, **values}
        reason = validate_parameters(merged, merged)
        if reason:
            raise ValueError(reason)
        fields = {}
        for spec in PARAMETERS:
            value = merged[spec.name]
            fields[spec.name] = (
                tuple(value) if isinstance(spec.default, list) else type(spec.default)(value)
            )
        fields['platform_node_name'] = fields['platform_node_name'].lstrip('/')
        return cls(nominal=load_geometry(fields['nominal_geometry_file']), **fields)
