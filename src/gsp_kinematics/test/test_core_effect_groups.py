"""The effect groups of the identification (gsp_kinematics.model.effect_groups): Jacobian columns
against finite differences, recovery and identifiability on a simulated real platform."""

import dataclasses

import numpy as np
import pytest

from gsp_kinematics.estimation._solver.formulations import _ImplicitModel
from gsp_kinematics.estimation.identification import (
    SENSOR_NAMES,
    IdentificationError,
    identify,
    resolve_free,
)
from gsp_kinematics.model.effect_groups import (
    EffectDesign,
    EffectTerms,
    compensated_leg_readings,
    model_poses,
    resolve_effects,
)
from gsp_kinematics.model.effects import (
    EFFECT_GROUPS,
    EFFECT_PARAMETER_NAMES,
    IdentifiedEffects,
    PlatformEffects,
)
from gsp_kinematics.model.geometry import (
    GeometryError,
    default_geometry,
    geometry_from_parameters,
    geometry_from_yaml,
    geometry_to_parameters,
    geometry_to_yaml,
)
from gsp_kinematics.model.kinematics import Workspace, inverse_kinematics, sample_valid_postures
from gsp_kinematics.model.real_pose import real_poses
from gsp_kinematics.model.sensor_noise import SensorNoise
from gsp_kinematics.model.validation import simulate_commands, validate

TRUE = default_geometry('true')
NOMINAL = default_geometry('nominal')
MASS, CENTRE = 40.0, (0.0, 0.0, 0.05)
#: Each group's effect alone, at the magnitudes of docs/platform_effects.md.
ALONE = {
    'compliance': PlatformEffects(
        payload_mass=MASS, centre_of_mass=CENTRE, leg_stiffness=np.full(6, 30e6)
    ),
    'backlash': PlatformEffects(backlash=np.array([4, 3, 5, 4, 2, 6]) * 1e-6),
    'thermal': PlatformEffects(temperature_rise=np.full(6, 1.5), thermal_time_constant=3000.0),
    'joint_offsets': PlatformEffects(base_joint_offsets=np.array([20, 10, 30, 20, 25, 15]) * 1e-6),
}
#: Finite-difference step of each group's parameters (the model is linear in them).
WORKSPACE = Workspace(rotation_range=np.radians(25.0))
STEPS = {'compliance': 1e-10, 'backlash': 1e-8, 'thermal': 1e-11, 'joint_offsets': 1e-8}


@pytest.fixture(scope='module')
def sequence():
    """60 postures in the order visited, 10 s apart, that the real platform reaches."""
    poses = sample_valid_postures(NOMINAL, 80, np.random.default_rng(5), WORKSPACE)
    for effects in ALONE.values():
        poses = poses[simulate_commands(TRUE, NOMINAL, poses, effects).reachable]
    return poses[:60], np.arange(60) * 10.0


def design_of(run):
    return EffectDesign(run.times_s, run.directions, MASS, CENTRE)


def test_effect_names_and_masks():
    assert len(EFFECT_PARAMETER_NAMES) == 24 and EFFECT_PARAMETER_NAMES[6] == 'backlash1'
    mask = resolve_effects(['paper', 'thermal', 'compliance3'])
    assert [EFFECT_PARAMETER_NAMES[i] for i in np.flatnonzero(mask)] == [
        'compliance3',
        *[f'strain_rate{leg}' for leg in range(1, 7)],
    ]
    assert resolve_free(['paper', 'thermal']).sum() == 44  # the groups are not geometry


