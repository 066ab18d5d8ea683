"""In-process tests of the device_driver node: a test node plays the platform's true pose."""

import math
from collections import defaultdict

import gsp_testing
import numpy as np
import pytest
from rclpy.parameter import Parameter

from gsp_device_driver.device_driver_node import DeviceDriverNode
from gsp_kinematics.model.device import device_readings
from gsp_kinematics.model.geometry import default_geometry
from gsp_msgs_py import conversions, names
from gsp_msgs_py.health import ERROR, OK, WARN
from gsp_msgs_py.parameter_specs import ConfigurationError

TRUE = default_geometry('true')
POSE = np.array([0.05, -0.03, 0.97, 0.08, -0.05, 0.2])
TIMEOUT_S = 10.0
TOPICS = (names.TOPIC_INCLINOMETER, names.TOPIC_ENCODER, names.TOPIC_LVDT)


class Harness(gsp_testing.NodeHarness):
    """device_driver plus a test node publishing true poses and recording readings."""

    def __init__(self, context, overrides=()):
        self.driver = DeviceDriverNode(context=context, parameter_overrides=list(overrides))
        super().__init__(context, self.driver, 'device_driver_test', TIMEOUT_S)
        self.received = defaultdict(list)  # topic -> [JointState]
        for topic in TOPICS:
            self.subscribe(topic, lambda m, t=topic: self.received[t].append(m))
        self.pose_pub = self.publisher(names.TOPIC_TRUE_POSE)
        self.true_pose_msg = None  # republished at 100 Hz while set, like platform_sim
        self._sent = {}  # id of a true pose message -> stamps (ns) it was published with
        self.node.create_timer(0.01, self._publish_true_pose)
        assert self.spin_until(
            lambda: (
                (
                    self.pose_pub.get_subscription_count() > 0
                    or not self.driver._backend.needs_true_pose
                )
                and all(self.node.count_publishers(t) > 0 for t in TOPICS)
            )
        ), 'no discovery'

    def _publish_true_pose(self):
        msg = self.true_pose_msg
        if msg is not None:
            msg.header.stamp = self.node.get_clock().now().to_msg()
            self.pose_pub.publish(msg)
            self._sent.setdefault(id(msg), set()).add(
                conversions.stamp_to_nanoseconds(msg.header.stamp)
            )

    def published_stamps(self, msg):
        """Publish ``msg`` as the true pose from now on; the set (growing) of its stamps (ns)."""
        self.true_pose_msg = msg
        return self._sent.setdefault(id(msg), set())

    def readings_after(self, count):
        """``count`` complete readings (N, 4) [alpha, beta, phi, d_m] taken from now on, and
        their stamps; a reading is complete when all three topics arrived with one stamp."""
        for topic in TOPICS:
            self.received[topic].clear()

        def complete():
            by_topic = [
                {conversions.stamp_to_nanoseconds(m.header.stamp): m for m in self.received[t]}
                for t in TOPICS
            ]
            return sorted(set(by_topic[0]) & set(by_topic[1]) & set(by_topic[2])), by_topic

        assert self.spin_until(lambda: len(complete()[0]) >= count)
        stamps, (inclinometer, encoder, lvdt) = complete()
        readings = np.array(
            [
                [
                    *conversions.msg_to_inclinometer(inclinometer[s]),
                    conversions.msg_to_encoder(encoder[s]),
                    conversions.msg_to_lvdt(lvdt[s]),
                ]
                for s in stamps
            ]
        )
        return readings, stamps


harness = gsp_testing.harness_fixture(Harness)


NOISE_FREE = [
    Parameter('inclinometer_noise_std', value=0.0),
    Parameter('encoder_noise_std', value=0.0),
    Parameter('lvdt_noise_std', value=0.0),
]


@pytest.mark.parametrize('harness', [NOISE_FREE], indirect=True)
def test_noise_free_readings_are_the_device_model_of_the_true_pose(harness):
    harness.spin_for(0.1)
    assert not any(harness.received.values()), 'readings before the first true pose'
    harness.true_pose_msg = conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE)
    readings, stamps = harness.readings_after(5)
    np.testing.assert_allclose(
        readings,
        np.broadcast_to(
            TRUE.sensors.device_readings(device_readings(TRUE, POSE[None])[0]), readings.shape
        ),
        rtol=0,
        atol=1e-12,
    )
    msg = harness.received[names.TOPIC_INCLINOMETER][-1]
    assert list(msg.name) == ['alpha', 'beta'] and msg.header.frame_id == names.FRAME_BASE
    assert list(harness.received[names.TOPIC_ENCODER][-1].name) == ['phi']
    assert list(harness.received[names.TOPIC_LVDT][-1].name) == ['d_m']


