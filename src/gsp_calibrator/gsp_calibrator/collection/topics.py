"""THE table of the sensor topics a calibration collects and the stream each one feeds, and how a
``JointState`` message or its CDR bytes are read (pure, no rclpy)."""

import math

from gsp_calibrator.collection.joint_state_cdr import read_joint_state
from gsp_calibrator.collection.synchroniser import ENCODER, INCLINOMETER, LEG_LENGTHS, LVDT
from gsp_kinematics import channels
from gsp_msgs_py import conversions, names

#: THE table of sensor topics and the collector stream each one feeds.
TOPIC_STREAMS = {
    names.TOPIC_LEG_LENGTHS: LEG_LENGTHS,
    names.TOPIC_INCLINOMETER: INCLINOMETER,
    names.TOPIC_ENCODER: ENCODER,
    names.TOPIC_LVDT: LVDT,
}
SENSOR_TOPICS = tuple(TOPIC_STREAMS)
#: Device streams, in the order of the readings ``[alpha, beta, phi, d_m]``.
DEVICE_STREAMS = channels.DEVICE_SENSORS

_READERS = {
    LEG_LENGTHS: lambda msg: (conversions.msg_to_leg_lengths(msg),),
    INCLINOMETER: conversions.msg_to_inclinometer,
    ENCODER: lambda msg: (conversions.msg_to_encoder(msg),),
    LVDT: lambda msg: (conversions.msg_to_lvdt(msg),),
}


def sensor_message(msg):
    """``msg`` as the readers take it: the fields of CDR bytes (the bytes if they are no
    ``JointState``, which :func:`read_sensor` then says), or the message itself."""
    if isinstance(msg, (bytes, bytearray, memoryview)):
        try:
            return read_joint_state(msg)
        except ValueError:
            return msg
    return msg


def read_sensor(topic, msg):
    """``(stream, stamp_ns, values)`` of a sensor message (or its CDR bytes); ValueError (or
    TypeError) if unusable."""
    stream = TOPIC_STREAMS[topic]
    msg = sensor_message(msg)
    if isinstance(msg, (bytes, bytearray, memoryview)):
        raise ValueError(f'not a sensor_msgs/JointState message ({len(msg)} bytes)')
    return stream, conversions.stamp_to_nanoseconds(msg.header.stamp), tuple(_READERS[stream](msg))


def has_non_finite(msg):
    """Whether a JointState sensor message (or its CDR bytes) holds a non-finite position."""
    msg = sensor_message(msg)
    try:
        return any(not math.isfinite(v) for v in msg.position)
    except (AttributeError, TypeError):
        return False
