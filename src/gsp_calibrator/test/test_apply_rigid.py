"""Applying a calibration that identified effects (issue 33), through the nodes: to a stand-in
controller that declares only the documented rigid geometry (``geometry.*`` without
``geometry.effects.*``) the calibrator applies the rigid geometry, the effects folded in; to
platform_sim, which declares the effects, the geometry and the effects it compensates."""

import json

import numpy as np
import rclpy
from calibrator_suite import DEVICE_FREE, make_suite, perturbed_truth
from rclpy.parameter import Parameter

from gsp_calibrator.files.run_directory import RIGID_RESULT_FILE, RunDirectory
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.run.rigid import RIGID_VERDICT_PREFIX
from gsp_kinematics.model.effects import PlatformEffects
from gsp_kinematics.model.geometry import geometry_to_parameters
from gsp_msgs_py.geometry_parameters import CONTROLLER_GEOMETRY_SPECS, EFFECT_PARAMETER_PREFIX
from gsp_msgs_py.parameter_specs import declare_parameters, parameter_values

#: The realistic preset's compliance alone: 40 kg on 30 N/um legs (docs/platform_effects.md).
COMPLIANCE = PlatformEffects(
    payload_mass=40.0, centre_of_mass=(0.0, 0.0, 0.05), leg_stiffness=np.full(6, 30e6)
)
RIGID_SPECS = tuple(
    spec for spec in CONTROLLER_GEOMETRY_SPECS if not spec.name.startswith(EFFECT_PARAMETER_PREFIX)
)


def test_a_rigid_controller_gets_the_folded_geometry_and_platform_sim_the_effects(
    ros_context, tmp_path
):
    perturbed_truth(tmp_path / 'true.yaml')
    stand_in = rclpy.create_node('rigid_controller', context=ros_context)
    declare_parameters(stand_in, RIGID_SPECS)
    suite, calibrator, platform, _ = make_suite(
        ros_context,
        tmp_path,
        tmp_path / 'true.yaml',
        {
            'posture_count': 16,
            'pool_size': 160,
            'apply_result': True,
            'free_parameters': DEVICE_FREE + ['compliance'],
            'payload_mass': COMPLIANCE.payload_mass,
            'payload_centre_of_mass': COMPLIANCE.centre_of_mass.tolist(),
            'platform_node_name': 'rigid_controller',
        },
        [Parameter(k, value=v) for k, v in COMPLIANCE.to_parameters('effects.').items()],
        extra_nodes=[stand_in],
    )
    try:
        response = suite.wait(suite.call())
        assert response.success, response.message
        assert 'applied the rigid geometry to /rigid_controller' in response.message
        assert 'not compensated: compliance' in response.message
        assert 'rigid controller (no geometry.effects.*): result_rigid.yaml' in response.message
        assert RIGID_VERDICT_PREFIX in response.message, response.message
        run = RunDirectory(parse_response(response.message).run_directory)
        compensating, rigid = run.read_geometry(), run.read_geometry(RIGID_RESULT_FILE)
        assert compensating.effects.groups() == ['compliance'] and rigid.effects.none
        # The verdict gives the rigid controller's accuracy beside the compensated one.
        summary = json.loads((run.path / 'result.json').read_text())
        assert summary['rigid_accuracy']['calibrated']['position_mm']['mean'] > 0.0
        record = summary['effects']['rigid']
        predicted = record['predicted']['position_mm']['mean']
        assert predicted > record['compensated_predicted_position_mm'] > 0.0
        assert f'predicted {predicted:.3g} mm' in (run.path / 'report.md').read_text()
        applied = parameter_values(stand_in, RIGID_SPECS)
        for name, value in geometry_to_parameters(rigid).items():
            np.testing.assert_allclose(applied[name], value, rtol=0, atol=1e-12, err_msg=name)
        # The fold moved the rigid geometry off the compensating one (micrometres: the legs'
        # mean deflection under 40 kg is tens of um).
        shift = np.abs(rigid.to_vector()[:42] - compensating.to_vector()[:42])
        assert np.max(shift) > 1e-6, np.max(shift)

        calibrator.set_parameters([Parameter('platform_node_name', value='platform_sim')])
        response = suite.wait(suite.call())
        assert response.success, response.message
        assert 'applied to /platform_sim' in response.message
        assert 'effects compensated by the controller: compliance' in response.message
        run = RunDirectory(parse_response(response.message).run_directory)
        sent = geometry_to_parameters(run.read_geometry(), all_effects=True)
        for name, value in sent.items():
            np.testing.assert_allclose(
                platform.get_parameter(name).value, value, rtol=0, atol=1e-12, err_msg=name
            )
    finally:
        suite.close()
