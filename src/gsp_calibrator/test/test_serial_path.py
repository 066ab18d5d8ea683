"""The calibrator through the serial path: platform_sim -> gsp_fake_device (pty) -> device_driver
(serial backend) -> calibrator, in one process. A silence of the device (until the run ends) is
reported as a silent topic; an unplug and replug mid-stream resumes publishing without a restart."""

import gsp_testing
import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from gsp_calibrator.node.calibrator_node import CalibratorNode
from gsp_calibrator.run.response import parse_response
from gsp_device_driver.device_driver_node import DeviceDriverNode
from gsp_device_driver.fake_device_node import FakeDeviceNode, parse_arguments
from gsp_msgs_py import names, qos
from gsp_platform_sim.platform_sim_node import PlatformSimNode

RATE_HZ = 100.0
TIMEOUT_S = 120.0


def wait_until(predicate, timeout=TIMEOUT_S):
    return gsp_testing.wait_until(predicate, timeout)


def test_silence_and_unplug_on_the_serial_path(ros_context, tmp_path):
    import rclpy

    link = tmp_path / 'gsp_device'
    rate = Parameter('publish_rate', value=RATE_HZ)
    platform = PlatformSimNode(
        context=ros_context, parameter_overrides=[rate, Parameter('publish_markers', value=False)]
    )
    args, _ = parse_arguments(['--port', str(link), '--rate', str(RATE_HZ)])
    fake = FakeDeviceNode(args, context=ros_context)
    driver = DeviceDriverNode(
        context=ros_context,
        parameter_overrides=[
            rate,
            Parameter('backend', value='serial'),
            Parameter('serial.port', value=str(link)),
            Parameter('serial.reconnect_interval', value=0.05),
        ],
    )
    calibrator = CalibratorNode(
        context=ros_context,
        parameter_overrides=[
            Parameter('posture_count', value=20),
            Parameter('pool_size', value=80),
            Parameter('pairs_per_posture', value=5),
            Parameter('sync_tolerance', value=0.5 / RATE_HZ),
            # The silence below lasts until the run fails: the timeout needs no margin to it, only
            # enough not to take a loaded machine's pause of the simulator for a silence.
            Parameter('topic_timeout', value=5.0),
            Parameter('output_root', value=str(tmp_path / 'runs')),
            Parameter('write_report_plots', value=False),  # the test is of the serial path
        ],
    )
    client_node = rclpy.create_node('serial_path_test', context=ros_context)
    lvdt = []
    client_node.create_subscription(
        JointState, names.TOPIC_LVDT, lvdt.append, qos.TOPIC_QOS[names.TOPIC_LVDT]
    )
    progress = []
    calibrator_progress = names.TOPIC_CALIBRATION_PROGRESS
    from diagnostic_msgs.msg import DiagnosticStatus

    client_node.create_subscription(
        DiagnosticStatus, calibrator_progress, progress.append, qos.TOPIC_QOS[calibrator_progress]
    )
    client = client_node.create_client(Trigger, names.SERVICE_CALIBRATE)
    nodes = [platform, fake, driver, calibrator, client_node]
    spinning = gsp_testing.SpinningNodes(
        ros_context, together=[calibrator, client_node], apart=[platform, fake, driver]
    )
    try:
        assert client.wait_for_service(timeout_sec=30.0)
        future = client.call_async(Trigger.Request())
        assert wait_until(
            lambda: future.done() or sum('averaged' in p.message for p in list(progress)) >= 3
        )
        fake.device.silence(3600.0)
        assert wait_until(future.done)
        fake.device.silence(0.0)  # the device speaks again
        response = future.result()
        assert not response.success
        assert 'is silent' in response.message and '/gsp/device/' in response.message, (
            response.message
        )
        assert parse_response(response.message).run_directory  # the samples are kept

        # Unplug and replug: the driver reconnects and publishes again, without a restart.
        backend = driver._backend
        assert wait_until(lambda: backend.counters['readings'] > 0 and len(lvdt) > 0)
        fake.device.disconnect(0.5)
        assert wait_until(lambda: backend.counters['disconnects'] == 1)
        heard = len(lvdt)
        assert wait_until(lambda: backend.counters['connects'] >= 2 and len(lvdt) > heard + 20)
        assert np.isfinite(lvdt[-1].position[0])
    finally:
        spinning.close()
        for node in nodes:
            node.destroy_node()
