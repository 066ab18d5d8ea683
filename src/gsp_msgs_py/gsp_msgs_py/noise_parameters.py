"""The sensor noise as node parameters: the nodes' names for the fields of
:class:`gsp_kinematics.model.sensor_noise.SensorNoise` (the core knows no parameter name)."""

from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, NOISE_FIELDS, SensorNoise

#: Name of a sensor's true noise std on the simulated nodes (``inclinometer_noise_std``).
TRUE_NOISE_PARAMETER = '{}_noise_std'
#: Name of a sensor's assumed noise std on the calibrator and in its run options
#: (``sigma_inclinometer``).
ASSUMED_NOISE_PARAMETER = 'sigma_{}'


def noise_parameter_names(pattern=ASSUMED_NOISE_PARAMETER, sensors=NOISE_FIELDS):
    """The parameter names of ``sensors`` under ``pattern``."""
    return tuple(pattern.format(name) for name in sensors)


def noise_from_parameters(values, pattern=ASSUMED_NOISE_PARAMETER, default=None):
    """The ``SensorNoise`` of ``{pattern.format(sensor): std}``; a missing key is taken from
    ``default`` (the suite's default noise when None)."""
    fields = {name: values.get(pattern.format(name)) for name in NOISE_FIELDS}
    return SensorNoise.from_channels(fields, DEFAULT_SENSOR_NOISE if default is None else default)
