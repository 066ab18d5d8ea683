"""The ``settle_ringing`` section of ``make bench`` (docs/sensor_errors.md): the rest rule on a
platform that rings after each move, offline through the collector (pure, no ROS).

After ``settled`` the platform still oscillates about its pose: a translation
``X exp(-t/T) sin(2 pi f t + phase)`` along a unit ``direction``, ``X`` set by the peak speed
``v0 = X 2 pi f``. The readings are the device model's (eq 9) at the displaced position, with
the inclinometer an accelerometer (as MEMS inclinometers are): it takes for vertical the
specific force ``a + g``, so the link's acceleration (taken at the platform end: the sensor sits
near the upper U joint) tilts its reading. ``phi`` does not ring (a translation).

Each posture's streams (200 Hz, the default noise, instant sensors) go to a
:class:`~gsp_calibrator.collection.synchroniser.SampleCollector` from the ``settled`` status on;
the row's device error is compared with the truth in the row's own (white) std, and its wait
(settled to the averaged window) is kept.
"""

import math

import numpy as np

from gsp_calibrator.collection.synchroniser import SampleCollector
from gsp_calibrator.settings import DEFAULTS
from gsp_kinematics.model.device import device_readings, position_to_inclinations
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.kinematics import sample_valid_postures
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE
from gsp_kinematics.rotation import wrap_angle

GRAVITY = 9.80665  #: m/s^2


