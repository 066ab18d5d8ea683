"""The ``sensor_dynamics`` section of ``make bench`` (docs/sensor_errors.md): the realistic device
(``gsp_demo --sensor-dynamics realistic``), collected by the calibrator's own protocol, with the
rest rule and with the old fixed settle and consistency rule.

Offline, on the pure core: the shipped real platform is driven by the nominal controller to the
60 postures the ``sensor_errors`` section selects; at each the platform jumps and reports
``settled`` after :data:`PLATFORM_SETTLE_S`. The device is
:class:`gsp_kinematics.model.sensor_dynamics.SensorDynamics` (its lag carried over from the previous
posture, its noise coloured), the legs are white, all at 200 Hz; every sample goes to a
:class:`~gsp_calibrator.collection.protocol.CollectionProtocol` with its stamp (receive time 1 ms
later), as the calibrator's node feeds it. The rows are identified (extended set) with weights
that are the rows' true noise (the std of a mean of ``pairs_per_posture`` AR(1) samples), so
the predicted accuracy (from the covariance) is what the noise alone allows: a ratio of
validation error to prediction above 1 is the bias the collection left. Validation: 50 other
postures, mean position error (mm).
"""

import math
import statistics

import numpy as np

from gsp_bench.nominal_sets import default_true_and_nominal
from gsp_bench.sensor_errors import POSTURES, SAMPLES, SIGMAS
from gsp_calibrator.collection import events
from gsp_calibrator.collection.protocol import CollectionProtocol
from gsp_calibrator.collection.synchroniser import ENCODER, INCLINOMETER, LEG_LENGTHS, LVDT
from gsp_calibrator.settings import DEFAULTS
from gsp_calibrator.tools.demo_commands import SENSOR_DYNAMICS
from gsp_kinematics.channels import DEVICE_CHANNELS, PHI_READING_COLUMN
from gsp_kinematics.estimation.identification import Options, identify
from gsp_kinematics.estimation.noise_estimate import ar1_std_of_mean
from gsp_kinematics.estimation.prediction import predicted_errors
from gsp_kinematics.model.kinematics import (
    Workspace,
    forward_kinematics_masked,
    sample_valid_postures,
)
from gsp_kinematics.model.sensor_dynamics import SensorDynamics
from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_kinematics.model.validation import commanded_articular, sensor_measurements, validate
from gsp_kinematics.planning.selection import select_postures
from gsp_kinematics.rotation import wrap_angle
from gsp_msgs_py import conversions, names

RATE_HZ = 200.0
PLATFORM_SETTLE_S = 0.02  #: the demo's platform_sim settle time
SETTLE_TIMEOUT_S = 5.0
NS = 1_000_000_000
#: The old rule: no look-back, and a trend never large enough to wait for.
OLD_RULE = {'rest_lookback': 0.0, 'rest_sigmas': 1e12}


def realistic_rule():
    return {
        'rest_lookback': DEFAULTS['rest_lookback'],
        'rest_sigmas': DEFAULTS['rest_sigmas'],
    }


def device_times():
    """``(response (4,), correlation (4,))`` s of ``[alpha, beta, phi, d_m]``, realistic."""
    device = SENSOR_DYNAMICS['realistic']['device']

    def per_reading(kind):
        return np.array([device[f'{channel.sensor}_{kind}'] for channel in DEVICE_CHANNELS])

    return per_reading('response_time'), per_reading('noise_correlation_time')


def row_noise(correlation, n=SAMPLES, sigmas=SIGMAS):
    """The true noise of a row (``SensorNoise``): per channel the std of the mean of ``n``
    stationary AR(1) samples at :data:`RATE_HZ` of correlation time ``correlation`` (4,) s."""
    factors = []
    for tc in correlation[[0, 2, 3]]:
        phi = math.exp(-1.0 / (RATE_HZ * tc)) if tc > 0 else 0.0
        factors.append(ar1_std_of_mean(1.0, phi, n))
    return SensorNoise(
        sigmas.leg_lengths / math.sqrt(n),
        sigmas.inclinometer * factors[0],
        sigmas.encoder * factors[1],
        sigmas.lvdt * factors[2],
    )


def collect_run(legs, readings, poses, rule, seed):
    """Feed the streams of every posture to a protocol with ``rule``; ``(rows legs (M, 6),
    readings (M, 4), commanded (M, 6), rest waits (M,) s, skipped, posture index (M,))``."""
    response, correlation = device_times()
    dynamics = SensorDynamics(response, correlation, 4, circular=[False, False, True, False])
    rng = np.random.default_rng(seed)
    device_std, leg_std = SIGMAS.readings(), SIGMAS.leg_lengths
    collection = CollectionProtocol(
        0.5 / RATE_HZ,
        SAMPLES,
        SIGMAS.channel_std(),
        topic_timeout=2.0,
        settle_timeout=SETTLE_TIMEOUT_S,
        **rule,
    )
    period = int(NS / RATE_HZ)
    now = 1_700_000_000 * NS
    dynamics.step(now / NS, readings[0], device_std, rng)  # at rest at the first posture
    rows, waits, skipped = [], [], 0
    for m in range(len(poses)):
        command_id = f'c{m}'
        collection.command(m + 1, poses[m], command_id, now)
        settled_at = now + int(PLATFORM_SETTLE_S * NS)
        done = None
        while done is None:
            now += period
            device = dynamics.step(now / NS, readings[m], device_std, rng)
            q = legs[m] + rng.normal(size=6) * leg_std
            out = []
            if settled_at is not None and now >= settled_at:
                status = conversions.parse_status(
                    conversions.make_status(command_id, names.STATE_SETTLED, '')
                )
                out += collection.status(status, now, start_ns=settled_at)
                settled_at = None
            received = now + 1_000_000
            out += collection.sample(LEG_LENGTHS, now, (q,), received)
            out += collection.sample(INCLINOMETER, now, (device[0], device[1]), received)
            out += collection.sample(ENCODER, now, (device[2],), received)
            out += collection.sample(LVDT, now, (device[3],), received)
            done = next((e for e in out if isinstance(e, events.FINAL_EVENTS)), None)
        if isinstance(done, events.RowReady):
            rows.append((done.sample.leg_lengths, done.sample.readings, done.pose, m))
            waits.append(done.sample.rest_wait)
        else:
            skipped += 1
    legs_rows, readings_rows, commanded, index = (np.array(x) for x in zip(*rows, strict=True))
    return legs_rows, readings_rows, commanded, np.array(waits), skipped, index


