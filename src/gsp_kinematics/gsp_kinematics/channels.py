"""THE table of the ten reading channels ``[q1..q6, alpha, beta, phi, d_m]`` a calibration
collects at each instant, from which every layout is derived (no rclpy; docs/core_api.md)."""

import dataclasses

LEG_COUNT = 6


@dataclasses.dataclass(frozen=True)
class Channel:
    """One reading channel: its ``name``, the ``sensor`` that produces it, its SI ``unit``, its
    ``column`` among the ten and whether it is an angle compared on the circle (``circular``)."""

    name: str
    sensor: str
    unit: str
    column: int
    circular: bool = False


#: The sensors, in column order: the six legs, then the device's three.
LEG_LENGTHS, INCLINOMETER, ENCODER, LVDT = 'leg_lengths', 'inclinometer', 'encoder', 'lvdt'
SENSORS = (LEG_LENGTHS, INCLINOMETER, ENCODER, LVDT)
DEVICE_SENSORS = (INCLINOMETER, ENCODER, LVDT)

#: THE channel table.
CHANNELS = (
    *(Channel(f'q{i + 1}', LEG_LENGTHS, 'm', i) for i in range(LEG_COUNT)),
    Channel('alpha', INCLINOMETER, 'rad', 6),
    Channel('beta', INCLINOMETER, 'rad', 7),
    # phi is the encoder's absolute rotation: compared and averaged on the circle.
    Channel('phi', ENCODER, 'rad', 8, circular=True),
    Channel('d_m', LVDT, 'm', 9),
)
CHANNEL_NAMES = tuple(channel.name for channel in CHANNELS)
CHANNEL_COUNT = len(CHANNELS)
#: The device's channels (the core's ``readings`` rows), in column order.
DEVICE_CHANNELS = tuple(channel for channel in CHANNELS if channel.sensor != LEG_LENGTHS)
READING_NAMES = tuple(channel.name for channel in DEVICE_CHANNELS)
#: Column of the first device channel among the ten.
FIRST_READING_COLUMN = DEVICE_CHANNELS[0].column
#: Columns among the ten of the circular channels (phi).
CIRCULAR_COLUMNS = tuple(channel.column for channel in CHANNELS if channel.circular)


def sensor_columns(sensor):
    """Columns among the ten of ``sensor``'s channels (a tuple of ints)."""
    columns = tuple(channel.column for channel in CHANNELS if channel.sensor == sensor)
    if not columns:
        raise KeyError(f'unknown sensor {sensor!r}; the sensors are {", ".join(SENSORS)}')
    return columns


def sensor_channel_names(sensor):
    """Names of ``sensor``'s channels, in column order (a tuple of str)."""
    return tuple(CHANNEL_NAMES[column] for column in sensor_columns(sensor))


#: Each device sensor -> its columns among the four readings.
DEVICE_READING_COLUMNS = {
    sensor: tuple(column - FIRST_READING_COLUMN for column in sensor_columns(sensor))
    for sensor in DEVICE_SENSORS
}
#: Each sensor -> the slice of its (contiguous) columns among the ten.
SENSOR_SLICES = {
    sensor: slice(sensor_columns(sensor)[0], sensor_columns(sensor)[-1] + 1) for sensor in SENSORS
}
#: Column among the four readings of phi (the encoder).
PHI_READING_COLUMN = CHANNEL_NAMES.index('phi') - FIRST_READING_COLUMN
#: The legs' joint names: in the leg lengths' JointState and as ``samples.csv`` columns.
LEG_JOINT_NAMES = tuple(f'leg_{column + 1}' for column in sensor_columns(LEG_LENGTHS))
