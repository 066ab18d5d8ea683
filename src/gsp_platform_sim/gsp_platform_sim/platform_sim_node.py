"""``platform_sim`` node: a simulated Gough-Stewart platform (see docs/nodes.md)."""

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock as ClockMessage

from gsp_kinematics.channels import LEG_LENGTHS
from gsp_kinematics.model.geometry import GeometryError, load_geometry
from gsp_kinematics.model.motion import MotionLimits
from gsp_msgs_py import conversions, names, node_tools, parameter_specs
from gsp_msgs_py.diagnostics import Component, DiagnosticsPublisher
from gsp_msgs_py.geometry_parameters import (
    CONTROLLER_GEOMETRY_SPECS,
    GEOMETRY_PARAMETER_NAMES,
    controller_geometry,
    controller_geometry_error,
    validate_geometry_change,
)
from gsp_msgs_py.parameter_specs import ParameterSpec, at_least, one_of, positive_spec
from gsp_msgs_py.pose_commands import PoseCommandServer

from .effect_specs import EFFECT_SPECS, effects_from_values, effects_summary
from .markers import make_marker_array
from .physics import PhysicsSimulator
from .physics_specs import BACKENDS, PHYSICS_SPECS, physics_from_values
from .simulator import DEFAULT_MAX_CONDITION, PlatformSimulator

MARKER_RATE_HZ = 10.0
#: Random stream of this node: the device driver with the same ``seed`` draws independent noise.
RNG_STREAM = 1
#: Physics backend: the most simulated time (s) one publish tick catches up; beyond it the
#: simulation's clock slips behind the node's (a machine that cannot keep real time).
MAX_CATCH_UP_S = 0.05

PARAMETERS = (
    ParameterSpec(
        'backend',
        'kinematic',
        'kinematic: the rigid model with the effects as formulas (fast); physics: MuJoCo, '
        'servo-driven compliant legs, a ringing platform (docs/physics.md)',
        read_only=True,
        check=one_of(BACKENDS),
    ),
    parameter_specs.true_geometry_file_spec(
        'Geometry params file of the real (true) platform, read once at start-up; never published'
    ),
    *CONTROLLER_GEOMETRY_SPECS,
    parameter_specs.publish_rate_spec('leg_lengths and true_pose'),
    parameter_specs.true_noise_spec(
        LEG_LENGTHS, 'Standard deviation of the Gaussian leg length sensor noise'
    ),
    parameter_specs.seed_spec(),
    parameter_specs.settle_time_spec('an accepted command'),
    # Defaults: no limits, the platform jumps (quick demos and tests); the realistic limits are
    # gsp_kinematics.model.motion.MotionLimits() (docs/planning.md).
    *parameter_specs.motion_limit_specs(0.0, 0.0),
    ParameterSpec(
        'max_condition',
        DEFAULT_MAX_CONDITION,
        'Commands whose dq/dX condition number is not below this are rejected (singularity guard)',
        float_range=(1.0, 1e12),
        check=at_least(1.0),
    ),
    ParameterSpec(
        'publish_markers',
        True,
        f'Publish RViz markers on {names.TOPIC_MARKERS} at {MARKER_RATE_HZ:g} Hz',
        read_only=True,
    ),
    parameter_specs.frame_id_spec(
        'Base frame: of the published messages, and required of pose commands'
    ),
    parameter_specs.diagnostics_period_spec(),
    positive_spec(
        'real_time_factor',
        1.0,
        'physics backend: 1 runs the simulation in real time on the node clock; any other value '
        'makes the simulation the clock: it runs this many times faster than wall time and '
        'publishes /clock (the other nodes need use_sim_time true; docs/physics.md)',
        read_only=True,
    ),
    *EFFECT_SPECS,
    *PHYSICS_SPECS,
)


def _check_start_up(values):
    reason = controller_geometry_error(values)
    if reason:
        return f'controller geometry: {reason}'
    if values['real_time_factor'] != 1.0 and values['backend'] != 'physics':
        return 'real_time_factor is for the physics backend (the kinematic one is not timed)'
    return ''


