"""``state.json``: what a run was asked to do, how far it got and why it stopped (pure, no rclpy).

The calibrator rewrites it atomically (:mod:`gsp_kinematics.fileio`) at every step, so after any
fault (a dead sensor, a killed process, a full disk) the run directory says where to carry on.
``/gsp/calibrator/resume`` reads it back: :func:`validate_resume` refuses a resume whose options
would change the selection, or whose rows came from another nominal geometry or device, and
:func:`postures_to_collect` lists what is left. See docs/faults.md and docs/data.md.
"""

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from gsp_calibrator.settings import SELECTION_PARAMETERS
from gsp_kinematics.fileio import atomic_write_text, to_json
from gsp_kinematics.identification import resolve_free

STATE_FILE = 'state.json'
STATE_VERSION = 1

PHASE_COLLECTING = 'collecting'
PHASE_IDENTIFYING = 'identifying'
PHASE_FAILED = 'failed'  #: the run stopped on an error (``stop_reason`` names it)
PHASE_INTERRUPTED = 'interrupted'  #: the calibrator shut down during the run
PHASE_DONE = 'done'
#: Phases a run can be resumed from (``collecting`` only when its process is gone).
RESUMABLE_PHASES = (PHASE_COLLECTING, PHASE_IDENTIFYING, PHASE_FAILED, PHASE_INTERRUPTED)

#: Options of the selection (the parameters marked so), in the order a refusal names them.
SELECTION_OPTIONS = SELECTION_PARAMETERS
DEVICE_PARAMETERS = ('device_length', 'inclinometer_axes_angle')
POSE_TOLERANCE = 1e-9  #: m or rad: a samples.csv row and its selected posture agree to this


class ResumeRefused(ValueError):
    """A run cannot be resumed as asked; the message names the option or the reason."""


def _digest(values):
    data = np.round(np.asarray(values, dtype=float).reshape(-1), 12).tobytes()
    return hashlib.sha256(data).hexdigest()[:16]


def nominal_digests(nominal):
    """``(platform digest, device digest)`` of a nominal ``Geometry``."""
    device = [getattr(nominal, name) for name in DEVICE_PARAMETERS]
    platform = np.concatenate(
        [
            np.ravel(nominal.base_joints),
            np.ravel(nominal.platform_joints),
            np.ravel(nominal.leg_offsets),
        ]
    )
    return _digest(platform), _digest(device)


def selection_options(settings):
    """The options that decide the selection of ``settings`` (``CalibratorSettings``)."""
    platform, device = nominal_digests(settings.nominal)
    options = settings.options(SELECTION_OPTIONS)
    # Compared as the mask: 'paper' and its 44 names are the same selection.
    options['free_parameters'] = list(resolve_free(list(settings.free_parameters)))
    return {
        **options,
        'nominal_geometry_file': str(settings.nominal_geometry_file),
        'nominal_digest': platform,
        'device_digest': device,
    }


@dataclasses.dataclass
class RunState:
    """The content of ``state.json`` (postures are 1-based, in commanded order)."""

    selection: dict  #: :func:`selection_options` of the run
    poses: list  #: the selected postures, (count, 6) m and rad
    done: list = dataclasses.field(default_factory=list)  #: postures with a samples.csv row
    skipped: list = dataclasses.field(default_factory=list)  #: [{posture, reason}]
    phase: str = PHASE_COLLECTING
    stop_reason: str = ''
    sessions: int = 1  #: 1 + the number of resumes
    recordings: list = dataclasses.field(default_factory=list)  #: recording files, in order
    pid: int = 0  #: process of the calibrator of the current session
    #: [{rejected, replacement, reason}]: postures the platform rejected and those appended
    #: (1-based) in their place
    replacements: list = dataclasses.field(default_factory=list)
    #: {posture (str): {wait_s, moving_pairs}}: each kept row's rest wait, from the
    #: platform's settled status to the first averaged sample, and the pairs waited out as still
    #: settling (:mod:`gsp_calibrator.collection.synchroniser`)
    rest_waits: dict = dataclasses.field(default_factory=dict)
    #: postures added from the pool by a run that stops when it is good enough (the last of
    #: ``poses``)
    added: int = 0
    #: what the effect groups added to the route (``postures.route_additions``; {}: nothing):
    #: reference revisits and approach postures, each its own posture at a pose of the plan
    route_additions: dict = dataclasses.field(default_factory=dict)

    def to_dict(self):
        data = dataclasses.asdict(self)
        data['version'] = STATE_VERSION
        data['poses'] = np.asarray(self.poses, dtype=float).reshape(-1, 6).tolist()
        return data

    @classmethod
    def from_dict(cls, data, source=STATE_FILE):
        if not isinstance(data, dict) or data.get('version') != STATE_VERSION:
            raise ResumeRefused(f'{source}: not a version {STATE_VERSION} run state')
        fields = {f.name for f in dataclasses.fields(cls)}
        try:
            state = cls(**{k: v for k, v in data.items() if k in fields})
            state.poses = np.asarray(state.poses, dtype=float).reshape(-1, 6).tolist()
        except (TypeError, ValueError) as error:
            raise ResumeRefused(f'{source}: malformed ({error})') from None
        return state

    def record_skip(self, posture, reason):
        self.skipped = [s for s in self.skipped if s['posture'] != posture]
        self.skipped.append({'posture': int(posture), 'reason': str(reason)})

    def record_done(self, posture, sample=None):
        """``posture`` has its row; ``sample`` (its ``PostureRow``) gives its rest wait."""
        self.skipped = [s for s in self.skipped if s['posture'] != posture]
        if posture not in self.done:
            self.done.append(int(posture))
        if sample is not None:
            self.rest_waits[str(int(posture))] = {
                'wait_s': float(sample.rest_wait),
                'moving_pairs': int(sample.moving_pairs),
            }


