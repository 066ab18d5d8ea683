"""Right by default (issue 33), through the nodes: the calibrator with no parameter but
``apply_result`` (and where it writes its runs) calibrates the realistic ``platform_sim`` (40 kg on
compliant legs, backlash, warming, base joint offsets; no payload mass told) and applies the
result to ``platform_sim``, which compensates the effects, and to a stand-in controller that
declares only the documented rigid geometry; the response says which effects are compensated and
gives the rigid controller's accuracy."""

import json

import numpy as np
import rclpy
from calibrator_suite import Suite
from rclpy.parameter import Parameter

from gsp_calibrator.files.run_directory import RIGID_RESULT_FILE, RunDirectory
from gsp_calibrator.node.calibrator_node import CalibratorNode
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.run.rigid import RIGID_VERDICT_PREFIX
from gsp_kinematics.model.effects import REALISTIC
from gsp_kinematics.model.geometry import geometry_to_parameters
from gsp_msgs_py.geometry_parameters import CONTROLLER_GEOMETRY_SPECS, EFFECT_PARAMETER_PREFIX
from gsp_msgs_py.parameter_specs import declare_parameters, parameter_values

RIGID_SPECS = tuple(
    spec for spec in CONTROLLER_GEOMETRY_SPECS if not spec.name.startswith(EFFECT_PARAMETER_PREFIX)
)


def _run(suite):
    """The response of one calibration and its run directory."""
    response = suite.wait(suite.call())
    assert response.success, response.message
    return response.message, RunDirectory(parse_response(response.message).run_directory)


def test_the_defaults_apply_to_a_compensating_and_a_rigid_controller(ros_context, tmp_path):
    from gsp_device_driver.device_driver_node import DeviceDriverNode
    from gsp_platform_sim.platform_sim_node import PlatformSimNode

    # platform_sim and device_driver at their defaults (shipped true geometry, 200 Hz), the
    # realistic platform's effects; the calibrator is told nothing of them.
    platform = PlatformSimNode(
        context=ros_context,
        parameter_overrides=[Parameter('publish_markers', value=False)]
        + [Parameter(k, value=v) for k, v in REALISTIC.to_parameters('effects.').items()],
    )
    device = DeviceDriverNode(context=ros_context)
    calibrator = CalibratorNode(
        context=ros_context,
        parameter_overrides=[
            Parameter('apply_result', value=True),
            Parameter('output_root', value=str(tmp_path / 'runs')),
        ],
    )
    stand_in = rclpy.create_node('rigid_controller', context=ros_context)
    declare_parameters(stand_in, RIGID_SPECS)
    suite = Suite(ros_context, [calibrator, platform, device, stand_in])
    try:
        message, run = _run(suite)
        assert 'applied to /platform_sim' in message, message
        summary = json.loads((run.path / 'result.json').read_text())
        groups = summary['effects']['groups']
        # The load was never weighed: the compliance is identified all the same, and said so.
        assert 'compliance' in groups, summary['effects']['model_choice']['reason']
        assert summary['effects']['payload_assumed'], summary['effects']
        # The thermal drift is reported, not compensated: the geometry refers to the run's end.
        compensated = ', '.join(group for group in groups if group != 'thermal')
        assert f'effects compensated by the controller: {compensated}' in message, message
        assert RIGID_VERDICT_PREFIX in message, message
        geometry = run.read_geometry()
        for name, value in geometry_to_parameters(geometry, all_effects=True).items():
            np.testing.assert_allclose(
                platform.get_parameter(name).value, value, rtol=0, atol=1e-12, err_msg=name
            )
        # The 95 % interval of the held-out accuracy, in the response's head and result.json.
        low, high = summary['accuracy']['calibrated']['position_mm']['mean_interval_95']
        assert 0.0 < low <= summary['accuracy']['calibrated']['position_mm']['mean'] <= high

        calibrator.set_parameters([Parameter('platform_node_name', value='rigid_controller')])
        message, run = _run(suite)
        assert 'applied the rigid geometry to /rigid_controller' in message, message
        assert 'not compensated: ' in message and RIGID_VERDICT_PREFIX in message, message
        rigid = run.read_geometry(RIGID_RESULT_FILE)
        assert rigid.effects.none and not run.read_geometry().effects.none
        applied = parameter_values(stand_in, RIGID_SPECS)
        for name, value in geometry_to_parameters(rigid).items():
            np.testing.assert_allclose(applied[name], value, rtol=0, atol=1e-12, err_msg=name)
        rigid_accuracy = json.loads((run.path / 'result.json').read_text())['rigid_accuracy']
        assert rigid_accuracy['calibrated']['position_mm']['mean'] > 0.0
    finally:
        suite.close()
