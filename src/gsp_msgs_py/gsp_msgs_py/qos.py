"""QoS profiles of the gsp-calibration interfaces."""

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from . import names


def _keep_last(depth, reliable, latched=False):
    """A keep-last profile: reliable or best effort; latched (transient local) or volatile."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


# Like rclpy.qos.qos_profile_sensor_data (best effort, volatile, keep last) but deeper.
# The driver publishes three device topics (plus the simulator's leg lengths / true pose) at up to
# a few hundred Hz, and the calibrator pairs samples by stamp. Depth 50 buffers ~0.25 s at 200 Hz
# per topic, enough to ride out an executor stall (a YAML write, a least-squares step in another
# callback) without a sample of a synchronised set being overwritten before it is taken; the
# memory cost is a few kB per topic. Best effort so a slow subscriber never throttles the sources.
SENSOR_QOS = _keep_last(50, reliable=False)

# What the calibrator's collector and its recorder subscribe the streams with: the sensor
# profile with a deep queue. They pair samples by stamp, so late samples are fine but lost ones
# are not; 1000 holds 5 s per topic at 200 Hz, enough to ride out a starved process without
# losing one of the three device topics of an instant. The recorder needs it as much as the
# collector: a reading it drops is missing from the rebuild and the replay of the run.
SENSOR_SUBSCRIPTION_QOS = _keep_last(1000, reliable=False)

# A sensor that samples the platform's current state needs only the newest pose: with depth 1 a
# busy subscriber (the simulated device) never works through a backlog of stale poses, which
# would make its readings lag the platform after a move.
LATEST_STATE_QOS = _keep_last(1, reliable=False)

# Pose commands must not be lost; a short queue is enough (one command per posture).
COMMAND_QOS = _keep_last(10, reliable=True)

# Status transitions (moving -> settled/rejected) are events: reliable, deep enough for bursts,
# and transient local (as ROS 2 action status topics are). A calibrator that has just started or
# restarted sees the platform's status publisher in its graph before the publisher has matched
# its subscription; a status published in that gap would be lost and the first posture would
# wait for a status that never comes. Kept statuses reach a late subscription when it matches;
# statuses of other commands are ignored by their command id.
STATUS_QOS = _keep_last(50, reliable=True, latched=True)

# The latest calibrated geometry, latched for late joiners.
RESULT_QOS = _keep_last(1, reliable=True, latched=True)

# Progress reports: reliable, but only recent ones matter.
PROGRESS_QOS = _keep_last(10, reliable=True)

# RViz markers: latest state, latched so a late RViz still draws the platform.
MARKER_QOS = _keep_last(1, reliable=True, latched=True)

# /diagnostics as diagnostic_updater publishes it upstream (reliable, volatile, keep last), so
# `ros2 topic echo /diagnostics`, rqt_robot_monitor and the aggregator match it. Upstream keeps
# depth 1 on its publisher; 10 here, because one subscriber hears every node of the suite on this
# one keyless topic and its reader history is shared by all of them.
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
