"""The platform on a physics engine (MuJoCo): servo-driven compliant legs, a ringing platform and a
device whose inclinometer is an accelerometer (pure, no rclpy; docs/physics.md).
"""

import math

import mujoco
import numpy as np

from gsp_kinematics.model.device import position_to_inclinations
from gsp_kinematics.model.kinematics import check_reachable, home_pose
from gsp_kinematics.model.motion import LegMove, MotionLimits
from gsp_kinematics.rotation import matrix_to_euler

from .physics_model import PhysicalParameters, build_mjcf
from .simulator import DEFAULT_MAX_CONDITION, CommandOutcome, PlatformSimulator

#: An encoder is in position within this distance of its target (m).
DEFAULT_IN_POSITION_WINDOW = 1e-6
#: ... for this long (s) before the controller reports the move done.
DEFAULT_IN_POSITION_TIME = 0.01
#: Simulated time (s) the platform is given at start-up to come to rest at the initial pose once
#: the encoders are in position (at most START_UP_TIMEOUT_S after the move to it).
START_UP_S = 1.0
START_UP_TIMEOUT_S = 10.0


class PhysicsSimulator:
    """The platform built to ``true_geometry`` driven by a controller using
    ``controller_geometry``; ``leg_lengths_noise_std`` in m, starting at ``start_s`` (s)."""

    def __init__(
        self,
        true_geometry,
        controller_geometry,
        params=PhysicalParameters(),
        leg_lengths_noise_std=0.0,
        rng=None,
        max_condition=DEFAULT_MAX_CONDITION,
        initial_pose=None,
        limits=None,
        in_position_window=DEFAULT_IN_POSITION_WINDOW,
        in_position_time=DEFAULT_IN_POSITION_TIME,
        start_s=0.0,
    ):
        start = home_pose() if initial_pose is None else np.asarray(initial_pose, dtype=float)
        # The kinematic platform vets commands and gives the controller's leg readings.
        self._checker = PlatformSimulator(
            true_geometry, controller_geometry, 0.0, rng, max_condition, start
        )
        self._true_geometry = true_geometry
        self.params = params
        self.limits = limits
        self.leg_lengths_noise_std = float(leg_lengths_noise_std)  #: m
        self.in_position_window = float(in_position_window)
        self.in_position_time = float(in_position_time)
        self._rng = rng if rng is not None else np.random.default_rng()
        reference = home_pose()
        self._model = mujoco.MjModel.from_xml_string(
            build_mjcf(true_geometry, params, reference[2])
        )
        self._data = mujoco.MjData(self._model)
        self._time_offset = float(start_s)  # the simulation's t = 0 on the caller's clock
        self._index_model(true_geometry, reference)
        self._integral = np.zeros(6)
        self._target = self._checker.leg_lengths  # encoder readings the servos go to (m)
        # From the model's zero to the initial pose as a move, then at rest (START_UP_S more).
        self._move = LegMove(self.leg_lengths, self._target, self._limits, 0.0)
        self._in_position_since = None
        self._commanded_pose = start.copy()
        give_up_s = self._move.end_s + START_UP_TIMEOUT_S
        while not self.in_position and self._data.time < give_up_s:
            self.advance(self.time_s + 0.05)
        self.advance(self.time_s + START_UP_S)
        self._time_offset = float(start_s) - self._data.time  # at rest at start_s

    def _index_model(self, geometry, reference):
        model = self._model
        servos = [model.joint(f'leg_{i + 1}_servo').id for i in range(6)]
        self._servo_qpos = model.jnt_qposadr[servos]
        self._servo_dof = model.jnt_dofadr[servos]
        platform_points = geometry.platform_joints + reference[:3]
        lengths = np.linalg.norm(platform_points - geometry.base_joints, axis=1)
        # servo slide s = real articular variable + L_off - (leg length at the model's zero)
        self._slide_offset = geometry.leg_offsets - lengths
        self._leg_gains = 1.0 + geometry.sensors.leg_gain_errors
        self._platform = model.body('platform').id
        self._device_top = model.body('device_top').id
        self._lvdt = model.jnt_qposadr[model.joint('device_lvdt').id]
        self._device_zero = float(reference[2]) - geometry.device_length  # d_m at slide 0
        self._inclinometer = model.sensor('inclinometer').adr[0]
        # What a servo's acceleration feedforward moves: its screw, its leg, its share of the top.
        params = self.params
        self._moved_mass = (
            params.servo_inertia
            + params.leg_rod_mass
            + (params.platform_mass + params.payload_mass) / 6.0
        )

    @property
    def time_s(self):
        """The simulation clock (s), on the clock of ``start_s``."""
        return self._time_offset + self._data.time

    @property
    def controller_geometry(self):
        """The controller's geometry, used from the next command (the kinematic checker's)."""
        return self._checker.controller_geometry

    @controller_geometry.setter
    def controller_geometry(self, geometry):
        self._checker.controller_geometry = geometry

    @property
    def max_condition(self):
        return self._checker.max_condition

    @max_condition.setter
    def max_condition(self, value):
        self._checker.max_condition = float(value)

    @property
    def limits(self):
        return self._limits

    @limits.setter
    def limits(self, limits):
        self._limits = MotionLimits() if limits is None or limits.instantaneous else limits

    @property
    def in_position(self):
        """The controller's "in position": the move is over and the encoders have been within
        ``in_position_window`` of their targets for ``in_position_time``."""
        return (
            self._in_position_since is not None
            and self._data.time - self._in_position_since >= self.in_position_time - 1e-12
        )

    @property
    def leg_lengths(self):
        """Noise-free encoder readings q (6,) (m): the servo slides, over the true leg gains."""
        slides = self._data.qpos[self._servo_qpos]
        return (slides - self._slide_offset) / self._leg_gains

    def measured_leg_lengths(self):
        """Encoder readings plus Gaussian noise of std ``leg_lengths_noise_std`` (m)."""
        return self.leg_lengths + self._rng.normal(0.0, self.leg_lengths_noise_std, size=6)

    @property
    def true_pose(self):
        """The platform's pose (6,) ``[x, y, z, psi, theta, phi]`` (m, rad) in the simulation."""
        data = self._data
        rotation = data.xmat[self._platform].reshape(3, 3)
        return np.concatenate([data.xpos[self._platform], matrix_to_euler(rotation)])

    def device_readings(self):
        """Noise-free device readings ``[alpha, beta, phi, d_m]`` (rad, rad, rad, m) of the
        chain now (before the device's sensor errors)."""
        data = self._data
        force = data.sensordata[self._inclinometer : self._inclinometer + 3]
        # The link's frame is R_Y(beta) R_X(-alpha): the specific force in it is
        # |f| (-sin b, -sin a cos b, cos a cos b) (gamma = pi/2).
        beta = math.atan2(-force[0], math.hypot(force[1], force[2]))
        alpha = math.atan2(-force[1], force[2])
        direction = np.array(
            [math.cos(alpha) * math.sin(beta), math.sin(alpha), math.cos(alpha) * math.cos(beta)]
        )
        alpha, beta = position_to_inclinations(
            direction, self._true_geometry.inclinometer_axes_angle
        )
        top = data.xmat[self._device_top].reshape(3, 3)
        phi = math.atan2(top[1, 0], top[1, 1])  # eq 2: R[1,0] = cos psi sin phi
        d_m = data.qpos[self._lvdt] + self._device_zero
        return np.array([float(alpha), float(beta), phi, d_m])

    def _slide(self, readings):
        return readings * self._leg_gains + self._slide_offset

    def advance(self, until_s):
        """Simulate up to ``until_s`` (s, the clock of ``start_s``), one time step at a time."""
        model, data, params = self._model, self._data, self.params
        step = model.opt.timestep
        count = int(math.floor((until_s - self._time_offset - data.time) / step + 0.5))
        if count <= 0:
            return
        references, feedforward = self._servo_references(count)
        servo_qpos, servo_dof = self._servo_qpos, self._servo_dof
        kp, ki = params.servo_kp, params.servo_ki
        arrival = math.inf if self._move is None else self._move.end_s
        target = self._slide(self._target)
        window = self.in_position_window * self._leg_gains
        for index in range(count):
            error = references[index] - data.qpos[servo_qpos]
            self._integral += error * step
            # PI on the position with velocity and acceleration feedforward; the velocity gain
            # is the slide's damping (integrated implicitly).
            data.qfrc_applied[servo_dof] = kp * error + ki * self._integral + feedforward[index]
            mujoco.mj_step(model, data)
            # The controller's "in position": the move is over, the encoders in the window.
            if data.time < arrival - 0.5 * step and self._move is not None:
                self._in_position_since = None
            elif np.any(np.abs(data.qpos[servo_qpos] - target) > window):
                self._in_position_since = None
            elif self._in_position_since is None:
                self._in_position_since = data.time
        if self._move is not None and data.time >= arrival - 0.5 * step:
            self._move = None

    def _servo_references(self, count):
        """The servo slides' references (count, 6) m for the next ``count`` steps and their
        feedforward forces (count, 6) N (velocity and acceleration)."""
        step = self._model.opt.timestep
        if self._move is None:
            reference = self._slide(self._target)
            return np.broadcast_to(reference, (count, 6)), np.zeros((count, 6))
        times = self._data.time + step * np.arange(-1, count + 1)
        slides = self._slide(np.array([self._move.legs(t) for t in times]))
        velocity = (slides[2:] - slides[1:-1]) / step
        acceleration = (slides[2:] - 2.0 * slides[1:-1] + slides[:-2]) / step**2
        feedforward = self.params.servo_kd * velocity + self._moved_mass * acceleration
        return slides[1:-1], feedforward

    def slip_to(self, now_s):
        """If the simulation is behind ``now_s`` (s), move its clock there without simulating the
        gap: a machine that cannot keep real time loses simulated time, never speeds it up."""
        self._time_offset += max(0.0, now_s - self.time_s)

    def command(self, pose, now_s=None):
        """Drive the platform to ``pose`` (6,) from the simulation's current time."""
        outcome = self._checker.command(pose, self.time_s)
        if not outcome.accepted:
            return outcome
        # Past a joint's stop, or near a singularity, compliant legs under load sag by
        # centimetres or snap to another assembly.
        ok, reasons = check_reachable(
            self._true_geometry, outcome.true_pose[None], self.max_condition
        )
        if not ok[0]:
            self._checker.command(self._commanded_pose, self.time_s)  # back to the legs' state
            reason = f'the real platform cannot hold it: {reasons[0]}'
            return CommandOutcome(False, reason, None, self.true_pose)
        now = self._data.time
        # From the servos' reference now (a command may supersede a move under way).
        start = self._target if self._move is None else self._move.legs(now)
        move = LegMove(start, outcome.commanded_leg_lengths, self._limits, now)
        self._target = outcome.commanded_leg_lengths.copy()
        self._move, self._in_position_since = move, None
        self._commanded_pose = np.asarray(pose, dtype=float).copy()
        return CommandOutcome(
            True, '', self._target.copy(), outcome.true_pose, float(move.duration_s)
        )
