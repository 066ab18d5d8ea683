"""Sensor errors: the geometry file section, Jacobian columns, identifiability, robust fitting,
noise estimates and the goodness of fit."""

import math

import numpy as np
import pytest

from gsp_kinematics.estimation import goodness
from gsp_kinematics.estimation._solver.formulations import _FkModel, _ImplicitModel
from gsp_kinematics.estimation.identifiability import analyse_design, unidentifiable_parameters
from gsp_kinematics.estimation.identification import (
    PARAMETER_GROUPS,
    SENSOR_NAMES,
    IdentificationError,
    Options,
    identify,
    resolve_free,
)
from gsp_kinematics.model.geometry import (
    NUM_PARAMETERS,
    PARAMETER_INDEX,
    SENSOR_PARAMETER_NAMES,
    GeometryError,
    SensorErrors,
    geometry_from_yaml,
    geometry_to_yaml,
)
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoise
from gsp_kinematics.model.validation import sensor_measurements

SENSORS = SensorErrors(
    leg_gain_errors=[3e-4, -2e-4, 4e-4, -3e-4, 1e-4, 2e-4],
    inclinometer_offsets=[math.radians(0.01), math.radians(-0.01)],
    encoder_offset=math.radians(0.02),
    lvdt_gain_error=1e-3,
)


@pytest.fixture(scope='module')
def with_sensors(exact):
    return exact.replace(sensors=SENSORS)


@pytest.fixture(scope='module')
def measured(with_sensors, moderate_postures):
    legs, readings = sensor_measurements(with_sensors, moderate_postures)
    return {'poses': moderate_postures, 'leg_lengths': legs, 'readings': readings}


# --- the geometry file ----------------------------------------------------------------------------


def test_sensor_section_round_trips_and_is_optional(exact, with_sensors):
    again = geometry_from_yaml(geometry_to_yaml(with_sensors))
    np.testing.assert_array_equal(again.to_full_vector(), with_sensors.to_full_vector())
    assert 'sensors' not in geometry_to_yaml(exact)  # ideal sensors: files as before
    assert geometry_from_yaml(geometry_to_yaml(exact)).sensors.ideal


@pytest.mark.parametrize(
    'line, message',
    [
        ('leg_gain_errors: [0.0, 0.0]', 'geometry.sensors.leg_gain_errors: expected 6 values'),
        ('inclinometer_offsets: 0.1', 'geometry.sensors.inclinometer_offsets: expected a list'),
        ('encoder_offset: abc', 'geometry.sensors.encoder_offset: expected a number'),
        ('lvdt_gain_error: .nan', 'geometry.sensors.lvdt_gain_error: value is not finite'),
        ('lvdt_gain_error: 0.9', 'geometry.sensors.lvdt_gain_error: a gain error is a small'),
    ],
)
def test_malformed_sensor_section_names_the_key(exact, line, message):
    text = geometry_to_yaml(exact) + f'      sensors:\n        {line}\n'
    with pytest.raises(GeometryError, match=message.replace('.', r'\.')):
        geometry_from_yaml(text)


def test_sensor_errors_invert(with_sensors, moderate_postures):
    sensors = with_sensors.sensors
    legs, readings = sensor_measurements(with_sensors, moderate_postures)
    ideal = sensors.ideal_device_readings(readings)
    np.testing.assert_allclose(sensors.device_readings(ideal), readings, atol=1e-15)
    np.testing.assert_allclose(sensors.leg_readings(sensors.true_leg_lengths(legs)), legs)


# --- Jacobian columns against finite differences, each with its own scale ----------------------


def assert_columns_match(analytic, numeric, relative=2e-5):
    """Each column within ``relative`` of that column's largest entry."""
    flat_a = analytic.reshape(-1, analytic.shape[-1])
    flat_n = numeric.reshape(-1, numeric.shape[-1])
    for column in range(flat_a.shape[1]):
        scale = max(np.max(np.abs(flat_a[:, column])), 1e-300)
        error = np.max(np.abs(flat_a[:, column] - flat_n[:, column]))
        assert error <= relative * scale, f'column {column}: {error:.3g} vs scale {scale:.3g}'


