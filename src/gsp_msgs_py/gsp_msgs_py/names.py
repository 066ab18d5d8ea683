"""Names of every gsp-calibration interface (topics, services, frames, joints, status keys)."""

from gsp_kinematics import channels

# Frames.
FRAME_BASE = 'gsp_base'
FRAME_PLATFORM = 'gsp_platform'

# Node names (default; may be remapped).
NODE_PLATFORM_SIM = 'platform_sim'
NODE_DEVICE_DRIVER = 'device_driver'
NODE_CALIBRATOR = 'calibrator'
NODE_PLATFORM_BRIDGE = 'platform_bridge'
NODE_REPLAY = 'replay'
#: Nodes that report their health on /diagnostics (docs/nodes.md#diagnostics).
DIAGNOSED_NODES = (
    NODE_PLATFORM_SIM,
    NODE_PLATFORM_BRIDGE,
    NODE_DEVICE_DRIVER,
    NODE_CALIBRATOR,
    NODE_REPLAY,
)

# Platform topics.
TOPIC_POSE_COMMAND = '/gsp/platform/pose_command'
TOPIC_LEG_LENGTHS = '/gsp/platform/leg_lengths'
TOPIC_TRUE_POSE = '/gsp/platform/true_pose'
TOPIC_PLATFORM_STATUS = '/gsp/platform/status'
TOPIC_MARKERS = '/gsp/platform/markers'
#: The physics backend's noise-free device readings (the device_driver ``physics`` backend adds
#: the sensors' errors and noise): ``alpha, beta, phi, d_m`` (rad, rad, rad, m).
TOPIC_DEVICE_TRUTH = '/gsp/platform/device_truth'

# Device topics.
TOPIC_INCLINOMETER = '/gsp/device/inclinometer'
TOPIC_ENCODER = '/gsp/device/encoder'
TOPIC_LVDT = '/gsp/device/lvdt'

# Calibrator interfaces.
SERVICE_CALIBRATE = '/gsp/calibrator/calibrate'
SERVICE_RESUME = '/gsp/calibrator/resume'
#: The one-minute check of the platform against its latest calibration (docs/upkeep.md).
SERVICE_CHECK = '/gsp/calibrator/check'
TOPIC_CALIBRATION_RESULT = '/gsp/calibrator/result'
TOPIC_CALIBRATION_PROGRESS = '/gsp/calibrator/progress'

# Health of every node: not a suite data topic (not in TOPIC_TYPES: runs do not record it).
TOPIC_DIAGNOSTICS = '/diagnostics'

# Joint names carried by the JointState topics (values in JointState.position): the channels of
# gsp_kinematics.channels.
LEG_JOINT_NAMES = channels.LEG_JOINT_NAMES
INCLINOMETER_JOINT_NAMES = channels.sensor_channel_names(channels.INCLINOMETER)
ENCODER_JOINT_NAMES = channels.sensor_channel_names(channels.ENCODER)
LVDT_JOINT_NAMES = channels.sensor_channel_names(channels.LVDT)
#: The joint names of ``/gsp/platform/device_truth``: every device reading.
DEVICE_READING_NAMES = channels.READING_NAMES

# Platform status.
STATE_MOVING = 'moving'
STATE_SETTLED = 'settled'
STATE_REJECTED = 'rejected'
STATES = (STATE_MOVING, STATE_SETTLED, STATE_REJECTED)
STATUS_NAME = 'gsp_platform'  # DiagnosticStatus.name of platform status messages
STATUS_HARDWARE_ID = 'gsp_platform'
KEY_COMMAND_ID = 'command_id'
KEY_STATE = 'state'
KEY_REASON = 'reason'

# Calibration progress.
PROGRESS_NAME = 'gsp_calibrator'
KEY_POSTURE_INDEX = 'posture_index'  # k, 1-based; 0 before the first posture
KEY_POSTURE_COUNT = 'posture_count'  # M
KEY_PHASE = 'phase'
KEY_RESIDUALS = 'residuals'  # JSON: mapping name -> float, or list of floats
PHASE_IDLE = 'idle'
PHASE_SELECTING = 'selecting'  # choosing the postures (calibrator)
PHASE_MOVING = 'moving'
PHASE_COLLECTING = 'collecting'  # collecting synchronised samples at a posture (calibrator)
PHASE_IDENTIFYING = 'identifying'
PHASE_DONE = 'done'
PHASE_FAILED = 'failed'

# Interface types, as ``pkg/msg/Type`` / ``pkg/srv/Type``.
TOPIC_TYPES = {
    TOPIC_POSE_COMMAND: 'geometry_msgs/msg/PoseStamped',
    TOPIC_LEG_LENGTHS: 'sensor_msgs/msg/JointState',
    TOPIC_TRUE_POSE: 'geometry_msgs/msg/PoseStamped',
    TOPIC_PLATFORM_STATUS: 'diagnostic_msgs/msg/DiagnosticStatus',
    TOPIC_MARKERS: 'visualization_msgs/msg/MarkerArray',
    TOPIC_DEVICE_TRUTH: 'sensor_msgs/msg/JointState',
    TOPIC_INCLINOMETER: 'sensor_msgs/msg/JointState',
    TOPIC_ENCODER: 'sensor_msgs/msg/JointState',
    TOPIC_LVDT: 'sensor_msgs/msg/JointState',
    TOPIC_CALIBRATION_RESULT: 'std_msgs/msg/String',
    TOPIC_CALIBRATION_PROGRESS: 'diagnostic_msgs/msg/DiagnosticStatus',
}


def interface_type(type_name):
    """Import and return the Python class of ``'pkg/msg/Type'`` or ``'pkg/srv/Type'``."""
    import importlib

    package, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)
