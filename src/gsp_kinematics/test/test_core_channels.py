"""The one channel table and the layouts derived from it."""

import numpy as np

from gsp_kinematics import channels
from gsp_kinematics.estimation import goodness
from gsp_kinematics.model import device
from gsp_kinematics.model.sensor_noise import SensorNoise


def test_the_ten_columns_are_the_legs_then_the_device_readings():
    assert channels.CHANNEL_NAMES == (
        'q1', 'q2', 'q3', 'q4', 'q5', 'q6', 'alpha', 'beta', 'phi', 'd_m'
    )  # fmt: skip
    assert [c.column for c in channels.CHANNELS] == list(range(10))
    assert channels.CIRCULAR_COLUMNS == (8,)
    assert channels.PHI_READING_COLUMN == 2
    assert {c.unit for c in channels.CHANNELS if c.sensor == channels.LEG_LENGTHS} == {'m'}
    assert [c.unit for c in channels.DEVICE_CHANNELS] == ['rad', 'rad', 'rad', 'm']


def test_the_core_layouts_are_the_table():
    assert device.READING_NAMES == ('alpha', 'beta', 'phi', 'd_m')
    assert device.SENSORS == {'inclinometer': (0, 1), 'encoder': (2,), 'lvdt': (3,)}
    assert goodness.NOISE_CHANNELS['leg_lengths'] == slice(0, 6)
    assert goodness.NOISE_CHANNELS['lvdt'] == slice(9, 10)


def test_sensor_noise_channels_follow_the_table():
    noise = SensorNoise(leg_lengths=1.0, inclinometer=2.0, encoder=3.0, lvdt=4.0)
    std = noise.channel_std()
    for sensor, columns in ((s, channels.sensor_columns(s)) for s in channels.SENSORS):
        np.testing.assert_array_equal(std[list(columns)], getattr(noise, sensor))


def test_an_unknown_sensor_is_named():
    try:
        channels.sensor_columns('gyro')
    except KeyError as error:
        assert 'gyro' in str(error) and 'lvdt' in str(error)
    else:
        raise AssertionError('no KeyError')
