"""Accuracy of a controller geometry against the real (true) platform (docs/sensor_errors.md)."""

import dataclasses

import numpy as np

from ..rotation import euler_to_matrix, rotation_angle_between
from .device import device_readings
from .effect_groups import commanded_leg_readings
from .effects import approach_directions
from .kinematics import forward_kinematics_masked, inverse_kinematics
from .real_pose import real_poses


def commanded_articular(true, controller, commanded):
    """True articular variables (M, 6) the real legs take when ``controller`` drives
    ``commanded``: its leg readings ``IK / (1 + kq_controller)``, scaled by ``1 + kq_true``."""
    readings = controller.sensors.leg_readings(inverse_kinematics(controller, commanded))
    return true.sensors.true_leg_lengths(readings)


def sensor_measurements(true, poses):
    """What the real sensors read at ``poses`` (M, 6): leg readings (M, 6) and device readings
    ``[alpha, beta, phi, d_m]`` (M, 4), noise-free, with the true sensor errors."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    legs = true.sensors.leg_readings(inverse_kinematics(true, poses))
    return legs, true.sensors.device_readings(device_readings(true, poses))


def pose_errors(commanded, reached):
    """Position error (mm) and orientation error (deg, angle of R_cmd^T R_real) per posture."""
    commanded = np.atleast_2d(commanded)
    reached = np.atleast_2d(reached)
    position_mm = 1000.0 * np.linalg.norm(reached[:, :3] - commanded[:, :3], axis=1)
    orientation_deg = np.degrees(
        rotation_angle_between(euler_to_matrix(commanded[:, 3:]), euler_to_matrix(reached[:, 3:]))
    )
    return position_mm, orientation_deg


@dataclasses.dataclass(frozen=True)
class SimulatedRun:
    """A commanded sequence on a simulated real platform, noise-free, (M, ...) in order: commanded
    poses, leg readings (m), approach directions, times (s), real poses, device readings and
    ``reachable`` (M,) (False: no pose near the command, the row NaN)."""

    commanded: np.ndarray
    leg_readings: np.ndarray
    directions: np.ndarray
    times_s: np.ndarray
    real_poses: np.ndarray
    device_readings: np.ndarray
    reachable: np.ndarray


def simulate_commands(
    true, controller, commanded, effects=None, times_s=None, previous_readings=None
):
    """What the real platform (``true`` geometry and ``effects``) does when ``controller`` drives
    it through ``commanded`` (M, 6) in order at ``times_s`` (M,) s (default 0): a
    :class:`SimulatedRun`. ``previous_readings`` (6,): the legs' readings before (None: the
    first). A controller with identified effects compensates them."""
    commanded = np.atleast_2d(np.asarray(commanded, dtype=float))
    readings = commanded_leg_readings(controller, commanded, previous_readings)
    times = np.zeros(len(commanded)) if times_s is None else np.asarray(times_s, dtype=float)
    if times.shape != (len(commanded),):
        raise ValueError(f'times_s must have shape ({len(commanded)},), got {times.shape}')
    directions = approach_directions(readings, previous_readings)
    reached, ok = real_poses(true, effects, readings, commanded, directions, times)
    reached[~ok] = np.nan
    device = np.full((len(commanded), 4), np.nan)
    if ok.any():
        device[ok] = true.sensors.device_readings(device_readings(true, reached[ok]))
    return SimulatedRun(commanded, readings, directions, times, reached, device, ok)


def summarise(position_mm, orientation_deg):
    return {
        'position_mm_mean': float(np.mean(position_mm)),
        'position_mm_max': float(np.max(position_mm)),
        'orientation_deg_mean': float(np.mean(orientation_deg)),
        'orientation_deg_max': float(np.max(orientation_deg)),
    }


def validate(true, controller, commanded, effects=None, times_s=None):
    """Mean and max errors (mm, deg) over ``commanded`` postures (M, 6); a posture the real
    platform cannot assemble is counted in ``unreachable``. ``effects``: the real platform's."""
    commanded = np.atleast_2d(commanded)
    if (effects is None or effects.ideal) and controller.effects.none:
        articular = commanded_articular(true, controller, commanded)
        reached, converged = forward_kinematics_masked(true, articular, commanded)
    else:
        run = simulate_commands(true, controller, commanded, effects, times_s)
        reached, converged = run.real_poses, run.reachable
    if not converged.any():
        raise ValueError('no validation posture is reachable by the real platform')
    position_mm, orientation_deg = pose_errors(commanded[converged], reached[converged])
    summary = summarise(position_mm, orientation_deg)
    summary['postures'] = int(converged.sum())
    summary['unreachable'] = int((~converged).sum())
    return summary
