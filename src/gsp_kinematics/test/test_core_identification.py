"""Identification: analytic Jacobians, exact recovery, fixed parameters, FK failures, bad inputs."""

import math

import numpy as np
import pytest

from gsp_kinematics.estimation._solver.formulations import _FkModel, _ImplicitModel
from gsp_kinematics.estimation.identification import (
    SENSOR_NAMES,
    IdentificationError,
    identify,
    resolve_free,
)
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import (
    PARAMETER_INDEX,
    PARAMETER_NAMES,
    Geometry,
    parameter_errors,
)
from gsp_kinematics.model.kinematics import (
    forward_kinematics_masked,
    inverse_kinematics,
    sample_valid_postures,
)
from gsp_kinematics.model.sensor_noise import DEFAULT_SENSOR_NOISE, SensorNoise

FORMULATIONS = ('implicit', 'fk', 'paper')


@pytest.fixture(scope='module')
def data(exact, nominal_sets, moderate_postures):
    """Noise-free measurements of the exact platform at 60 random valid postures."""
    poses = moderate_postures
    return {
        'nominal': nominal_sets[2],
        'poses': poses,
        'leg_lengths': inverse_kinematics(exact, poses),
        'readings': device_readings(exact, poses),
    }


def assert_recovers(result, exact, tolerance=1e-6):
    errors = np.abs(parameter_errors(result.geometry, exact))  # mm, deg for gamma
    worst = PARAMETER_NAMES[int(np.argmax(errors))]
    assert errors.max() < tolerance, (
        f'{result.formulation}: {worst} off by {errors.max():.2e} ({result.message})'
    )


# --- Jacobians ------------------------------------------------------------------------------------


@pytest.mark.parametrize('paper', [False, True], ids=['fk', 'paper'])
@pytest.mark.parametrize('free_names', [None, 'subset'])
def test_fk_model_jacobian_matches_finite_differences(data, paper, free_names, fd):
    free = resolve_free(
        None if free_names is None else ['A1x', 'A4z', 'B2y', 'B6x', 'Loff3', 'D0', 'gamma']
    )
    nominal = data['nominal']
    model = _FkModel(
        nominal,
        data['leg_lengths'],
        data['readings'],
        SensorNoise(),
        free,
        data['poses'],
        paper,
        SENSOR_NAMES,
    )
    values = nominal.to_full_vector()[free] + 1e-4  # off the nominal: a general point
    residuals, jacobian, _, converged = model.evaluate(values, linearize=True)
    assert converged.all()
    assert jacobian.shape == (60, 3 if paper else 4, int(free.sum()))

    def residual_of(v):
        result, _, _, ok = model.evaluate(v, linearize=False)
        assert ok.all()
        return result

    numeric = fd(residual_of, values, 1e-7)
    scale = np.max(np.abs(jacobian))
    np.testing.assert_allclose(jacobian, numeric, atol=2e-5 * scale)
    np.testing.assert_allclose(residuals, residual_of(values), atol=1e-9)


def test_implicit_model_jacobians_match_finite_differences(data, rng, fd, pose_fd):
    nominal = data['nominal']
    free = resolve_free(None)
    poses = data['poses'] + rng.normal(0.0, 1e-3, data['poses'].shape)
    model = _ImplicitModel(
        nominal, data['leg_lengths'], data['readings'], SensorNoise(), free, poses, SENSOR_NAMES
    )
    values = nominal.to_full_vector()[free]
    residuals, jac_pose, jac_u = model.evaluate(values, poses, linearize=True)
    assert (
        residuals.shape == (60, 10)
        and jac_pose.shape == (60, 10, 6)
        and jac_u.shape == (60, 10, 44)
    )
    numeric_u = fd(lambda v: model.evaluate(v, poses, False)[0], values, 1e-7)
    np.testing.assert_allclose(jac_u, numeric_u, atol=1e-5 * np.max(np.abs(jac_u)))
    # Residual row m depends on pose m only.
    numeric = pose_fd(lambda shifted: model.evaluate(values, shifted, False)[0], poses)
    np.testing.assert_allclose(jac_pose, numeric, atol=1e-5 * np.max(np.abs(jac_pose)))


# --- recovery ---------------------------------------------------------------------------------------


@pytest.mark.parametrize('formulation', FORMULATIONS)
def test_noise_free_identification_recovers_all_44_parameters(exact, data, formulation):
    result = identify(
        data['nominal'],
        data['leg_lengths'],
        data['readings'],
        SensorNoise(),
        formulation=formulation,
        pose_guesses=data['poses'],
    )
    assert result.converged, result.message
    assert result.formulation == formulation
    assert result.free[:44].all() and len(result.free_names) == 44
    assert_recovers(result, exact)
    assert result.excluded_postures == []
    assert np.all(np.isfinite(result.standard_deviations[:44]))
    assert result.covariance.shape == (44, 44) and result.information.shape == (44, 44)
    expected_sensors = (
        set(SENSOR_NAMES)
        if formulation == 'implicit'
        else (
            {'alpha', 'beta', 'phi'} if formulation == 'paper' else {'alpha', 'beta', 'phi', 'd_m'}
        )
    )
    assert set(result.residual_rms) == expected_sensors
    assert max(result.residual_rms.values()) < 1e-9
    if formulation == 'implicit':
        np.testing.assert_allclose(result.poses, data['poses'], atol=1e-10)


def test_noise_free_identification_from_nominal_set_3(exact, nominal_sets, data):
    result = identify(
        nominal_sets[3], data['leg_lengths'], data['readings'], pose_guesses=data['poses']
    )
    assert result.converged, result.message
    assert_recovers(result, exact)