def test_effect_columns_and_the_rest_match_finite_differences(sequence, fd):
    poses, times = sequence
    run = simulate_commands(TRUE, NOMINAL, poses, ALONE['backlash'], times)
    free = resolve_free(['extended'])
    mask = resolve_effects(list(EFFECT_GROUPS))
    terms = EffectTerms(NOMINAL, design_of(run), mask, len(poses))
    model = _ImplicitModel(
        NOMINAL,
        run.leg_readings,
        run.device_readings,
        SensorNoise(),
        free,
        poses,
        SENSOR_NAMES,
        terms,
    )
    theta = np.repeat([3e-8, 4e-6, 1e-8, 2e-5], 6)  # realistic values: a general point
    values = np.concatenate([NOMINAL.to_full_vector()[free], theta])
    _, jac_pose, jac_u = model.evaluate(values, poses, linearize=True)
    count = int(free.sum())
    assert jac_u.shape == (60, 10, count + 24)

    def residuals(v):
        return model.evaluate(v, poses, False)[0]

    # Each effect column with its own step, against its own largest entry.
    for index, group in enumerate(EFFECT_GROUPS):
        for leg in range(6):
            column = count + 6 * index + leg
            step = np.zeros_like(values)
            step[column] = STEPS[group]
            numeric = (residuals(values + step) - residuals(values - step)) / (2 * STEPS[group])
            analytic = jac_u[:, :, column]
            assert np.max(np.abs(analytic)) > 0, EFFECT_PARAMETER_NAMES[6 * index + leg]
            np.testing.assert_allclose(
                analytic, numeric, atol=1e-6 * np.max(np.abs(analytic)), err_msg=group
            )
    # The geometry and sensor columns (kq sees the effects' share of the leg reading). The
    # regressors follow the geometry estimate and the Jacobian leaves out theta dh/du (as it
    # leaves out theta dh/dX): with the regressors frozen at the point the columns match...
    follow = terms.regressors
    terms.regressors = lambda poses, geometry=None: follow(poses, NOMINAL)
    numeric_u = fd(lambda v: residuals(np.concatenate([v, theta])), values[:count], 1e-7)
    scale = np.max(np.abs(jac_u[:, :, :count]))
    np.testing.assert_allclose(jac_u[:, :, :count], numeric_u, atol=1e-5 * scale)
    # ... and what they leave out is small.
    del terms.regressors
    numeric_u = fd(lambda v: residuals(np.concatenate([v, theta])), values[:count], 1e-7)
    assert np.max(np.abs(jac_u[:, :, :count] - numeric_u)) < 1e-3 * scale


@pytest.mark.parametrize('group', list(EFFECT_GROUPS))
def test_each_group_is_identified_from_noise_free_data_of_its_effect(sequence, group):
    poses, times = sequence
    truth = ALONE[group]
    run = simulate_commands(TRUE, NOMINAL, poses, truth, times)
    plain = identify(NOMINAL, run.leg_readings, run.device_readings, free=['extended'])
    result = identify(
        NOMINAL,
        run.leg_readings,
        run.device_readings,
        free=['extended', group],
        pose_guesses=poses,
        effects=design_of(run),
    )
    assert result.converged, result.message
    assert np.isfinite(result.covariance).all() and np.linalg.matrix_rank(result.information) == (
        len(result.free_names)
    )
    # The group explains what the plain model leaves in the legs.
    legs, plain_legs = result.residual_rms['leg_lengths'], plain.residual_rms['leg_lengths']
    assert legs < 0.3 * plain_legs, (legs, plain_legs)
    values = np.array([value for value, _ in result.effects.values()])
    expected = {
        'compliance': truth.leg_compliance,
        'backlash': truth.backlash,
        # The first-order rise's mean rate over the 10 min run (time constant 50 min).
        'thermal': np.full(6, 12e-6 * 1.5 * -np.expm1(-600.0 / 3000.0) / 600.0),
        'joint_offsets': truth.base_joint_offsets,
    }[group]
    tolerance = {'compliance': 0.15, 'backlash': 1e-6, 'thermal': 0.15, 'joint_offsets': 0.03}
    np.testing.assert_allclose(values, expected, rtol=tolerance[group])


def test_backlash_seen_from_one_direction_only_is_the_leg_offset(sequence):
    poses, times = sequence
    run = simulate_commands(TRUE, NOMINAL, poses, ALONE['backlash'], times)
    one_way = EffectDesign(times, np.ones((60, 6)), MASS, CENTRE)
    result = identify(
        NOMINAL, run.leg_readings, run.device_readings, free=['paper', 'backlash'], effects=one_way
    )
    eigenvalues = np.linalg.eigvalsh(result.information)
    assert eigenvalues[0] < 1e-12 * eigenvalues[-1]  # rank deficient: backlash_i = 2 Loff_i


def test_what_a_group_lacks_is_named(sequence):
    poses, times = sequence
    run = simulate_commands(TRUE, NOMINAL, poses[:20], None, times[:20])
    args = (NOMINAL, run.leg_readings, run.device_readings)
    with pytest.raises(IdentificationError, match='payload_mass'):
        identify(*args, free=['paper', 'compliance'], effects=EffectDesign(times[:20]))
    with pytest.raises(IdentificationError, match='times_s'):
        identify(*args, free=['paper', 'thermal'])
    with pytest.raises(IdentificationError, match='directions'):
        identify(*args, free=['paper', 'backlash'], effects=EffectDesign(times[:20]))
    with pytest.raises(IdentificationError, match='implicit'):
        identify(*args, formulation='fk', free=['paper', 'backlash'], effects=design_of(run))