def test_readings_match_within_the_noise_and_share_one_stamp(harness):
    harness.true_pose_msg = conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE)
    readings, stamps = harness.readings_after(20)
    stds = np.array([math.radians(0.001)] * 3 + [1e-6])
    errors = readings - TRUE.sensors.device_readings(device_readings(TRUE, POSE[None])[0])
    assert np.all(np.abs(errors) < 6 * stds), errors / stds
    assert np.all(np.std(errors, axis=0) > 0.1 * stds)  # noise is there
    # The 20 complete readings are 20 stamps that all three topics carry (no fixed share of the
    # best-effort messages: a loaded test node may drop some of any topic).
    assert len(set(stamps)) == len(stamps) >= 20


@pytest.mark.parametrize(
    'harness',
    [[Parameter('publish_rate', value=20.0), Parameter('use_sim_time', value=True)]],
    indirect=True,
)
def test_sim_readings_are_stamped_exactly_at_the_timer_ticks(harness):
    # The sim backend samples at the publish timer: its stamps are the timer's scheduled ticks,
    # not the callback's clock readings. Under the simulated clock (steps off the 50 ms grid,
    # still between the reads of one callback), the ticks are on one grid to the ns, and the
    # instants the callbacks ran at are not.
    harness.true_pose_msg = conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE)
    _, stamps = harness.readings_after(6)
    assert len(gsp_testing.grid_offsets(stamps, 50_000_000)) == 1, stamps


def test_bad_true_poses_are_ignored_and_the_driver_keeps_going(harness):
    harness.true_pose_msg = conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE)
    harness.readings_after(2)
    exact = TRUE.sensors.device_readings(device_readings(TRUE, POSE[None])[0])
    nan_pose = conversions.pose_to_pose_stamped(POSE + 0.01, None, names.FRAME_BASE)
    nan_pose.pose.position.x = math.nan
    wrong_frame = conversions.pose_to_pose_stamped(POSE + 0.01, None, 'world')
    not_unit = conversions.pose_to_pose_stamped(POSE + 0.01, None, names.FRAME_BASE)
    not_unit.pose.orientation.w = 2.0
    at_origin = conversions.pose_to_pose_stamped(np.zeros(6), None, names.FRAME_BASE)
    # Each bad pose is republished until the driver has taken one (its true-pose callback,
    # observed here, ran with it), then the next replaces it.
    taken = set()  # stamps (ns) of the true poses the driver's callback has run with
    subscription = next(
        s for s in harness.driver.subscriptions if s.topic_name == names.TOPIC_TRUE_POSE
    )
    driver_callback = subscription.callback

    def observed(msg):
        driver_callback(msg)
        taken.add(conversions.stamp_to_nanoseconds(msg.header.stamp))

    subscription.callback = observed
    for bad in (nan_pose, wrong_frame, not_unit, at_origin):
        sent = harness.published_stamps(bad)
        assert harness.spin_until(lambda sent=sent: sent & taken), bad
    harness.true_pose_msg = None
    readings, _ = harness.readings_after(3)
    assert np.all(np.abs(readings - exact) < 6 * np.array([1.75e-5] * 3 + [1e-6]))


def test_noise_parameters_change_at_run_time_and_refuse_negative_values(harness):
    driver = harness.driver
    for name in ('inclinometer_noise_std', 'encoder_noise_std', 'lvdt_noise_std'):
        result = driver.set_parameters([Parameter(name, value=-1e-6)])[0]
        assert not result.successful and name in result.reason
    result = driver.set_parameters([Parameter('inclinometer_noise_std', value=8.7e-5)])[0]
    assert result.successful
    assert driver.get_parameter('inclinometer_noise_std').value == 8.7e-5
    np.testing.assert_allclose(
        driver._backend.noise.readings(), [8.7e-5, 8.7e-5, math.radians(0.001), 1e-6]
    )
    assert 'read-only' in driver.set_parameters([Parameter('backend', value='replay')])[0].reason


FAST_DIAGNOSTICS = [Parameter('diagnostics_period', value=0.05)]


