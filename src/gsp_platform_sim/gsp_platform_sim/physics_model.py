"""A MuJoCo closed-chain model of a Gough-Stewart platform and its measuring device (no rclpy;
docs/physics.md). Explicit integration: keep ``sqrt(k / m) * timestep`` below ~0.9."""

import dataclasses
import math

import numpy as np

from gsp_kinematics.rotation import matrix_to_quaternion

#: Standard gravity (m/s^2).
GRAVITY = 9.81


#: Each field of :class:`PhysicalParameters`: (unit, description).
FIELD_DOCS = {
    'platform_mass': ('kg', "the moving platform's structure"),
    'platform_inertia': ('kg m^2', "the platform's principal moments of inertia (x, y, z)"),
    'payload_mass': ('kg', 'the payload on the platform'),
    'payload_center': ('m', "the payload's centre of mass, platform frame"),
    'leg_housing_mass': ('kg', "a leg's cylinder and motor, turning with the base U joint"),
    'leg_rod_mass': ('kg', "a leg's rod and nut beyond its spring (keeps the spring stable)"),
    'leg_stiffness': ('N/m', 'axial stiffness of a leg (.inf: rigid)'),
    'leg_damping': ('N s/m', 'axial damping of a leg'),
    'servo_inertia': ('kg', "the screw's and motor's inertia reflected on a leg's slide"),
    'servo_kp': ('N/m', "the servo's position gain"),
    'servo_ki': ('N/(m s)', "the servo's integral gain"),
    'servo_kd': ('N s/m', "the servo's velocity gain"),
    'joint_damping': ('N m s/rad', "every passive joint's viscous friction"),
    'device_link_mass': ('kg', "the device's lower link, carrying the inclinometer"),
    'device_slide_mass': ('kg', "the LVDT's moving part"),
    'device_top_mass': ('kg', "the encoder's body welded to the platform"),
    'inclinometer_height': ('m', 'the inclinometer on the link, from the base origin'),
    'timestep': (
        's',
        'simulation step: keep sqrt(leg_stiffness / leg_rod_mass) * timestep near 1 or below (springs are explicit)',
    ),
    'gravity': ('', 'gravity on (false: no load on the legs)'),
}


@dataclasses.dataclass(frozen=True)
class PhysicalParameters:
    """Masses (kg), stiffness (N/m), servo gains and damping of the simulated platform."""

    platform_mass: float = 40.0
    platform_inertia: tuple = (6.4, 6.4, 12.8)  # a 0.8 m radius plate of 40 kg
    payload_mass: float = 0.0
    payload_center: tuple = (0.0, 0.0, 0.1)
    leg_housing_mass: float = 5.0
    leg_rod_mass: float = 7.0
    leg_stiffness: float = 3.0e7
    leg_damping: float = 2.0e3
    servo_inertia: float = 150.0
    servo_kp: float = 2.4e6
    servo_ki: float = 6.0e6
    servo_kd: float = 2.6e4
    joint_damping: float = 1.0
    device_link_mass: float = 1.0
    device_slide_mass: float = 0.5
    device_top_mass: float = 0.3
    inclinometer_height: float = 0.3
    timestep: float = 5e-4
    gravity: bool = True

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            values = value if isinstance(value, tuple) else (value,)
            for number in values:
                if isinstance(number, bool):
                    continue
                if not (isinstance(number, int | float) and not math.isnan(number)):
                    raise ValueError(f'{field.name} must be a number, got {value!r}')
        positive = [
            name
            for name in (
                'platform_mass',
                'leg_housing_mass',
                'leg_rod_mass',
                'leg_stiffness',
                'servo_inertia',
                'device_link_mass',
                'device_slide_mass',
                'device_top_mass',
                'timestep',
            )
            if not getattr(self, name) > 0.0
        ]
        if positive or not all(v > 0 for v in self.platform_inertia):
            raise ValueError(f'must be > 0: {", ".join(positive) or "platform_inertia"}')
        if self.payload_mass < 0.0:
            raise ValueError(f'payload_mass must be >= 0 kg, got {self.payload_mass}')


def _vec(values):
    return ' '.join(f'{float(v):.12g}' for v in values)


def _leg_frame(direction):
    """Quaternion (w, x, y, z) of a leg's base frame: z along the unit ``direction``, x in the
    base plane. The U joint turns about x, then about y: it is singular only for a horizontal
    leg (along x), outside the joints' limits, as a real base U joint with its outer axis in
    the base plane."""
    x = np.cross([0.0, 0.0, 1.0], direction)
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(direction, x), direction], axis=1)
    quaternion = matrix_to_quaternion(rotation)  # (x, y, z, w)
    return np.concatenate([quaternion[3:], quaternion[:3]])


def _rod_inertia(mass, length):
    """Diagonal inertia of a slender rod along z (kg m^2), with a radius-0.04 m floor."""
    across = mass * (length**2 / 12.0 + 0.04**2 / 4.0)
    return (across, across, mass * 0.04**2 / 2.0)


def _inertial(mass, center, inertia):
    return f'<inertial pos="{_vec(center)}" mass="{mass:.12g}" diaginertia="{_vec(inertia)}"/>'


