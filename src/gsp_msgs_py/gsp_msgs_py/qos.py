"""QoS profiles of the gsp-calibration interfaces."""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from . import names


def _keep_last(depth, reliable, latched=False):
    """A keep-last profile: reliable or best effort; latched (transient local) or volatile."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


# qos_profile_sensor_data but deeper: 50 rides out ~0.25 s of executor stall at 200 Hz; best
# effort so a slow subscriber never throttles the sources.
SENSOR_QOS = _keep_last(50, reliable=False)

# The collector's and recorder's subscriptions: late samples are fine, lost ones are not (1000
# holds 5 s per topic at 200 Hz).
SENSOR_SUBSCRIPTION_QOS = _keep_last(1000, reliable=False)

# Only the newest pose: a busy simulated device never works through a backlog of stale poses.
LATEST_STATE_QOS = _keep_last(1, reliable=False)

# Pose commands must not be lost; a short queue is enough (one command per posture).
COMMAND_QOS = _keep_last(10, reliable=True)

# Status transitions are events: reliable, and transient local (as action status topics) so a
# status published before a (re)started calibrator's subscription matched still reaches it.
STATUS_QOS = _keep_last(50, reliable=True, latched=True)

# The latest calibrated geometry, latched for late joiners.
RESULT_QOS = _keep_last(1, reliable=True, latched=True)

# Progress reports: reliable, but only recent ones matter.
PROGRESS_QOS = _keep_last(10, reliable=True)

# RViz markers: latest state, latched so a late RViz still draws the platform.
MARKER_QOS = _keep_last(1, reliable=True, latched=True)

# /diagnostics as diagnostic_updater publishes it; depth 10, not 1: one keyless topic carries
# every node's reports.
DIAGNOSTICS_QOS = _keep_last(10, reliable=True)

TOPIC_QOS = {
    names.TOPIC_POSE_COMMAND: COMMAND_QOS,
    names.TOPIC_LEG_LENGTHS: SENSOR_QOS,
    names.TOPIC_TRUE_POSE: SENSOR_QOS,
    names.TOPIC_DEVICE_TRUTH: SENSOR_QOS,
    names.TOPIC_PLATFORM_STATUS: STATUS_QOS,
    names.TOPIC_MARKERS: MARKER_QOS,
    names.TOPIC_INCLINOMETER: SENSOR_QOS,
    names.TOPIC_ENCODER: SENSOR_QOS,
    names.TOPIC_LVDT: SENSOR_QOS,
    names.TOPIC_CALIBRATION_RESULT: RESULT_QOS,
    names.TOPIC_CALIBRATION_PROGRESS: PROGRESS_QOS,
}
