"""Right by default (issue 33), through the nodes: the calibrator with no parameter but
``apply_result`` (and where it writes its runs) calibrates the realistic ``platform_sim`` (40 kg on
compliant legs, backlash, warming, base joint offsets; no payload mass told) and applies the
result to ``platform_sim``, which compensates the effects; the response says which effects are
compensated, and the run also gives the rigid geometry (the effects folded in) and the verdict
that lets it be applied to a controller that declares only the documented rigid geometry. One
run at the defaults: how a rigid controller gets that geometry (through its parameters) is
test_apply_rigid's, on a shorter run."""

import json

import numpy as np
from calibrator_suite import Suite
from rclpy.parameter import Parameter

from gsp_calibrator.files.run_directory import RIGID_RESULT_FILE, RunDirectory
from gsp_calibrator.node.calibrator_node import CalibratorNode
from gsp_calibrator.run.response import parse_response
from gsp_calibrator.run.rigid import RIGID_VERDICT_PREFIX
from gsp_kinematics.model.effects import REALISTIC
from gsp_kinematics.model.geometry import geometry_to_parameters


def _run(suite):
    """The response of one calibration and its run directory."""
    response = suite.wait(suite.call())
    assert response.success, response.message
    return response.message, RunDirectory(parse_response(response.message).run_directory)


def test_the_defaults_apply_to_a_compensating_controller_and_fold_for_a_rigid_one(
    ros_context, tmp_path
):
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
    suite = Suite(ros_context, [calibrator, platform, device])
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

        # What a rigid controller would get: the geometry with the effects folded in, and a
        # verdict of its own that accepts it (result_delivery applies what its verdict accepts).
        rigid = run.read_geometry(RIGID_RESULT_FILE)
        assert rigid.effects.none and not geometry.effects.none
        assert summary['rigid_acceptance']['accepted'], summary['rigid_acceptance']['text']
        assert summary['rigid_accuracy']['calibrated']['position_mm']['mean'] > 0.0
    finally:
        suite.close()