def rotation_to_vertical(vectors):
    """(n, 3, 3): the least rotation taking each of ``vectors`` (n, 3) to +z."""
    unit = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    axis = np.cross(unit, [0.0, 0.0, 1.0])
    sin, cos = np.linalg.norm(axis, axis=1), unit[:, 2]
    axis = axis / np.where(sin > 0.0, sin, 1.0)[:, None]
    skew = np.zeros((len(unit), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    skew -= skew.transpose(0, 2, 1)
    return np.eye(3) + sin[:, None, None] * skew + (1.0 - cos)[:, None, None] * (skew @ skew)


def ringing_readings(geometry, pose, times, peak_speed, frequency, time_constant, direction, phase):
    """Noise-free readings ``[alpha, beta, phi, d_m]`` (n, 4) at ``times`` (n,) s after the
    settle of ``pose`` (6,) ringing as the module docstring says (m/s, Hz, s, unit (3,), rad)."""
    omega = 2.0 * math.pi * frequency
    amplitude = peak_speed / omega
    times = np.asarray(times, dtype=float)
    envelope = amplitude * np.exp(-times / time_constant)
    sin, cos = np.sin(omega * times + phase), np.cos(omega * times + phase)
    displacement = envelope * sin
    acceleration = envelope * (
        (time_constant**-2 - omega**2) * sin - 2.0 * omega / time_constant * cos
    )
    direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    position = np.asarray(pose[:3], dtype=float) + displacement[:, None] * direction
    specific_force = acceleration[:, None] * direction + [0.0, 0.0, GRAVITY]
    seen = np.einsum('nij,nj->ni', rotation_to_vertical(specific_force), position)
    alpha, beta = position_to_inclinations(seen, geometry.inclinometer_axes_angle)
    d_m = np.linalg.norm(position, axis=1) - geometry.device_length
    return np.stack([alpha, beta, np.full(len(times), pose[5]), d_m], axis=1)


def at_rest_readings(geometry, pose):
    """The readings (4,) of ``pose`` once the ringing has died out."""
    return device_readings(geometry, np.asarray(pose, dtype=float)[None])[0]


RATE_HZ = 200.0  #: the simulated sensors' default rate
TRUTH = default_geometry('true')
#: (peak speed m/s, frequency Hz, time constant s) of the ringing cases; None: a still platform.
RINGS = {
    'still': None,
    '2 Hz, 0.1 s': (4e-4, 2.0, 0.1),
    '5 Hz, 0.1 s': (4e-4, 5.0, 0.1),
    '10 Hz, 0.05 s': (4e-4, 10.0, 0.05),
    '2 Hz, 0.25 s': (4e-4, 2.0, 0.25),
    '5 Hz, 0.25 s': (4e-4, 5.0, 0.25),
}


def default_rule():
    """The calibrator's rest rule: ``{rest_lookback, rest_sigmas}``."""
    return {key: DEFAULTS[key] for key in ('rest_lookback', 'rest_sigmas')}


def collect(poses, ring, seed, rule=None, noise_std=True, seconds=3.0):
    """Rows of ``poses`` (M, 6) collected at ``rule`` (default :func:`default_rule`) from
    200 Hz streams with the default noise, the platform ringing ``ring`` (:data:`RINGS`) from
    the settle on; ``noise_std`` False: the collector without the configured noise (the trend
    test alone). ``(errors (M, 4) in the rows' white stds, waits (M,) s)``; a posture with no
    row within ``seconds`` gives NaN."""
    rng = np.random.default_rng(seed)
    noise = DEFAULT_SENSOR_NOISE
    samples = DEFAULTS['pairs_per_posture']
    collector = SampleCollector(
        0.5 / RATE_HZ,
        samples,
        noise_std=noise.channel_std() if noise_std else None,
        **(rule or default_rule()),
    )
    times = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    period, start = int(1e9 / RATE_HZ), 10**18
    errors, waits = np.full((len(poses), 4), np.nan), np.full(len(poses), np.nan)
    for m, pose in enumerate(poses):
        truth = at_rest_readings(TRUTH, pose)
        clean = np.tile(truth, (len(times), 1))
        if ring is not None:
            direction, phase = rng.normal(size=3), rng.uniform(0.0, 2.0 * math.pi)
            clean = ringing_readings(TRUTH, pose, times, *ring, direction, phase)
        readings = clean + rng.normal(size=clean.shape) * noise.readings()
        collector.start(start)
        for i, values in enumerate(readings):
            stamp = start + i * period
            collector.add_leg_lengths(stamp, 0.6 + rng.normal(size=6) * noise.leg_lengths)
            collector.add_inclinometer(stamp, values[0], values[1])
            collector.add_encoder(stamp, values[2])
            collector.add_lvdt(stamp, values[3])
            if collector.ready():
                row = collector.take_posture()
                error = row.readings - truth
                error[2] = wrap_angle(error[2])
                errors[m] = error / (noise.readings() / math.sqrt(samples))
                waits[m] = row.rest_wait
                break
        collector.stop()
        start += (len(times) + 10) * period
    return errors, waits


def case(ring, seeds, postures, **options):
    """Over ``seeds``: the rows' worst channel RMS error (row stds; 1: noise alone), the
    median and largest wait (s), the postures with no row."""
    pose_rng = np.random.default_rng(0)
    poses = sample_valid_postures(default_geometry('nominal'), postures, pose_rng)
    runs = [collect(poses, ring, seed, **options) for seed in seeds]
    errors = np.concatenate([e for e, _ in runs])
    waits = np.concatenate([w for _, w in runs])
    done = np.isfinite(waits)
    return {
        'row_error_rms_row_stds': float(np.sqrt(np.mean(errors[done] ** 2, axis=0)).max()),
        'wait_median_s': float(np.median(waits[done])),
        'wait_max_s': float(waits[done].max()),
        'no_row': int(np.sum(~done)),
    }


RULES = {
    'default': {},
    'window_alone': {'rule': {'rest_lookback': 0.0, 'rest_sigmas': 3.0}},
    'trend_test_alone': {'noise_std': False},
}


def run(quick=False):
    """The ``settle_ringing`` section (``quick``: fewer seeds and postures)."""
    seeds, postures = (range(1), 10) if quick else (range(3), 20)
    return {
        'description': (
            'a platform ringing after each move (peak speed, frequency, envelope time '
            'constant), the inclinometer an accelerometer; 200 Hz, default noise, instant '
            "sensors; offline through the collector; row error: the rows' device readings "
            "against the truth, RMS of the worst channel in the rows' own std (1: noise "
            'alone); wait: settled to the averaged window. Rules: the default '
            f'{default_rule()}, the window alone (rest_lookback 0), the trend test alone '
            '(no configured noise: no scatter test)'
        ),
        'seeds': list(seeds),
        'postures': postures,
        **{
            name: {ring: case(RINGS[ring], seeds, postures, **options) for ring in RINGS}
            for name, options in RULES.items()
        },
    }