@pytest.mark.parametrize('formulation', ['implicit', 'fk'])
def test_fixed_parameters_stay_fixed(exact, data, formulation):
    fixed = ['A1x', 'A3z', 'B2y', 'B6z', 'Loff4', 'gamma']
    vector = data['nominal'].to_vector()
    exact_vector = exact.to_vector()
    for name in fixed:  # the fixed ones are right, so the free ones can be recovered exactly
        vector[PARAMETER_INDEX[name]] = exact_vector[PARAMETER_INDEX[name]] + (
            1e-3 if name == 'A1x' else 0.0
        )
    nominal = Geometry.from_vector(vector, exact.limits)
    free = [name for name in PARAMETER_NAMES if name not in fixed]
    result = identify(
        nominal,
        data['leg_lengths'],
        data['readings'],
        formulation=formulation,
        free=free,
        pose_guesses=data['poses'],
    )
    assert result.converged, result.message
    assert result.free_names == free
    fixed_index = [PARAMETER_INDEX[name] for name in fixed]
    np.testing.assert_array_equal(result.parameters[fixed_index], vector[fixed_index])
    assert np.all(np.isnan(result.standard_deviations[fixed_index]))
    assert result.covariance.shape == (38, 38)
    # A1x was held 1 mm off: the fit cannot be exact, but nothing fixed moved.
    assert result.geometry.base_joints[0, 0] == vector[0]


def test_identification_survives_fk_failures_at_the_nominal(exact, nominal_sets):
    """Nominal set 3 and postures near the +-40 deg edge: FK fails there at the nominal estimate."""
    nominal = nominal_sets[3]
    pool = sample_valid_postures(exact, 3000, np.random.default_rng(11))
    edge = pool[np.max(np.abs(pool[:, 3:5]), axis=1) > math.radians(34.0)]
    _, converged = forward_kinematics_masked(nominal, inverse_kinematics(exact, edge), edge)
    assert (~converged).sum() >= 5, 'the test needs postures where FK fails under the nominal'
    poses = np.concatenate([edge[~converged][:5], edge[converged][:55]])
    leg_lengths, readings = inverse_kinematics(exact, poses), device_readings(exact, poses)
    for formulation in FORMULATIONS:
        result = identify(
            nominal, leg_lengths, readings, formulation=formulation, pose_guesses=poses
        )
        assert result.converged, result.message
        assert_recovers(result, exact)
        if formulation != 'implicit':  # no inner FK loop in the implicit formulation
            assert 'readmitted' in result.message and '0, 1, 2, 3, 4' in result.message
            assert result.excluded_postures == []


def test_a_posture_that_never_solves_is_excluded_and_reported(exact, data):
    leg_lengths = data['leg_lengths'].copy()
    leg_lengths[7] += 0.6  # corrupted: no assembly near that posture under any estimate
    result = identify(
        data['nominal'], leg_lengths, data['readings'], formulation='fk', pose_guesses=data['poses']
    )
    assert result.converged, result.message
    assert result.excluded_postures == [7]
    assert 'excluded' in result.message and '7' in result.message
    assert np.all(np.isnan(result.residuals[7])) and np.all(
        np.isfinite(np.delete(result.residuals, 7, axis=0))
    )
    assert_recovers(result, exact)


def test_identification_with_noise_is_close_and_reports_statistics(exact, data, rng):
    sigmas = DEFAULT_SENSOR_NOISE
    leg_lengths = data['leg_lengths'] + rng.normal(0.0, sigmas.leg_lengths, (60, 6))
    readings = data['readings'] + rng.normal(0.0, 1.0, (60, 4)) * sigmas.readings()
    result = identify(data['nominal'], leg_lengths, readings, sigmas, pose_guesses=data['poses'])
    assert result.converged, result.message
    errors = parameter_errors(result.geometry, exact)
    assert np.max(np.abs(errors[:43])) < 0.5  # mm: 60 random postures at the finest noise level
    deviations = result.standard_deviations * 1000.0
    assert np.all(np.abs(errors[:43]) < 6.0 * deviations[:43])  # consistent with the covariance
    # Weighted chi-square over its degrees of freedom: 600 residuals, 360 pose and 44 parameter unknowns.
    assert 0.6 < 2.0 * result.cost / (600 - 360 - 44) < 1.5
    assert set(result.residual_rms) == set(SENSOR_NAMES)
    assert isinstance(result.correlations(0.99), list)


# --- bad inputs -------------------------------------------------------------------------------------


def test_bad_inputs_raise_identification_errors(data):
    nominal, q, r = data['nominal'], data['leg_lengths'], data['readings']
    with pytest.raises(IdentificationError, match='formulation'):
        identify(nominal, q, r, formulation='magic')
    with pytest.raises(IdentificationError, match='readings'):
        identify(nominal, q, r[:, :3])
    with pytest.raises(IdentificationError, match=r'\(M, 6\)'):
        identify(nominal, q[:, :5], r)
    bad = r.copy()
    bad[5, 1] = np.nan
    with pytest.raises(IdentificationError, match=r'posture\(s\) \[5\]'):
        identify(nominal, q, bad)
    with pytest.raises(IdentificationError, match='Azz'):
        identify(nominal, q, r, free=['A1x', 'Azz'])
    with pytest.raises(IdentificationError, match='sigma'):
        identify(nominal, q, r, SensorNoise(leg_lengths=0.0))
    with pytest.raises(IdentificationError, match='sensors'):
        identify(nominal, q, r, sensors=('alpha', 'laser'))
