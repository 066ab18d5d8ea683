"""The course of one calibration run, as the calibrator node drives it (no rclpy).

:class:`CalibrationRun` opens the run (:func:`.session.open_session`), starts its recording,
selects the postures (or keeps a resumed run's), orders a new run's postures from the
platform's current posture, waits for the system, collects, then identifies
(:func:`.identify.finish_run`), publishes and applies the result. What it needs from the node is
:class:`.host.RunHost`; the postures themselves are commanded by the node, each at once from the
end of the previous one, and this coroutine only reports them as they end (``host.finals``).
"""

import os
import time
import traceback

from gsp_calibrator.collection import events, protocol, topics
from gsp_calibrator.collection.single_source import SecondSource
from gsp_calibrator.recording.recorder import next_recording_file, settings_options
from gsp_calibrator.run import postures
from gsp_calibrator.run.host import RunHost, first_timeout
from gsp_calibrator.run.identify import finish_run
from gsp_calibrator.run.response import (
    failure_message,
    final_progress_message,
    format_response,
    posture_report,
)
from gsp_calibrator.run.session import RunRefused, RunWriteError, WriteFailed, open_session
from gsp_calibrator.run.state import (
    PHASE_DONE,
    PHASE_FAILED,
    PHASE_IDENTIFYING,
    PHASE_INTERRUPTED,
    STATE_FILE,
    settle_statistics,
)
from gsp_msgs_py import names

#: Final posture events that end the run.
RUN_FAILURES = (events.TopicSilent, events.NoSynchronisedSample, SecondSource, WriteFailed)


class RunFailed(Exception):
    """Ends a run early; the message says why (e.g. names the silent topic)."""


def system_checks(node, heard, timeout):
    """``[(predicate, failure message)]`` a run awaits before its first posture: a subscriber to
    the pose commands, a status publisher, and a message on each sensor topic (``heard(topic)``);
    ``node``: the :class:`.host.RunHost`; ``timeout`` (s) is for the messages."""
    checks = [
        (
            lambda: node.command_subscriber_count() > 0,
            f'no subscriber on {names.TOPIC_POSE_COMMAND} within {timeout:g} s '
            '(is platform_sim running?)',
        ),
        (
            lambda: node.count_publishers(names.TOPIC_PLATFORM_STATUS) > 0,
            f'topic {names.TOPIC_PLATFORM_STATUS} is silent: no publisher within {timeout:g} s '
            '(is platform_sim running?)',
        ),
    ]
    for topic in topics.SENSOR_TOPICS:
        message = f'topic {topic} is silent: no message within {timeout:g} s'
        checks.append((lambda t=topic: heard(t), message))
    return checks