def _leg(index, base_joint, platform_point, params):
    """MJCF of leg ``index`` (0-based) from ``base_joint`` to the world ``platform_point``."""
    vector = platform_point - base_joint
    length = float(np.linalg.norm(vector))
    name = f'leg_{index + 1}'
    damping = params.joint_damping
    spring = (
        ''
        if math.isinf(params.leg_stiffness)
        else (
            f'<joint name="{name}_spring" type="slide" axis="0 0 1" '
            f'stiffness="{params.leg_stiffness:.12g}" damping="{params.leg_damping:.12g}"/>'
        )
    )
    return f"""
    <body name="{name}_housing" pos="{_vec(base_joint)}" quat="{_vec(_leg_frame(vector / length))}">
      <joint name="{name}_base_x" type="hinge" axis="1 0 0" damping="{damping}"/>
      <joint name="{name}_base_y" type="hinge" axis="0 1 0" damping="{damping}"/>
      {_inertial(params.leg_housing_mass, (0, 0, 0.3 * length), _rod_inertia(params.leg_housing_mass, 0.6 * length))}
      <body name="{name}_nut">
        <joint name="{name}_servo" type="slide" axis="0 0 1" armature="{params.servo_inertia:.12g}"
               damping="{params.servo_kd:.12g}"/>
        {_inertial(0.5, (0, 0, 0.5 * length), (0.01, 0.01, 0.01))}
        <body name="{name}_rod">
          {spring}
          {_inertial(params.leg_rod_mass, (0, 0, 0.75 * length), _rod_inertia(params.leg_rod_mass, 0.5 * length))}
          <site name="{name}_top" pos="0 0 {length:.12g}"/>
        </body>
      </body>
    </body>"""


def _device(link_length, params):
    damping = params.joint_damping
    return f"""
    <body name="device_link" pos="0 0 0">
      <joint name="device_beta" type="hinge" axis="0 1 0" damping="{damping}"/>
      <joint name="device_alpha" type="hinge" axis="1 0 0" damping="{damping}"/>
      {_inertial(params.device_link_mass, (0, 0, 0.3 * link_length), _rod_inertia(params.device_link_mass, 0.6 * link_length))}
      <site name="inclinometer" pos="0 0 {params.inclinometer_height:.12g}"/>
      <body name="device_slide">
        <joint name="device_lvdt" type="slide" axis="0 0 1" damping="{damping}"/>
        {_inertial(params.device_slide_mass, (0, 0, 0.8 * link_length), _rod_inertia(params.device_slide_mass, 0.3 * link_length))}
        <body name="device_top" pos="0 0 {link_length:.12g}">
          <joint name="device_encoder" type="ball" damping="{damping}"/>
          {_inertial(params.device_top_mass, (0, 0, 0), (1e-3, 1e-3, 1e-3))}
        </body>
      </body>
    </body>"""


def build_mjcf(geometry, params, reference_height):
    """MJCF text of the platform ``geometry`` built at the pose ``[0, 0, reference_height, 0, 0,
    0]``, where every joint is at its zero."""
    platform_origin = np.array([0.0, 0.0, float(reference_height)])
    points = geometry.platform_joints + platform_origin
    legs = ''.join(_leg(i, geometry.base_joints[i], points[i], params) for i in range(len(points)))
    solref = f'{2.0 * params.timestep:.12g} 1'
    solimp = '0.9999 0.9999 0.001 0.5 2'
    connects = ''.join(
        f'<connect body1="leg_{i + 1}_rod" body2="platform" '
        f'anchor="0 0 {np.linalg.norm(points[i] - geometry.base_joints[i]):.12g}" '
        f'solref="{solref}" solimp="{solimp}"/>'
        for i in range(len(points))
    )
    gravity = f'0 0 {-GRAVITY}' if params.gravity else '0 0 0'
    payload_center = np.asarray(params.payload_center, dtype=float)
    total = params.platform_mass + params.payload_mass
    center = params.payload_mass * payload_center / total
    # Parallel axes: the payload as a point mass at its centre.
    offset = payload_center - center
    inertia = np.diag(params.platform_inertia) + params.platform_mass * (
        np.dot(center, center) * np.eye(3) - np.outer(center, center)
    )
    inertia += params.payload_mass * (np.dot(offset, offset) * np.eye(3) - np.outer(offset, offset))
    full_inertia = _vec(inertia[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]])
    return f"""<mujoco model="gough_stewart">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{params.timestep:.12g}" gravity="{gravity}" integrator="implicitfast"
          cone="elliptic" jacobian="dense" solver="Newton" iterations="50" tolerance="1e-12"/>
  <worldbody>{legs}
    <body name="platform" pos="{_vec(platform_origin)}">
      <freejoint name="platform"/>
      <inertial pos="{_vec(center)}" mass="{total:.12g}" fullinertia="{full_inertia}"/>
    </body>{_device(reference_height, params)}
  </worldbody>
  <equality>
    {connects}
    <weld body1="device_top" body2="platform" solref="{solref}" solimp="{solimp}"/>
  </equality>
  <sensor><accelerometer name="inclinometer" site="inclinometer"/></sensor>
</mujoco>
"""