@pytest.mark.parametrize('group', ['compliance', 'backlash', 'joint_offsets'])
def test_a_controller_compensating_the_identified_effect_reaches_the_commands(sequence, group):
    poses, times = sequence
    truth = ALONE[group]
    run = simulate_commands(TRUE, NOMINAL, poses, truth, times)
    design = design_of(run)
    plain = identify(NOMINAL, run.leg_readings, run.device_readings, free=['extended'])
    result = identify(
        NOMINAL, run.leg_readings, run.device_readings, free=['extended', group], effects=design
    )
    assert result.geometry.effects.groups() == [group]
    rigid = result.geometry.replace(effects=IdentifiedEffects())
    validation = sample_valid_postures(NOMINAL, 40, np.random.default_rng(11), WORKSPACE)
    before = validate(TRUE, plain.geometry, validation, truth)['position_mm_mean']
    after = validate(TRUE, result.geometry, validation, truth)
    uncompensated = validate(TRUE, rigid, validation, truth)['position_mm_mean']
    assert after['unreachable'] == 0
    assert after['position_mm_mean'] < 0.1 * min(before, uncompensated), (
        after['position_mm_mean'],
        before,
        uncompensated,
    )


def test_compensation_reads_the_model_backwards():
    """Without effects the compensated readings are the controller's IK readings; with them,
    the identification's model predicts exactly the commanded readings at the commanded pose."""
    poses = sample_valid_postures(NOMINAL, 5, np.random.default_rng(3))
    plain = compensated_leg_readings(NOMINAL, IdentifiedEffects(), poses)
    np.testing.assert_array_equal(
        plain, NOMINAL.sensors.leg_readings(inverse_kinematics(NOMINAL, poses))
    )
    values = np.zeros(24)
    values[6:12] = 4e-6  # backlash: an extending leg is driven b / 2 further
    identified = IdentifiedEffects(values)
    directions = np.array([[1, -1, 1, -1, 1, -1]] * 5, dtype=float)
    compensated = compensated_leg_readings(NOMINAL, identified, poses, directions)
    np.testing.assert_allclose(compensated - plain, directions * 2e-6, atol=1e-15)


def test_the_geometry_file_carries_the_identified_effects():
    values = np.arange(1, 25) * 1e-7
    values[:6] = np.arange(1, 7) * 1e-8  # compliance, m/N
    identified = IdentifiedEffects(values, 40.0, (0.01, -0.02, 0.05), 1.7e9, (11.8,) * 6)
    geometry = NOMINAL.replace(effects=identified)
    text = geometry_to_yaml(geometry)
    assert 'effects:' in text and 'effects:' not in geometry_to_yaml(NOMINAL)
    for back in (
        geometry_from_yaml(text),
        geometry_from_parameters(geometry_to_parameters(geometry)),
    ):
        np.testing.assert_array_equal(back.effects.values, identified.values)
        assert back.effects.payload_mass == 40.0 and back.effects.reference_time_s == 1.7e9
        np.testing.assert_array_equal(back.effects.centre_of_mass, identified.centre_of_mass)
        assert back.effects.leg_mass == (11.8,) * 6
        np.testing.assert_array_equal(back.to_full_vector(), NOMINAL.to_full_vector())
    assert geometry_from_yaml(geometry_to_yaml(NOMINAL)).effects.none
    parameters = geometry_to_parameters(geometry)
    parameters['geometry.effects.payload_mass'] = 0.0
    with pytest.raises(GeometryError, match='geometry.effects.payload_mass'):
        geometry_from_parameters(parameters)
    parameters['geometry.effects.backlash'] = [1e-6] * 5
    with pytest.raises(GeometryError, match='geometry.effects.backlash'):
        geometry_from_parameters(parameters)