class PlatformSimNode(Node):
    """Simulated platform; ``**kwargs`` go to ``Node`` (``context=``, ``parameter_overrides=``)."""

    def __init__(self, **kwargs):
        super().__init__(names.NODE_PLATFORM_SIM, **kwargs)
        values = parameter_specs.declare_parameters(self, PARAMETERS, validate=_check_start_up)
        try:
            true_geometry = load_geometry(values['true_geometry_file'])
        except GeometryError as error:
            raise parameter_specs.ConfigurationError(f'true_geometry_file: {error}') from None
        seed = parameter_specs.resolve_seed(values['seed'])
        self._physics = values['backend'] == 'physics'
        try:
            effects = effects_from_values(values)
            self._simulator = self._make_simulator(
                values, true_geometry, controller_geometry(values), effects, seed
            )
        except ValueError as error:
            raise parameter_specs.ConfigurationError(str(error)) from None
        self._frame_id = values['frame_id']
        self._values = values  # kept current by _apply_parameters
        parameter_specs.watch_parameters(
            self, PARAMETERS, apply=self._apply_parameters, validate=validate_geometry_change
        )

        # All callbacks in the node's default (mutually exclusive) group: no locking needed.
        self._pubs = node_tools.create_publishers(
            self,
            (names.TOPIC_LEG_LENGTHS, names.TOPIC_TRUE_POSE)
            + ((names.TOPIC_DEVICE_TRUTH,) if self._physics else ())
            + ((names.TOPIC_MARKERS,) if values['publish_markers'] else ()),
        )
        self._travel_s = 0.0  # of the command just accepted
        self._commands = PoseCommandServer(
            self,
            self._frame_id,
            # physics: the controller reports "in position" itself (report mode)
            None if self._physics else values['settle_time'],
            self._move,
            travel_s=lambda: self._travel_s,
        )
        self._diagnostics = DiagnosticsPublisher(
            self,
            values['diagnostics_period'],
            [Component('commands', names.STATUS_HARDWARE_ID, self._commands.health)],
        )
        self._tick_s = 1.0 / values['publish_rate']
        self._clock_pub = None  # the simulation as the clock (real_time_factor != 1)
        if self._physics and values['real_time_factor'] != 1.0:
            self._clock_pub = self.create_publisher(ClockMessage, '/clock', 10)
            self.set_parameters([Parameter('use_sim_time', value=True)])
            self._state_timer = self.create_timer(
                self._tick_s / values['real_time_factor'],
                self._publish_simulated,
                clock=Clock(clock_type=ClockType.STEADY_TIME),
            )
        else:
            self._state_timer = self.create_timer(self._tick_s, self._publish_state)
        if values['publish_markers']:
            self.create_timer(1.0 / MARKER_RATE_HZ, self._publish_markers)

        self.get_logger().info(
            f'platform_sim ready ({values["backend"]} backend): '
            f'true geometry from {values["true_geometry_file"]}, '
            f'publishing at {values["publish_rate"]:g} Hz, '
            f'leg noise {values["leg_lengths_noise_std"]:g} m, '
            f'settle time {values["settle_time"]:g} s, leg limits '
            f'{values["max_leg_speed"]:g} m/s and {values["max_leg_acceleration"]:g} m/s^2 '
            f'(0: none), seed {seed}, '
            f'home pose {self._simulator.true_pose.round(6).tolist()}; {effects_summary(effects)}'
        )

    def _make_simulator(self, values, true_geometry, controller, effects, seed):
        common = dict(
            leg_lengths_noise_std=values['leg_lengths_noise_std'],
            rng=np.random.default_rng([seed, RNG_STREAM]),
            max_condition=values['max_condition'],
            limits=MotionLimits.from_parameters(
                values['max_leg_speed'], values['max_leg_acceleration']
            ),
            start_s=self._now_s(),
        )
        if not self._physics:
            return PlatformSimulator(true_geometry, controller, effects=effects, **common)
        if not effects.ideal:
            raise ValueError('effects.* are for the kinematic backend: the physics makes its own')
        params, window, hold = physics_from_values(values)
        return PhysicsSimulator(
            true_geometry,
            controller,
            params,
            in_position_window=window,
            in_position_time=hold,
            **common,
        )

    def _apply_parameters(self, changes):
        """Apply accepted run-time changes (checked by parameter_specs.watch_parameters)."""
        values = self._values
        values.update(changes)
        for name in ('leg_lengths_noise_std', 'max_condition'):
            if name in changes:
                setattr(self._simulator, name, changes[name])
        if 'settle_time' in changes and not self._physics:
            self._commands.settle_time = changes['settle_time']
        if {'max_leg_speed', 'max_leg_acceleration'} & set(changes):
            # From the next command (a move under way keeps its profile).
            self._simulator.limits = MotionLimits.from_parameters(
                values['max_leg_speed'], values['max_leg_acceleration']
            )
        changed = sorted(name for name in changes if name in GEOMETRY_PARAMETER_NAMES)
        if changed:
            self._simulator.controller_geometry = controller_geometry(values)
            self.get_logger().info(
                f'controller geometry updated ({", ".join(changed)}); applies from the next '
                'pose command'
            )

    def _move(self, command_id, pose):
        """PoseCommandServer callback: move to ``pose`` (m, rad); '' or the rejection reason."""
        now_s = self._simulator.time_s if self._clock_pub else self._now_s()
        outcome = self._simulator.command(pose, now_s)
        self._travel_s = outcome.travel_s
        if outcome.accepted:
            self.get_logger().debug(f'pose command {command_id} accepted: {pose.tolist()}')
        return '' if outcome.accepted else outcome.reason

    def _now_s(self):
        return self.get_clock().now().nanoseconds * 1e-9

    def _publish_state(self):
        # Stamped at the timer's scheduled tick, as a sensor sampling on its own clock: the
        # callback's delay would jitter the leg-length stamps against the device's.
        tick = node_tools.timer_tick_time(self, self._state_timer)
        if self._physics:
            self._publish_physics(tick.nanoseconds * 1e-9)
            return
        self._simulator.update(tick.nanoseconds * 1e-9)
        self._publish_samples(tick.to_msg())

    def _publish_simulated(self):
        """The simulation as the clock: one publish period simulated per (scaled) wall tick,
        whatever it takes; /clock says the simulated instant."""
        tick_s = self._simulator.time_s + self._tick_s
        self._simulator.advance(tick_s)
        self._clock_pub.publish(ClockMessage(clock=conversions.seconds_to_stamp(tick_s)))
        self._publish_physics(tick_s)

    def _publish_physics(self, tick_s):
        """Simulate up to the tick (at most ``MAX_CATCH_UP_S``, then the simulation's clock
        slips), publish the state stamped at the simulated instant, report "in position"."""
        simulator = self._simulator
        simulator.advance(min(tick_s, simulator.time_s + MAX_CATCH_UP_S))
        simulator.slip_to(tick_s)
        stamp = conversions.seconds_to_stamp(simulator.time_s)
        self._publish_samples(stamp)
        self._pubs[names.TOPIC_DEVICE_TRUTH].publish(
            conversions.device_truth_to_msg(simulator.device_readings(), stamp, self._frame_id)
        )
        moving = self._commands.moving
        if moving is not None and simulator.in_position:
            self._commands.settled(moving)

    def _publish_samples(self, stamp):
        self._pubs[names.TOPIC_LEG_LENGTHS].publish(
            conversions.leg_lengths_to_msg(
                self._simulator.measured_leg_lengths(), stamp, self._frame_id
            )
        )
        self._pubs[names.TOPIC_TRUE_POSE].publish(
            conversions.pose_to_pose_stamped(self._simulator.true_pose, stamp, self._frame_id)
        )

    def _publish_markers(self):
        self._pubs[names.TOPIC_MARKERS].publish(
            make_marker_array(
                self._simulator.controller_geometry,
                self._simulator.true_pose,
                self.get_clock().now().to_msg(),
                self._frame_id,
            )
        )


def main(args=None):
    """Console script ``platform_sim``; returns 1 if the parameters prevent start-up."""
    return node_tools.run_node(PlatformSimNode, args, logger_name=names.NODE_PLATFORM_SIM)


if __name__ == '__main__':
    raise SystemExit(main())
