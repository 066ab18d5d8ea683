import dataclasses

from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_msgs_py.noise_parameters import (
    TRUE_NOISE_PARAMETER,
    noise_from_parameters,
    noise_parameter_names,
)

NOISE = SensorNoise(leg_lengths=1e-6, inclinometer=2e-5, encoder=3e-5, lvdt=4e-6)


def test_parameters_round_trip_with_the_names_users_type():
    assigned = {'sigma_leg_lengths': 1e-6, 'sigma_inclinometer': 2e-5, 'sigma_encoder': 3e-5}
    assert noise_from_parameters({**assigned, 'sigma_lvdt': 4e-6}) == NOISE
    assert noise_from_parameters({'sigma_lvdt': 5e-6}) == SensorNoise(lvdt=5e-6)
    device = {f'{sensor}_noise_std': std for sensor, std in dataclasses.asdict(NOISE).items()}
    assert noise_from_parameters(device, TRUE_NOISE_PARAMETER) == NOISE
    changed = noise_from_parameters({'encoder_noise_std': 7e-5}, TRUE_NOISE_PARAMETER, NOISE)
    assert changed == dataclasses.replace(NOISE, encoder=7e-5)
    assert noise_parameter_names(TRUE_NOISE_PARAMETER, ('lvdt',)) == ('lvdt_noise_std',)