@pytest.mark.parametrize('harness', [FAST_DIAGNOSTICS], indirect=True)
def test_diagnostics_say_whether_the_sim_device_follows_a_live_true_pose(harness):
    name = 'device_driver: device'
    health = harness.wait_health(name)
    assert health.level == WARN and health.message == 'waiting for the first true pose'
    assert harness.diagnostics.hardware_ids[name] == 'sim'

    harness.published_stamps(conversions.pose_to_pose_stamped(POSE, None, names.FRAME_BASE))
    # (The first report after the first reading may hold that reading alone: no rate yet.)
    health = harness.wait_health(
        name, lambda h: h.level == OK and float(h.values['reading_rate_hz']) > 0
    )
    assert int(health.values['readings']) > 0
    assert float(health.values['lvdt_noise_std_m']) == pytest.approx(1e-6, rel=1e-5)
    assert float(health.values['encoder_noise_std_rad']) == pytest.approx(math.radians(0.001))

    # platform_sim gone: the readings repeat the last pose, which the status says.
    harness.true_pose_msg = None
    health = harness.wait_health(name, lambda h: h.level == WARN)
    assert 'no true pose since the last report' in health.message


@pytest.mark.parametrize(
    'overrides, words',
    [
        (
            [Parameter('backend', value='replay')],
            "unknown device backend 'replay'; valid backends: physics, serial, sim",
        ),
        ([Parameter('publish_rate', value=0.0)], 'publish_rate'),
        ([Parameter('lvdt_noise_std', value=-1e-6)], 'lvdt_noise_std'),
        ([Parameter('inclinometer_response_time', value=-0.1)], 'inclinometer_response_time'),
        ([Parameter('true_geometry_file', value='/nonexistent/geometry.yaml')], 'nonexistent'),
    ],
)
def test_bad_start_up_parameters_are_a_clear_error(ros_context, overrides, words):
    with pytest.raises(ConfigurationError, match=words):
        DeviceDriverNode(context=ros_context, parameter_overrides=overrides)


def test_the_sensor_dynamics_parameters_reach_the_sim_backend(ros_context):
    driver = DeviceDriverNode(
        context=ros_context,
        parameter_overrides=[
            Parameter('inclinometer_response_time', value=0.3),
            Parameter('lvdt_noise_correlation_time', value=0.001),
        ],
    )
    try:
        described = driver._backend.describe()
    finally:
        driver.destroy_node()
    assert 'inclinometer response 0.3 s, noise correlation 0 s' in described
    assert 'lvdt response 0 s, noise correlation 0.001 s' in described


def test_the_serial_backend_publishes_every_reading_of_the_emulated_device(ros_context, tmp_path):
    from gsp_device_driver.fake_device import FakeDevice

    link = tmp_path / 'gsp_device'
    exact = device_readings(TRUE, POSE[None])[0]
    fake = FakeDevice(link, lambda: exact, garbage_fraction=0.05, rng=np.random.default_rng(3))
    overrides = [
        Parameter('backend', value='serial'),
        Parameter('serial.port', value=str(link)),
        Parameter('serial.reconnect_interval', value=0.05),
        *FAST_DIAGNOSTICS,
    ]
    harness = Harness(ros_context, overrides)
    try:
        fake.start()
        readings, stamps = harness.readings_after(20)
        np.testing.assert_allclose(readings, np.broadcast_to(exact, readings.shape), atol=1e-9)
        # Every garbage line sent is counted once the backend has read what is on the line:
        # stop sending (the port stays open), then wait for the backend to catch up.
        fake.silence(3600.0)
        backend = harness.driver._backend
        assert harness.spin_until(lambda: backend.counters['garbage'] == fake.counters['garbage'])
        # ... and on /diagnostics, where the port names the hardware.
        name = 'device_driver: device'
        garbage = str(fake.counters['garbage'])
        health = harness.wait_health(name, lambda h: h.values.get('dropped_garbage') == garbage)
        assert health.level in (OK, WARN) and health.values['units'] == 'rad/m'
        assert harness.diagnostics.hardware_ids[name] == str(link)
        result = harness.driver.set_parameters([Parameter('lvdt_noise_std', value=1e-5)])[0]
        assert not result.successful and 'no simulated noise' in result.reason
    finally:
        fake.close()
        harness.close()


def test_diagnostics_report_a_serial_port_that_cannot_be_opened(ros_context, tmp_path):
    overrides = [
        Parameter('backend', value='serial'),
        Parameter('serial.port', value=str(tmp_path / 'absent')),
        Parameter('serial.reconnect_interval', value=0.05),
        *FAST_DIAGNOSTICS,
    ]
    harness = Harness(ros_context, overrides)
    try:
        health = harness.wait_health('device_driver: device')
        assert health.level == ERROR and 'not open' in health.message
        assert health.values['connects'] == '0' and health.values['lines'] == '0'
    finally:
        harness.close()