class CalibrationRun:
    """One run (``resume``: the rest of an unfinished one) with ``settings``, hosted by ``node``
    (a :class:`.host.RunHost`: the ``CalibratorNode``, or a test's plain Python host)."""

    def __init__(self, node: RunHost, settings, resume):
        self.node, self.settings, self.resume = node, settings, resume
        self.log = node.get_logger()
        self.session = None
        self.collection = protocol.CollectionProtocol.for_settings(settings)

    async def serve(self):
        """:meth:`run`, answered whatever happens: ``(success, message)``; then the recording is
        closed and the node told (``run_ended()``). Only ``GeneratorExit`` (the executor drops
        the task: the node is going down) and a shutdown leave the run to ``destroy_node``."""
        node = self.node
        try:
            result = await self.run()
        except GeneratorExit:
            # Nothing may be awaited now (an await here would hang the garbage collector that
            # closes the coroutine); destroy_node() closes the recording and marks the run.
            node.stop_collection()
            raise
        except Exception as error:  # the node must survive any failure of a run
            if node.shutting_down():  # shut down meanwhile (Ctrl-C, SIGTERM): not a crash
                node.stop_collection()
                return False, 'the calibrator shut down'
            self.log.error(f'calibration crashed: {error}\n{traceback.format_exc()}')
            result = False, f'calibration failed: {error}'
        node.stop_collection()
        try:
            # Drain (the last progress, the result) and close the file off the executor.
            await node.in_thread(node.recorder.stop, drain_s=0.2)
        except Exception as error:
            self.log.error(f'recording not closed: {error}')
        finally:
            if self.session is not None:
                self.session.close()
            node.run_ended()
        return result

    def interrupted(self):
        """The node goes down during the run: mark state.json ``interrupted``."""
        state = self.session.state if self.session is not None else None
        if state is not None and state.phase != PHASE_DONE:
            self.save_state(PHASE_INTERRUPTED, 'the calibrator shut down during the run')

    async def run(self):
        """``(success, message)``."""
        settings, log, node = self.settings, self.log, self.node
        started = time.monotonic()
        try:
            session = self.session = open_session(
                settings,
                self.resume,
                os.getpid(),
                node.get_publishers_info_by_topic(names.TOPIC_POSE_COMMAND),
                (node.get_name(), node.get_namespace()),
            )
        except RunRefused as error:
            log.error(str(error))
            return False, str(error)
        for recovered in session.recovered:
            log.warning(
                f'recovered {recovered["message_count"]} messages of a recording left '
                f'unfinished into {recovered["path"]}'
            )
        log.info(
            f'calibration {"resumed" if self.resume else "started"}: run directory {session.run}'
        )
        try:
            part = next_recording_file(session.run.path)
            node.recorder.start(part, options=settings_options(settings))
        except (OSError, ValueError, ImportError) as error:  # the run goes on without it
            part = None
            log.error(f'not recording the run: {error}')
        node.start_collection(session, self.collection)
        try:
            await self._begin(part)
            await self._wait_for_system()
            await self._collect()
        except (RunFailed, RunWriteError) as error:
            self.save_state(PHASE_FAILED, str(error))
            message = failure_message(error, len(session.samples), session.run)
            log.error(message)
            node.progress(len(session.samples), names.PHASE_FAILED, str(error))
            return False, message
        node.stop_collection()
        return await self._identify(started)

    def save_state(self, phase=None, stop_reason=None):
        """Rewrite state.json; an error is logged (the run is ending)."""
        try:
            if self.session is not None:
                self.session.save(phase, stop_reason)
        except RunWriteError as error:
            self.log.error(f'{STATE_FILE} not written: {error}')

    async def _begin(self, part):
        """Select the postures of a new run (a resumed one keeps its own) and order them from
        where the platform is; write state.json."""
        settings, session, count = self.settings, self.session, self.settings.posture_count
        self.node.progress(
            0, names.PHASE_SELECTING, f'selecting {count} postures from {settings.pool_size}'
        )
        poses = None
        if session.state is None:
            try:
                selection = await self.node.await_thread(self.node.selection_future(settings))
            except (postures.CalibrationError, RuntimeError, ValueError) as error:
                raise RunFailed(f'posture selection failed: {error}') from None
            self.log.info(
                f'{len(selection.poses)} postures selected (scaled condition number '
                f'{selection.condition_number:.4g})'
            )
            poses = selection.poses
        if poses is not None and settings.posture_order == 'route':
            # From the latest leg lengths (if none come, the system check fails the run next).
            await self.node.wait_for(
                lambda: self.collection.latest_leg_lengths() is not None, settings.topic_timeout
            )
            start, reason = postures.route_start(
                settings.nominal, self.collection.latest_leg_lengths()
            )
            if reason:
                self.log.warning(f'route from the home pose: {reason}')
            # state.json keeps the poses in this order: a resumed run keeps it.
            route = postures.posture_route(settings, poses, start)
            poses = poses[route.order]
            x, y, z = start[:3] * 1e3
            self.log.info(
                f'route order from ({x:.1f}, {y:.1f}, {z:.1f}) mm: predicted travel '
                f'{route.travel_s:.1f} s (selection order {route.selection_order_s:.1f} s, '
                f'lower bound {route.lower_bound_s:.1f} s)'
            )
        try:
            session.replace = await self.node.in_thread(postures.PostureReplacer, settings)
        except (postures.CalibrationError, RuntimeError, ValueError) as error:
            self.log.warning(f'rejected postures will not be replaced: {error}')
        session.begin(settings, poses, os.getpid(), part)
        if session.resumed:
            self.log.info(
                f'resuming: {len(session.samples)} rows kept, '
                f'{len(session.remaining)} postures to go'
            )
            if len(session.samples):
                self.collection.continue_after(session.samples.readings[-1])

    async def _wait_for_system(self):
        """Wait until platform_sim listens to commands and every sensor topic has spoken."""
        timeout = self.settings.topic_timeout
        checks = system_checks(self.node, self.collection.heard, timeout)
        failure = await first_timeout(self.node.wait_for, timeout, checks)
        if failure:
            raise RunFailed(failure)
        if self.node.failure is not None:
            raise RunFailed(self.node.failure.message)

    async def _collect(self):
        """Have every posture left commanded and report each as it ends; RunFailed on a failure."""
        self.node.command_first()
        while not self.node.collection_done():
            event = await self.node.finals.get()
            if isinstance(event, RUN_FAILURES):
                raise RunFailed(event.message)
            report = posture_report(event, self.settings.posture_count, self.settings.nominal)
            for level, line in report.log:  # one call site per severity (rclpy requires it)
                if level == 'warning':
                    self.log.warning(line)
                else:
                    self.log.info(line)
            extra = {} if report.skipped is None else {'skipped': report.skipped}
            self.node.progress(
                event.posture,
                report.phase,
                report.message,
                report.residuals,
                report.warning,
                **extra,
            )
            self.session.save()

    async def _identify(self, started):
        """Identify over every row, write the results, publish and apply; ``(success, text)``."""
        settings, session, node, log = self.settings, self.session, self.node, self.log
        count = settings.posture_count
        self.save_state(PHASE_IDENTIFYING)
        node.progress(
            count,
            names.PHASE_IDENTIFYING,
            f'identifying {settings.free_count} parameters from {len(session.samples)} postures',
        )
        finished = await node.in_thread(
            finish_run,
            session.run,
            settings,
            session.samples,
            {
                **self.collection.summary(),
                'replacements': session.state.replacements,
                'settle': settle_statistics(session.state.settle_waits),
            },
            settings_options(settings),
        )
        if finished.report_error:
            log.error(f'report not written: {finished.report_error}')
        outcome, summary = finished.outcome, finished.summary
        residuals = outcome.result.residual_rms if outcome.result is not None else None
        if not outcome.success:
            log.error(summary)
            self.save_state(PHASE_FAILED, outcome.message)
            node.progress(count, names.PHASE_FAILED, outcome.message, residuals)
            return False, summary
        self.save_state(PHASE_DONE)
        geometry = outcome.geometry
        # A result the goodness of fit rejects is written and latched, but applied only on demand.
        success, note = await node.deliver_result(settings, geometry, outcome.fit_accepted)
        if note:
            summary += '\n' + note
        summary += f'\ncalibration time: {time.monotonic() - started:.2f} s'
        (log.info if success else log.error)(summary)
        phase = names.PHASE_DONE if success else names.PHASE_FAILED
        node.progress(
            count,
            phase,
            final_progress_message(summary, success, note),
            residuals,
            run_directory=session.run.path,
        )
        return success, format_response(summary, geometry)
