"""The calibrator, platform_sim and device_driver nodes in one test process, spun as in use.

:func:`make_suite` builds the three nodes (100 Hz streams: three nodes share one Python process)
and a :class:`Suite` with the test's client of the calibrate service; :func:`perturbed_truth`
writes a true platform that the calibration must find. The calibrator's node tests share them
(test_calibrator_node, test_faults, test_disk_full, test_noise_unknown, test_upkeep_node,
test_replay). rclpy and the nodes are imported here, so only the calibrator's tests import this.
"""

import gsp_testing
import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from gsp_calibrator.node.calibrator_node import CalibratorNode
from gsp_kinematics.model.geometry import default_geometry, save_geometry
from gsp_msgs_py import conversions, names, qos

RATE_HZ = 100.0
#: A safety net, not a speed target: a run of 16 postures under a load of 10-12 on 2 cores took
#: over 120 s (the tests wait on the response, an event).
CALL_TIMEOUT_S = 600.0
DEVICE_FREE = ['Loff1', 'Loff2', 'Loff3', 'Loff4', 'Loff5', 'Loff6', 'D0', 'gamma']


def calibrator_parameters(output_root, **overrides):
    values = {
        'posture_count': 12,
        'pool_size': 120,
        'pairs_per_posture': 5,
        'sync_tolerance': 0.5 / RATE_HZ,
        'topic_timeout': 10.0,
        'settle_timeout': 10.0,
        'output_root': str(output_root),
        'free_parameters': DEVICE_FREE,
        # Drawing the report's PNGs takes the calibrator many seconds while the sensor streams
        # hold the GIL; the tests need the tables (test_report and test_end_to_end draw them).
        'write_report_plots': False,
    }
    values.update(overrides)
    return [Parameter(name, value=value) for name, value in values.items()]


#: The parameters in which :func:`perturbed_truth` differs from the nominal.
PERTURBED = [f'Loff{leg}' for leg in range(1, 7)] + ['D0', 'gamma']


def perturbed_truth(path):
    """A true platform that differs from the nominal only in the leg offsets and the device."""
    nominal = default_geometry('nominal')
    truth = nominal.replace(
        leg_offsets=nominal.leg_offsets + np.array([1.0, -2.0, 0.5, 1.5, -1.0, 2.0]) * 1e-3,
        device_length=nominal.device_length + 0.8e-3,
        inclinometer_axes_angle=nominal.inclinometer_axes_angle + 0.004,
    )
    save_geometry(truth, path)
    return truth


def spin_as_in_use(context, nodes, client_node, num_threads=4):
    """``gsp_testing.SpinningNodes``: the calibrators with the test's client, every other node apart."""
    calibrators = [node for node in nodes if isinstance(node, CalibratorNode)]
    return gsp_testing.SpinningNodes(
        context,
        together=calibrators + [client_node],
        apart=[node for node in nodes if node not in calibrators],
        num_threads=num_threads,
    )


class Suite:
    """In-process nodes spun as in use (``gsp_testing.SpinningNodes``) plus a test client."""

    def __init__(self, context, nodes):
        import rclpy

        self.context = context
        self.nodes = list(nodes)
        self.client_node = rclpy.create_node('calibrator_test_client', context=context)
        self.progress = []
        self.results = []
        self.client_node.create_subscription(
            DiagnosticStatus,
            names.TOPIC_CALIBRATION_PROGRESS,
            lambda m: self.progress.append(conversions.parse_progress(m)),
            qos.TOPIC_QOS[names.TOPIC_CALIBRATION_PROGRESS],
        )
        self.client = self.client_node.create_client(Trigger, names.SERVICE_CALIBRATE)
        self.spinning = spin_as_in_use(context, self.nodes, self.client_node)
        assert self.client.wait_for_service(timeout_sec=30.0)

    def call(self):
        return self.client.call_async(Trigger.Request())

    @staticmethod
    def wait_until(predicate, timeout=CALL_TIMEOUT_S):
        """Wait for an event (``predicate()``); False if it has not come within ``timeout``."""
        return gsp_testing.wait_until(predicate, timeout)

    def wait(self, future, timeout=CALL_TIMEOUT_S):
        assert self.wait_until(future.done, timeout), 'no calibrate response'
        return future.result()

    def phase_seen(self, phase):
        return any(p.phase == phase for p in list(self.progress))

    def stop_spinning(self, node):
        """The node's callbacks stop (its timers no longer publish); destroyed in close()."""
        self.spinning.remove(node)

    def close(self):
        self.spinning.close()
        for node in self.nodes + [self.client_node]:
            node.destroy_node()


def make_suite(
    context,
    tmp_path,
    truth_file,
    calibrator_overrides=(),
    platform_overrides=(),
    device_overrides=(),
    extra_nodes=(),
):
    """The calibrator (``calibrator_overrides`` on :func:`calibrator_parameters`), platform_sim
    of ``truth_file`` and device_driver, and ``extra_nodes`` (the test's, e.g. a stand-in
    controller), spun in a :class:`Suite`: ``(suite, calibrator, platform, device)``."""
    from gsp_device_driver.device_driver_node import DeviceDriverNode
    from gsp_platform_sim.platform_sim_node import PlatformSimNode

    rate = [
        Parameter('publish_rate', value=RATE_HZ),
        Parameter('true_geometry_file', value=str(truth_file)),
    ]
    platform = PlatformSimNode(
        context=context,
        parameter_overrides=rate
        + [Parameter('publish_markers', value=False)]
        + list(platform_overrides),
    )
    device = DeviceDriverNode(context=context, parameter_overrides=rate + list(device_overrides))
    calibrator = CalibratorNode(
        context=context,
        parameter_overrides=calibrator_parameters(tmp_path / 'runs', **dict(calibrator_overrides)),
    )
    suite = Suite(context, [calibrator, platform, device, *extra_nodes])
    return suite, calibrator, platform, device
