"""Parameters of the ``calibrator`` node: names, defaults, units, checks (pure, no rclpy).

:data:`PARAMETERS` is the single source of the declarations (the node builds its
``ParameterDescriptor`` objects from it, the README table follows it); :func:`check_parameters`
gives the reason a set of values is rejected, at start-up and in the set-parameters callback;
:meth:`CalibratorSettings.from_values` turns accepted values into the settings of one run.
"""

import dataclasses
import math
import re

from gsp_kinematics.geometry import (
    PARAMETER_NAMES,
    GeometryError,
    default_geometry_path,
    load_geometry,
)
from gsp_kinematics.identification import FORMULATIONS, Sigmas

DEFAULT_SIGMAS = Sigmas()  # Table 3, first level: 0.001 deg and 0.001 mm


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """One parameter: its default (which fixes its ROS type), unit and description."""

    name: str
    default: object
    unit: str
    description: str
    constraints: str


PARAMETERS = (
    ParameterSpec('nominal_geometry_file', default_geometry_path('nominal'), '',
                  'Geometry params file of the nominal (design) geometry the identification '
                  'starts from; also used to choose reachable postures',
                  'a readable geometry params file'),
    ParameterSpec('posture_count', 60, '', 'Postures selected and commanded per calibration',
                  '>= 1 and <= pool_size'),
    ParameterSpec('pool_size', 600, '',
                  'Random reachable postures the selection (condition-number criterion) chooses '
                  'from', '>= posture_count'),
    ParameterSpec('samples_per_posture', 10, '',
                  'Synchronised (leg lengths, device) samples averaged per posture', '>= 1'),
    ParameterSpec('sync_tolerance', 0.0025, 's',
                  'Largest stamp difference of a leg-length sample and the device sample it is '
                  'paired with (about half the sensor period)', '>= 0'),
    ParameterSpec('settle_timeout', 5.0, 's',
                  "Longest wait for a commanded posture's 'settled' status after its first "
                  'status; a posture that does not settle is skipped', '> 0'),
    ParameterSpec('topic_timeout', 2.0, 's',
                  'Longest silence of a topic (or service) the run waits on before it ends with '
                  'an error naming it', '> 0'),
    ParameterSpec('seed', 0, '', 'Seed of the random posture pool', '>= 0'),
    ParameterSpec('free_parameters', list(PARAMETER_NAMES), '',
                  'Parameters identified (A1x..B6z, Loff1..Loff6, D0, gamma); the others keep '
                  'their nominal values', 'non-empty, known names, no duplicates'),
    ParameterSpec('formulation', 'implicit', '',
                  'Identification formulation: implicit (all sensors, poses as unknowns), fk '
                  "(device residuals through FK) or paper (the paper's eq 11)",
                  'one of ' + ', '.join(FORMULATIONS)),
    ParameterSpec('sigma_leg_lengths', DEFAULT_SIGMAS.leg_lengths, 'm',
                  'Noise std of one leg-length sample (weight of the leg residuals)', '> 0'),
    ParameterSpec('sigma_inclinometer', DEFAULT_SIGMAS.inclinometer, 'rad',
                  'Noise std of one inclinometer sample (alpha, beta)', '> 0'),
    ParameterSpec('sigma_encoder', DEFAULT_SIGMAS.encoder, 'rad',
                  'Noise std of one encoder sample (phi)', '> 0'),
    ParameterSpec('sigma_lvdt', DEFAULT_SIGMAS.lvdt, 'm',
                  'Noise std of one LVDT sample (d_m)', '> 0'),
    ParameterSpec('output_root', 'runs', '',
                  'Directory under which each run writes <UTC timestamp>/ (samples.csv, '
                  'result.yaml)', 'non-empty path'),
    ParameterSpec('apply_result', False, '',
                  'After a successful calibration, set the geometry.* parameters of '
                  'platform_node_name (its controller) through its parameter service', ''),
    ParameterSpec('platform_node_name', 'platform_sim', '',
                  'Node whose geometry.* parameters apply_result sets', 'a valid node name'),
)
PARAMETER_SPECS = {spec.name: spec for spec in PARAMETERS}
DEFAULTS = {spec.name: spec.default for spec in PARAMETERS}

_NODE_NAME = re.compile(r'^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$')


def _finite_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_free(value):
    names = list(value)
    if not names:
        return 'must name at least one parameter'
    unknown = [n for n in names if n not in PARAMETER_NAMES]
    if unknown:
        return (f'unknown parameter name(s) {unknown}; expected names among A1x..A6z, B1x..B6z, '
                'Loff1..Loff6, D0, gamma')
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


def _positive(value):
    return '' if _finite_number(value) and value > 0.0 else 'must be a finite number > 0'


_CHECKS = {
    'nominal_geometry_file': _check_geometry_file,
    'posture_count': lambda v: '' if v >= 1 else 'must be >= 1',
    'pool_size': lambda v: '' if v >= 1 else 'must be >= 1',
    'samples_per_posture': lambda v: '' if v >= 1 else 'must be >= 1',
    'sync_tolerance': lambda v: '' if _finite_number(v) and v >= 0.0 else 'must be finite and >= 0 s',
    'settle_timeout': _positive,
    'topic_timeout': _positive,
    'seed': lambda v: '' if v >= 0 else 'must be >= 0',
    'free_parameters': _check_free,
    'formulation': lambda v: '' if v in FORMULATIONS else f'must be one of {list(FORMULATIONS)}',
    'sigma_leg_lengths': _positive,
    'sigma_inclinometer': _positive,
    'sigma_encoder': _positive,
    'sigma_lvdt': _positive,
    'output_root': lambda v: '' if str(v).strip() else 'must not be empty',
    'apply_result': lambda v: '',
    'platform_node_name': lambda v: '' if _NODE_NAME.match(str(v)) else 'is not a valid node name',
}


def check_parameters(changes, current=None):
    """Reason ('' if none) why ``changes`` ({name: value}) on top of ``current`` are invalid.

    Each changed value is checked alone, then the combination (``posture_count <= pool_size``).
    """
    for name, value in changes.items():
        if name not in _CHECKS:
            continue
        reason = _CHECKS[name](value)
        if reason:
            shown = value if not isinstance(value, (list, tuple)) or len(value) < 8 else '[...]'
            return f'{name}: {shown!r} rejected, {reason}'
    merged = dict(DEFAULTS if current is None else current)
    merged.update(changes)
    if merged['posture_count'] > merged['pool_size']:
        return (f"posture_count ({merged['posture_count']}) must not exceed pool_size "
                f"({merged['pool_size']})")
    return ''


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
    sigmas: Sigmas  #: per-sample noise std (m, rad)
    output_root: str
    apply_result: bool
    platform_node_name: str

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
            sigmas=Sigmas(
                leg_lengths=float(merged['sigma_leg_lengths']),
                inclinometer=float(merged['sigma_inclinometer']),
                encoder=float(merged['sigma_encoder']),
                lvdt=float(merged['sigma_lvdt']),
            ),
            output_root=str(merged['output_root']),
            apply_result=bool(merged['apply_result']),
            platform_node_name=str(merged['platform_node_name']).lstrip('/'),
        )