def settle_statistics(waits):
    """``result.json`` ``collection.settle`` of the kept rows' rest waits (``rest_waits``):
    ``rows``, ``median_s``, ``max_s``, ``mean_s`` of the waits, ``waited``: the rows that
    waited for a channel still moving (not only for their first samples), and ``per_posture_s``
    (``{posture: wait_s}``, in posture order)."""
    entries = list(waits.values())
    values = np.array([entry['wait_s'] for entry in entries], dtype=float)
    if values.size == 0:
        return {
            'rows': 0,
            'median_s': None,
            'max_s': None,
            'mean_s': None,
            'waited': 0,
            'per_posture_s': {},
        }
    return {
        'rows': int(values.size),
        'median_s': float(np.median(values)),
        'max_s': float(values.max()),
        'mean_s': float(values.mean()),
        'waited': sum(1 for entry in entries if entry['moving_pairs'] > 0),
        'per_posture_s': {
            posture: float(waits[posture]['wait_s']) for posture in sorted(waits, key=int)
        },
    }


def write_state(directory, state):
    """Write ``directory/state.json`` atomically; returns its path."""
    return atomic_write_text(Path(directory) / STATE_FILE, to_json(state.to_dict()))


def read_state(directory):
    path = Path(directory) / STATE_FILE
    try:
        data = json.loads(path.read_text(encoding='utf-8'))
    except OSError as error:
        raise ResumeRefused(f'{path}: cannot read ({error.strerror})') from None
    except json.JSONDecodeError as error:
        raise ResumeRefused(f'{path}: not valid JSON ({error})') from None
    return RunState.from_dict(data, str(path))


def process_alive(pid):
    """Whether process ``pid`` exists (this host)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def resumable(state, own_pid=None):
    """Whether ``state`` is of an unfinished run no live calibrator is writing."""
    if state.phase not in RESUMABLE_PHASES:
        return False
    if state.phase in (PHASE_COLLECTING, PHASE_IDENTIFYING) and state.pid != own_pid:
        return not process_alive(state.pid)
    return True


def latest_unfinished_run(output_root, own_pid=None):
    """The newest run directory under ``output_root`` that can be resumed (ResumeRefused if none)."""
    root = Path(output_root)
    candidates = sorted(
        (p for p in root.glob('*') if (p / STATE_FILE).is_file()), key=lambda p: p.name
    )
    for path in reversed(candidates):
        try:
            if resumable(read_state(path), own_pid):
                return path
        except ResumeRefused:
            continue
    raise ResumeRefused(f'no unfinished run to resume under {root.resolve()}')


def validate_resume(state, settings, samples, own_pid=None):
    """Refuse (:class:`ResumeRefused`) a resume of ``state`` with ``settings`` and the run's
    ``samples`` (``Rows`` of its samples.csv) when they do not belong together. ``own_pid``:
    the resuming calibrator's process (a run it left unfinished, e.g. on a full disk whose
    state.json kept ``collecting``, is resumable)."""
    current = selection_options(settings)
    stored = state.selection
    if stored.get('device_digest') != current['device_digest']:
        raise ResumeRefused(
            'the run was collected with a different device (device_length or '
            'inclinometer_axes_angle of the nominal geometry differ): resume refused'
        )
    if stored.get('nominal_digest') != current['nominal_digest']:
        raise ResumeRefused(
            f'nominal geometry changed (the run used {stored.get("nominal_geometry_file")}, '
            f'now {current["nominal_geometry_file"]} with other values): resume refused'
        )
    for name in SELECTION_OPTIONS:
        if stored.get(name) != current[name]:
            raise ResumeRefused(
                f'option {name} changed since the run started ({stored.get(name)} -> '
                f'{current[name]}): it would change the selection; resume refused'
            )
    if not resumable(state, own_pid):
        if state.phase == PHASE_DONE:
            raise ResumeRefused('the run is finished (phase done): nothing to resume')
        raise ResumeRefused(
            f'the run is still being written by process {state.pid} (phase {state.phase})'
        )
    poses = np.asarray(state.poses, dtype=float)
    for m, posture in enumerate(samples.posture):
        if not 1 <= posture <= len(poses):
            raise ResumeRefused(f'samples.csv row {m + 1}: posture {posture} is not selected')
        if np.max(np.abs(samples.commanded_poses[m] - poses[posture - 1])) > POSE_TOLERANCE:
            raise ResumeRefused(
                f'samples.csv row {m + 1} (posture {posture}) was commanded at another pose '
                'than the selection: its samples come from a different selection or nominal'
            )


def postures_to_collect(state, samples):
    """The 1-based postures without a samples.csv row (skipped ones are tried again, except those
    a replacement stands in for)."""
    collected = set(int(k) for k in samples.posture)
    replaced = {int(r['rejected']) for r in state.replacements}
    return [k for k in range(1, len(state.poses) + 1) if k not in collected and k not in replaced]