def test_only_the_identified_effects_go_into_the_parameters():
    """A controller that declares the documented rigid geometry alone refuses a set with any
    ``geometry.effects.*`` key: none without effects, only the identified groups' otherwise
    (the load with the compliance, the reference instant with the thermal growth)."""
    effects = [key for key in geometry_to_parameters(NOMINAL) if '.effects.' in key]
    assert effects == [] and 'effects:' not in geometry_to_yaml(NOMINAL)
    values = np.zeros(24)
    values[6:12] = 4e-6
    backlash = NOMINAL.replace(effects=IdentifiedEffects(values, 40.0, (0, 0, 0.05), 9.0))
    effects = [key for key in geometry_to_parameters(backlash) if '.effects.' in key]
    assert effects == ['geometry.effects.backlash']
    assert 'payload_mass' not in geometry_to_yaml(backlash)
    assert geometry_from_yaml(geometry_to_yaml(backlash)).effects.groups() == ['backlash']
    values[0:6] = 1e-8
    effects = [
        key
        for key in geometry_to_parameters(backlash.replace(effects=IdentifiedEffects(values, 40.0)))
        if '.effects.' in key
    ]
    assert sorted(effects) == sorted(
        f'geometry.effects.{key}'
        for key in ('payload_mass', 'centre_of_mass', 'compliance', 'backlash')
    )
    every = [key for key in geometry_to_parameters(NOMINAL, all_effects=True) if '.effects.' in key]
    assert len(every) == 8


def test_forward_kinematics_with_the_identified_effects_finds_the_real_pose(sequence):
    """A backlash the model holds exactly: the pose model_poses gives for the actuators'
    readings is where the real platform is; the rigid forward kinematics is micrometres off."""
    poses, times = sequence
    truth = ALONE['backlash']
    run = simulate_commands(TRUE, NOMINAL, poses, truth, times)
    values = np.zeros(24)
    values[6:12] = truth.backlash
    knowing = TRUE.replace(effects=IdentifiedEffects(values))
    found, converged = model_poses(knowing, run.leg_readings, poses, design_of(run))
    assert converged.all()
    np.testing.assert_allclose(found, run.real_poses, atol=1e-11)
    rigid, _ = model_poses(TRUE, run.leg_readings, poses, design_of(run))
    assert np.max(np.abs(rigid[:, :3] - run.real_poses[:, :3])) > 1e-6


def test_heavy_legs_are_identified_to_the_floor_and_compensated_under_a_new_load(sequence):
    """Legs of 11.8 kg (docs/platform_effects.md): the sag is about twice the massless-leg
    model's. Told the legs' mass, the compliance is the legs' own and the calibrated platform
    reaches its commands (noise free: the floor is 0); told nothing, the compliance absorbs the
    legs' weight (1.9x) and the compensation is wrong once the payload changes."""
    poses, times = sequence
    heavy = ALONE['compliance'].replace(leg_mass=np.full(6, 11.8))
    light = ALONE['compliance']
    commanded = TRUE.sensors.leg_readings(inverse_kinematics(TRUE, poses))
    sags = {}
    for name, effects in (('light', light), ('heavy', heavy)):
        reached, _ = real_poses(TRUE, effects, commanded, poses)
        sags[name] = np.linalg.norm(reached[:, :3] - poses[:, :3], axis=1).mean()
    assert 1.6 < sags['heavy'] / sags['light'] < 2.2, sags
    run = simulate_commands(TRUE, NOMINAL, poses, heavy, times)
    validation = sample_valid_postures(NOMINAL, 40, np.random.default_rng(11), WORKSPACE)
    heavier = heavy.replace(payload_mass=2 * MASS)  # the platform's new load after calibration
    errors = {}
    for name, leg_mass in (('told', heavy.leg_mass), ('not told', np.zeros(6))):
        design = EffectDesign(run.times_s, run.directions, MASS, CENTRE, leg_mass=tuple(leg_mass))
        result = identify(
            NOMINAL,
            run.leg_readings,
            run.device_readings,
            free=['extended', 'compliance'],
            pose_guesses=poses,
            effects=design,
        )
        compliance = np.array([value for value, _ in result.effects.values()])
        loaded = result.geometry.replace(
            effects=dataclasses.replace(result.geometry.effects, payload_mass=2 * MASS)
        )
        errors[name] = (
            compliance / heavy.leg_compliance,
            validate(TRUE, result.geometry, validation, heavy)['position_mm_mean'],
            validate(TRUE, loaded, validation, heavier)['position_mm_mean'],
        )
    ratio, floor, new_load = errors['told']
    np.testing.assert_allclose(ratio, 1.0, rtol=1e-3)
    assert floor < 1e-5 and new_load < 1e-5  # mm
    ratio, _, new_load = errors['not told']
    assert np.all(ratio > 1.5)
    assert new_load > 1e-3  # mm: the massless model's compensation overshoots the new load
