"""Test helpers shared by test_replay.py and test_replay_revisits.py: a live calibration
through platform_sim, device_driver and the calibrator, and its replay to a fresh calibrator."""

import gsp_testing
import rclpy
from calibrator_suite import spin_as_in_use
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from gsp_calibrator.files.run_directory import RunDirectory
from gsp_calibrator.replay.replay_node import ReplayNode
from gsp_calibrator.run.response import parse_response
from gsp_msgs_py import names

TIMEOUT_S = 20.0  # generous: the machine may be loaded; waits end as soon as they can
#: The replay's and platform_sim's settle (s): short, the tests wait on statuses.
FAST = [Parameter('settle_time', value=0.02)]

# Generous timeouts: they only bound a failure, and CI machines are loaded.
CALIBRATION = {
    'posture_count': 14,
    'pool_size': 42,
    'pairs_per_posture': 3,
    'seed': 5,
    'topic_timeout': 10.0,
    'settle_timeout': 10.0,
    # The test is of the replay, not of the verdict: 14 postures for 51 parameters leave each
    # fold's fit (12 postures) poor, so the held-out accuracy misses the default 0.1 mm.
    'required_position_accuracy_mm': 10.0,
    'write_report_plots': False,  # ... nor of the report's plots (slow to draw)
    # A replayed samples.csv republishes averaged rows, without the within-posture scatter an
    # estimated noise uses: the replay gives the same calibration with the configured sigmas.
    'noise_source': 'configured',
    # The replay rests at the original's last posture, so a route from there would command the
    # postures in another order than the original's (a route from home).
    'posture_order': 'selection',
}


class Suite:
    """Nodes spun as in use (``spin_as_in_use``), plus a client of the calibrate service."""

    def __init__(self, context, nodes):
        self.nodes = list(nodes)
        self.client_node = rclpy.create_node('replay_test_client', context=context)
        self.client = self.client_node.create_client(Trigger, names.SERVICE_CALIBRATE)
        self.spinning = spin_as_in_use(context, self.nodes, self.client_node, num_threads=3)

    def calibrate(self, timeout=120.0):
        assert self.client.wait_for_service(timeout_sec=TIMEOUT_S), 'calibrate service missing'
        future = self.client.call_async(Trigger.Request())
        assert gsp_testing.wait_until(future.done, timeout), 'no calibrate response'
        response = future.result()
        assert response.success, response.message
        return RunDirectory(parse_response(response.message).run_directory)

    def close(self):
        self.spinning.close()
        for node in self.nodes + [self.client_node]:
            node.destroy_node()


def calibrator_node(context, output_root, settings=None):
    """A calibrator with ``settings`` ({parameter: value}; default :data:`CALIBRATION`)."""
    from gsp_calibrator.node.calibrator_node import CalibratorNode

    settings = CALIBRATION if settings is None else settings
    overrides = [Parameter(name, value=value) for name, value in settings.items()]
    overrides.append(Parameter('output_root', value=str(output_root)))
    return CalibratorNode(context=context, parameter_overrides=overrides)


def live_run(tmp_path_factory, settings=None):
    """The run directory of one live calibration with ``settings`` (default
    :data:`CALIBRATION`) through platform_sim, device_driver and the calibrator."""
    from gsp_device_driver.device_driver_node import DeviceDriverNode
    from gsp_platform_sim.platform_sim_node import PlatformSimNode

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        live = Suite(
            context,
            [
                PlatformSimNode(
                    context=context,
                    parameter_overrides=FAST + [Parameter('publish_markers', value=False)],
                ),
                DeviceDriverNode(context=context),
                calibrator_node(context, tmp_path_factory.mktemp('live'), settings),
            ],
        )
        try:
            return live.calibrate()
        finally:
            live.close()
    finally:
        rclpy.try_shutdown(context=context)


def replay_run(context, run, output_root, settings=None):
    """Replay ``run`` (a path) to a fresh calibrator with ``settings`` (default
    :data:`CALIBRATION`): the replay node and the replayed run."""
    node = ReplayNode(context=context, parameter_overrides=FAST + [Parameter('run', value=run)])
    suite = Suite(context, [node, calibrator_node(context, output_root, settings)])
    try:
        return node, suite.calibrate()
    finally:
        suite.close()
