"""gsp_calibrate_client against a fake calibrator (Trigger service + progress) in one context."""

import io

import pytest
from gsp_testing import SpinThread, wait_until

from gsp_calibrator.run.response import RESPONSE_SEPARATOR, RUN_DIRECTORY_LABEL, format_response
from gsp_calibrator.tools import client
from gsp_kinematics.model.geometry import default_geometry
from gsp_msgs_py import conversions, names
from gsp_msgs_py.qos import PROGRESS_QOS

RUN_DIRECTORY = '/tmp/runs/20260101T000000Z'
WAIT_S = 30.0  # bounds a failure only


class FakeCalibrator:
    """A node serving /gsp/calibrator/calibrate that reports progress while it 'runs'."""

    def __init__(
        self, context, success=True, service=names.SERVICE_CALIBRATE, postures=3, shown=None
    ):
        from diagnostic_msgs.msg import DiagnosticStatus
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from std_srvs.srv import Trigger

        self.node = Node('fake_calibrator', context=context)
        self.success = success
        self.postures = postures
        # None, or a function telling whether the client has shown the last progress: the
        # response waits for it (progress and response travel separately, in no given order).
        self.shown = shown
        self.calls = 0
        self.publisher = self.node.create_publisher(
            DiagnosticStatus, names.TOPIC_CALIBRATION_PROGRESS, PROGRESS_QOS
        )
        self.node.create_service(Trigger, service, self._calibrate)
        self.node.declare_parameter('noise_source', 'estimated')
        self.refuse_parameters = False
        self.node.add_on_set_parameters_callback(self._on_parameters)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)

    def _calibrate(self, request, response):
        self.calls += 1
        # The client subscribes before it calls: progress published once it is matched arrives
        # (reliable, in order). The waits only bound a failure (the assertions then say what).
        wait_until(lambda: self.publisher.get_subscription_count() > 0, WAIT_S)
        count = self.postures
        for k in range(1, count + 1):
            self.publisher.publish(
                conversions.make_progress(
                    k, count, names.PHASE_COLLECTING, {'alpha': 1.7e-5, 'leg_lengths': 2e-6}
                )
            )
        if self.success:
            self.publisher.publish(conversions.make_progress(count, count, names.PHASE_DONE))
            summary = (
                f'calibration succeeded: {count} posture(s)\n{RUN_DIRECTORY_LABEL}{RUN_DIRECTORY}'
            )
            response.message = format_response(summary, default_geometry('true'))
        else:
            self.publisher.publish(
                conversions.make_progress(
                    count, count, names.PHASE_FAILED, message='identification failed'
                )
            )
            response.message = (
                f'calibration FAILED: {count} posture(s)\nreason: no luck\n'
                f'{RUN_DIRECTORY_LABEL}{RUN_DIRECTORY}'
            )
        if self.shown is not None:
            wait_until(self.shown, WAIT_S)
        response.success = self.success
        return response

    def _on_parameters(self, parameters):
        from rcl_interfaces.msg import SetParametersResult

        if self.refuse_parameters:
            return SetParametersResult(successful=False, reason='a run is active')
        return SetParametersResult(successful=True)

    def __enter__(self):
        self.spinning = SpinThread(self.executor)
        return self

    def __exit__(self, *exc_info):
        self.spinning.stop()
        self.executor.shutdown()
        self.node.destroy_node()