def _setting():
    true, nominal = default_true_and_nominal()
    workspace = Workspace()
    pool = sample_valid_postures(nominal, 600, np.random.default_rng(0), workspace)
    chosen, _ = select_postures(
        nominal, pool, POSTURES, SIGMAS.averaged([SAMPLES]), free='extended'
    )
    poses = pool[chosen]
    reached, ok = forward_kinematics_masked(true, commanded_articular(true, nominal, poses), poses)
    legs, readings = sensor_measurements(true, reached[ok])
    validation_poses = sample_valid_postures(nominal, 50, np.random.default_rng(1), workspace)
    return true, nominal, poses[ok], legs, readings, validation_poses


def run_rule(rule, seeds, setting=None):
    """Per seed: validation error (mm), predicted (mm), their ratio, mean rest wait (s)."""
    true, nominal, poses, legs, readings, validation_poses = setting or _setting()
    weights = row_noise(device_times()[1])
    runs = []
    for seed in seeds:
        rows_legs, rows_readings, commanded, waits, skipped, index = collect_run(
            legs, readings, poses, rule, seed
        )
        # The rows' device readings against the truth, in the rows' own noise.
        error = rows_readings - readings[index]
        error[:, PHI_READING_COLUMN] = wrap_angle(error[:, PHI_READING_COLUMN])
        z = error / weights.readings()
        result = identify(
            nominal,
            rows_legs,
            rows_readings,
            weights,
            free='extended',
            pose_guesses=commanded,
            options=Options(),
        )
        try:
            validation = validate(true, result.geometry, validation_poses)['position_mm_mean']
        except ValueError:  # the fit is so far off that no validation posture is reachable
            validation = math.inf
        position, _ = predicted_errors(
            result.geometry, result.covariance, validation_poses, result.free
        )
        predicted = float(position.mean())
        runs.append(
            {
                'validation_mm': validation,
                'predicted_mm': predicted,
                'ratio': validation / predicted,
                'row_error_rms_row_sigmas': float(np.sqrt(np.mean(z**2))),
                'alpha_error_max_deg': float(np.degrees(np.abs(error[:, 0]).max())),
                'settle_wait_mean_s': float(np.mean(waits)),
                'skipped': skipped,
                'chi2_p': result.goodness_of_fit.p_value,
            }
        )
    return runs


def _summary(runs):
    """Over seeds; a fit so far off that the validation reaches nothing counts as inf."""
    return {
        'ratio_median': statistics.median(r['ratio'] for r in runs),
        'ratio_of_means': statistics.mean(r['validation_mm'] for r in runs)
        / statistics.mean(r['predicted_mm'] for r in runs),
        'validation_mm_mean': statistics.mean(r['validation_mm'] for r in runs),
        'predicted_mm_mean': statistics.mean(r['predicted_mm'] for r in runs),
        'settle_wait_mean_s': statistics.mean(r['settle_wait_mean_s'] for r in runs),
        'row_error_rms_row_sigmas': statistics.median(r['row_error_rms_row_sigmas'] for r in runs),
        'alpha_error_max_deg': max(r['alpha_error_max_deg'] for r in runs),
        'unreachable_validations': sum(not math.isfinite(r['validation_mm']) for r in runs),
        'skipped': sum(r['skipped'] for r in runs),
        'fit_p_median': statistics.median(r['chi2_p'] for r in runs),
        'runs': runs,
    }


def run(quick=False):
    """The ``sensor_dynamics`` section (``quick``: fewer seeds)."""
    seeds = range(3 if quick else 10)
    setting = _setting()
    settle = _summary(run_rule(realistic_rule(), seeds, setting))
    old = _summary(run_rule(OLD_RULE, seeds, setting))
    response, correlation = device_times()
    return {
        'description': (
            'realistic device (alpha, beta, phi, d_m response times '
            f'{response.tolist()} s, noise correlation times {correlation.tolist()} s), '
            f'{POSTURES} selected postures, {SAMPLES} samples at {RATE_HZ:g} Hz, platform '
            f'settled {PLATFORM_SETTLE_S:g} s after each jump; offline through the collection '
            "protocol; weights: the rows' true noise; validation: mean position error over 50 "
            "postures (mm) / its prediction from the covariance; row error: the rows' device "
            "readings against the truth, RMS in the rows' own noise (1 when unbiased)"
        ),
        'target_ratio': 1.3,
        'settle_from_data': {'rule': realistic_rule(), **settle},
        'fixed_settle_and_consistency': {'rule': OLD_RULE, **old},
        'settle_wait_mean_s': settle['settle_wait_mean_s'],
    }