ALL_FREE = np.ones(NUM_PARAMETERS + len(SENSOR_PARAMETER_NAMES), dtype=bool)


@pytest.mark.parametrize('paper', [False, True], ids=['fk', 'paper'])
def test_fk_model_sensor_columns_match_finite_differences(with_sensors, measured, paper, fd):
    model = _FkModel(
        with_sensors,
        measured['leg_lengths'],
        measured['readings'],
        SensorNoise(),
        ALL_FREE,
        measured['poses'],
        paper,
        SENSOR_NAMES,
    )
    values = with_sensors.to_full_vector() + 1e-4
    _, jacobian, _, converged = model.evaluate(values, linearize=True)
    assert converged.all()

    def residual_of(v):
        return model.evaluate(v, linearize=False)[0]

    numeric = fd(residual_of, values, 1e-7)
    assert_columns_match(jacobian, numeric)
    assert np.all(np.abs(jacobian[..., PARAMETER_INDEX['kq1']]) > 0)


def test_implicit_model_sensor_columns_match_finite_differences(
    with_sensors, measured, rng, fd, pose_fd
):
    poses = measured['poses'] + rng.normal(0.0, 1e-3, measured['poses'].shape)
    model = _ImplicitModel(
        with_sensors,
        measured['leg_lengths'],
        measured['readings'],
        SensorNoise(),
        ALL_FREE,
        poses,
        SENSOR_NAMES,
    )
    values = with_sensors.to_full_vector() + 1e-4
    _, jac_pose, jac_u = model.evaluate(values, poses, linearize=True)
    assert jac_u.shape == (60, 10, 54)
    numeric = fd(lambda v: model.evaluate(v, poses, False)[0], values, 1e-7)
    assert_columns_match(jac_u, numeric)
    numeric = pose_fd(lambda shifted: model.evaluate(values, shifted, False)[0], poses)
    for j in range(6):
        assert_columns_match(jac_pose[:, :, j : j + 1], numeric[:, :, j : j + 1])


# --- identifiability ------------------------------------------------------------------------------


def test_identifiability_names_the_datum_combinations(exact, moderate_postures):
    everything = analyse_design(exact, moderate_postures, free=ALL_FREE)
    names = unidentifiable_parameters(everything)
    assert everything['rank'] == 54 - 3
    assert {'phi0', 'beta0', 'kDm'} <= set(names)
    extended = analyse_design(exact, moderate_postures, free=resolve_free('extended'))
    assert extended['rank'] == extended['parameters'] and extended['unidentifiable'] == []
    assert set(PARAMETER_GROUPS['extended']) - set(PARAMETER_GROUPS['paper']) == {
        'kq1',
        'kq2',
        'kq3',
        'kq4',
        'kq5',
        'kq6',
        'alpha0',
    }


def test_groups_and_names_resolve(exact):
    assert resolve_free(None).sum() == 44 and resolve_free('paper').sum() == 44
    mask = resolve_free(['paper', 'kDm'])
    assert mask[PARAMETER_INDEX['kDm']] and mask.sum() == 45
    with pytest.raises(IdentificationError, match=r"unknown parameter name\(s\) \['kq9'\]"):
        resolve_free(['kq9'])


# --- fitting ----------------------------------------------------------------------------------------


def noisy(measured, sigmas, rng):
    legs = measured['leg_lengths'] + rng.normal(0.0, sigmas.leg_lengths, (60, 6))
    readings = measured['readings'] + rng.normal(0.0, 1.0, (60, 4)) * sigmas.readings()
    return legs, readings