def _run(context, *arguments, err=None):
    out, err = io.StringIO(), io.StringIO() if err is None else err
    args = client.build_parser().parse_args(list(arguments))
    code = client.run(args, context=context, out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def test_client_success_prints_summary_progress_and_run_directory(ros_context):
    err = io.StringIO()
    done = '[' + '#' * client.BAR_WIDTH + '] 3/3 done'
    with FakeCalibrator(ros_context, shown=lambda: done in err.getvalue()) as fake:
        code, out, err = _run(ros_context, '--wait-timeout', '10', '--geometry', err=err)
    assert code == 0, err
    assert fake.calls == 1
    assert 'calibration succeeded: 3 posture(s)' in out
    assert f'run directory: {RUN_DIRECTORY}' in out
    assert 'ros__parameters' in out  # --geometry: the calibrated params file
    assert RESPONSE_SEPARATOR not in out
    assert '] 1/3 collecting' in err and '] 3/3 collecting' in err
    assert done in err
    assert 'alpha' in err and 'deg' in err  # latest residuals


def test_client_failure_exits_1(ros_context):
    with FakeCalibrator(ros_context, success=False):
        code, out, err = _run(ros_context, '--wait-timeout', '10', '--no-progress')
    assert code == 1
    assert 'calibration FAILED' in out and 'reason: no luck' in out
    assert f'run directory: {RUN_DIRECTORY}' in out
    assert 'calibration failed' in err
    assert 'collecting' not in err  # --no-progress


def test_client_sets_the_noise_source_before_the_call(ros_context):
    with FakeCalibrator(ros_context) as fake:
        code, out, err = _run(
            ros_context,
            '--wait-timeout',
            '10',
            '--no-progress',
            '--noise-source',
            'configured',
            '--calibrator',
            'fake_calibrator',
        )
        assert code == 0, err
        assert fake.node.get_parameter('noise_source').value == 'configured'
        assert fake.calls == 1
        fake.refuse_parameters = True
        code, out, err = _run(
            ros_context,
            '--wait-timeout',
            '10',
            '--noise-source',
            'estimated',
            '--calibrator',
            'fake_calibrator',
        )
        assert code == 1 and fake.calls == 1  # not called with the wrong noise source
        assert 'noise_source not set: noise_source rejected: a run is active' in err


def test_client_without_service_times_out(ros_context):
    code, out, err = _run(
        ros_context, '--service', '/gsp/test/no_such_service', '--wait-timeout', '0.3'
    )
    assert code == 1
    assert 'not available after 0.3 s' in err and out == ''


def test_progress_bar_rendering():
    stream = io.StringIO()
    bar = client.ProgressBar(stream, width=10, interactive=True)
    bar.update(
        conversions.parse_progress(
            conversions.make_progress(5, 10, names.PHASE_COLLECTING, {'d_m': 1e-6})
        )
    )
    bar.finish()
    text = stream.getvalue()
    assert text.startswith('\r\x1b[2K[#####-----] 5/10 collecting')
    assert 'd_m 1 um' in text and text.endswith('\n')
    quiet = io.StringIO()
    bar = client.ProgressBar(quiet, interactive=False)
    for k in range(0, 61):
        bar.update(
            conversions.parse_progress(conversions.make_progress(k, 60, names.PHASE_COLLECTING))
        )
    lines = quiet.getvalue().splitlines()
    assert 5 <= len(lines) <= 12  # about every tenth posture, not one line per update
    assert lines[-1].endswith('60/60 collecting')


@pytest.mark.parametrize('argv', [['--help']])
def test_main_help_exits_cleanly(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        client.main(argv)
    assert exit_info.value.code == 0
    assert 'gsp_calibrate_client' in capsys.readouterr().out


class FakeChecker(FakeCalibrator):
    """A calibrator's /gsp/calibrator/check answering ``verdict``."""

    def __init__(self, context, verdict):
        super().__init__(context, service=names.SERVICE_CHECK)
        self.verdict = verdict

    def _calibrate(self, request, response):
        self.calls += 1
        response.success = True
        response.message = f'check: {self.verdict} (platform default, 9 postures)\nrun directory: x'
        return response


@pytest.mark.parametrize(
    ('verdict', 'code'), [('WITHIN TOLERANCE', client.EXIT_OK), ('RECALIBRATE', 3)]
)
def test_client_check_calls_the_check_and_exits_by_its_verdict(ros_context, verdict, code):
    with FakeChecker(ros_context, verdict) as fake:
        found, out, _ = _run(ros_context, '--check', '--wait-timeout', '10', '--no-progress')
    assert fake.calls == 1 and found == code
    assert out.startswith(f'check: {verdict}')
