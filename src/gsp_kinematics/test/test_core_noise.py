"""SensorNoise: one noise type and its conversions (channels, averaged rows, parameters, files)."""

import math

import numpy as np
import pytest

from gsp_kinematics.model.sensor_noise import (
    DEFAULT_SENSOR_NOISE,
    SensorNoise,
    SensorNoiseError,
)

NOISE = SensorNoise(leg_lengths=1e-6, inclinometer=2e-5, encoder=3e-5, lvdt=4e-6)


def test_the_default_is_table_3_first_level():
    for angle in (DEFAULT_SENSOR_NOISE.inclinometer, DEFAULT_SENSOR_NOISE.encoder):
        assert angle == pytest.approx(math.radians(0.001), rel=1e-15)
    for length in (DEFAULT_SENSOR_NOISE.leg_lengths, DEFAULT_SENSOR_NOISE.lvdt):
        assert length == pytest.approx(1e-6, rel=1e-15)


def test_channels_in_the_collector_order():
    channel_std = NOISE.channel_std()
    assert channel_std.tolist() == [1e-6] * 6 + [2e-5, 2e-5, 3e-5, 4e-6]
    assert NOISE.readings().tolist() == [2e-5, 2e-5, 3e-5, 4e-6]


def test_an_estimate_feeds_the_type_with_the_configured_value_where_it_has_none():
    estimate = {'leg_lengths': 3e-6, 'inclinometer': None, 'encoder': 6e-5, 'lvdt': 1e-5}
    noise = SensorNoise.from_channels(estimate, default=NOISE)
    assert noise == SensorNoise(3e-6, 2e-5, 6e-5, 1e-5)
    assert SensorNoise.from_channels(NOISE.channels()) == NOISE
    with pytest.raises(SensorNoiseError, match='inclinometer'):
        SensorNoise.from_channels(estimate)


def test_averaged_rows_have_sigma_over_root_n_of_the_median_count():
    averaged = NOISE.averaged([9, 9, 10])
    np.testing.assert_allclose(averaged.channel_std(), NOISE.channel_std() / 3.0, rtol=1e-15)
    assert NOISE.averaged([]) == NOISE
    assert NOISE.averaged([0, 4]) == NOISE  # a count below one: rows are not averages


@pytest.mark.parametrize('value', [0.0, -1e-6, math.nan, math.inf])
def test_validate_names_the_bad_sensor(value):
    with pytest.raises(SensorNoiseError, match='encoder'):
        SensorNoise(encoder=value).validate()