def test_extended_fit_recovers_sensor_errors_and_paper_fit_is_rejected(with_sensors, measured):
    # The datum (beta0, phi0, kDm) is known: the nominal carries it; the 44 and the rest start off.
    sigmas = DEFAULT_SENSOR_NOISE
    legs, readings = noisy(measured, sigmas, np.random.default_rng(5))
    datum = SensorErrors(
        inclinometer_offsets=[0.0, SENSORS.inclinometer_offsets[1]],
        encoder_offset=SENSORS.encoder_offset,
        lvdt_gain_error=SENSORS.lvdt_gain_error,
    )
    nominal = with_sensors.replace(
        sensors=datum, leg_offsets=with_sensors.leg_offsets + 1e-3, device_length=0.851
    )
    extended = identify(
        nominal, legs, readings, sigmas, free='extended', pose_guesses=measured['poses']
    )
    assert extended.converged, extended.message
    estimated = extended.geometry.sensors
    # Within 5 standard deviations of the truth (the covariance is honest), and clearly nonzero.
    truth = SENSORS.to_vector()
    for name in ('kq1', 'kq2', 'kq3', 'kq4', 'kq5', 'kq6', 'alpha0'):
        index = PARAMETER_INDEX[name]
        error = extended.parameters[index] - truth[index - NUM_PARAMETERS]
        assert abs(error) < 5.0 * extended.standard_deviations[index], name
    assert np.all(np.sign(estimated.leg_gain_errors) == np.sign(SENSORS.leg_gain_errors))
    assert extended.goodness_of_fit.p_value > 1e-4
    paper = identify(nominal, legs, readings, sigmas, free='paper', pose_guesses=measured['poses'])
    assert paper.goodness_of_fit.p_value < 0.01
    assert not paper.goodness_of_fit.accepted
    text = goodness.fit_diagnosis(
        paper.goodness_of_fit, free_sensor_errors=paper.sensor_errors_free
    )
    assert 'try free_parameters: extended' in text


def test_huber_names_and_down_weights_a_corrupted_posture(exact, moderate_postures):
    sigmas = DEFAULT_SENSOR_NOISE
    legs, readings = sensor_measurements(exact, moderate_postures)
    rng = np.random.default_rng(3)
    legs = legs + rng.normal(0.0, sigmas.leg_lengths, legs.shape)
    readings = readings + rng.normal(0.0, 1.0, readings.shape) * sigmas.readings()
    legs[7, 2] += 0.5e-3
    options = {'pose_guesses': moderate_postures}
    linear = identify(exact, legs, readings, sigmas, **options)
    assert [entry['posture'] for entry in linear.outliers][:1] == [7]
    assert linear.goodness_of_fit.p_value < 0.01 and linear.down_weighted == []
    huber = identify(exact, legs, readings, sigmas, options=Options(loss='huber'), **options)
    assert huber.converged, huber.message
    assert huber.down_weighted[0]['posture'] == 7 and huber.down_weighted[0]['weight'] < 0.05
    assert (
        huber.outliers[0]['posture'] == 7 and huber.outliers[0]['sensor'] in huber.residual_columns
    )
    assert huber.goodness_of_fit.excluded_postures == (7,)
    worst_linear = np.max(np.abs(linear.parameters[:43] - exact.to_vector()[:43]))
    worst_huber = np.max(np.abs(huber.parameters[:43] - exact.to_vector()[:43]))
    assert worst_huber < 0.5 * worst_linear
    with pytest.raises(IdentificationError, match='loss must be one of'):
        identify(exact, legs, readings, sigmas, options=Options(loss='tukey'), **options)


# --- noise estimates and the verdict --------------------------------------------------------------


def test_goodness_of_fit_and_verdict_text():
    rng = np.random.default_rng(2)
    fit = goodness.goodness_of_fit(rng.normal(size=(100, 10)), 44)
    assert fit.dof == 956 and fit.accepted
    assert 'explains the data' in goodness.fit_diagnosis(fit)
    bad = goodness.goodness_of_fit(3.0 * rng.normal(size=(100, 10)), 44)
    text = goodness.fit_diagnosis(bad, free_sensor_errors=True)
    assert not bad.accepted and 'does NOT explain' in text and 'unmodelled error' in text
    assert 'extended' not in text
