"""The course of one run, as the calibrator node drives it (no rclpy)."""

import dataclasses
import os
import time
import traceback
import typing

from gsp_calibrator.collection import posture_state, protocol, topics
from gsp_calibrator.files import history
from gsp_calibrator.files.calibration_files import CalibrationFileError
from gsp_calibrator.recording.recorder import next_recording_file, settings_options
from gsp_calibrator.report.data import settle_statistics
from gsp_calibrator.run import postures, reused_rows, run_to_requirement
from gsp_calibrator.run.host import POSTURE_ENDS, RunHost, first_timeout
from gsp_calibrator.run.identify import identify_with_settings, write_run_files
from gsp_calibrator.run.record import (
    PHASE_DONE,
    PHASE_FAILED,
    PHASE_IDENTIFYING,
    PHASE_INTERRUPTED,
    STATE_FILE,
    RunRefused,
    RunWriteError,
    open_record,
)
from gsp_calibrator.run.response import (
    failure_message,
    final_progress_message,
    format_response,
    report_posture_end,
)
from gsp_msgs_py import names


class RunFailed(Exception):
    """Ends a run early; the message says why (e.g. names the silent topic)."""


@dataclasses.dataclass
class Judged:
    """What a run's judge found (then its writer's summary)."""

    success: bool
    failure: str = ''  #: why it failed: state.json's stop reason ('' on success)
    progress: str = ''  #: the progress message of a failure
    summary: str = ''  #: the human summary, the run's answer
    residuals: dict | None = None  #: the fit's residuals (progress), None without a fit
    outcome: typing.Any = None  #: a calibration's ``identify.CalibrationOutcome``
    data: dict | None = None  #: a calibration's result.json collection record; a check.json


class Course(typing.Protocol):
    """What a run is for. ``plan``: ``(poses, route additions or None)`` to command in order
    (None: a resumed run keeps its own; :class:`RunFailed`); ``judge`` the collected rows
    (``reused``: an earlier run's; ``stopping``: the record of a run that stops when accurate);
    ``write`` what was judged, with its summary; ``deliver``: ``(success, answer)``."""

    def settings_of(self, settings): ...  # the settings the run uses, from the node's
    async def plan(self, run): ...
    async def judge(self, run, reused, stopping) -> Judged: ...
    async def write(self, run, judged) -> Judged: ...
    async def deliver(self, run, judged, started) -> tuple: ...


def system_checks(host, heard, timeout):
    """``[(predicate, failure message)]`` a run awaits before its first posture: a subscriber to
    the pose commands, a status publisher, and a message on each sensor topic (``heard``)."""
    checks = [
        (
            lambda: host.command_subscribers() > 0,
            f'no subscriber on {names.TOPIC_POSE_COMMAND} within {timeout:g} s '
            '(is platform_sim running?)',
        ),
        (
            lambda: host.status_publishers() > 0,
            f'topic {names.TOPIC_PLATFORM_STATUS} is silent: no publisher within {timeout:g} s '
            '(is platform_sim running?)',
        ),
    ]
    for topic in topics.SENSOR_TOPICS:
        message = f'topic {topic} is silent: no message within {timeout:g} s'
        checks.append((lambda t=topic: heard(t), message))
    return checks


class CalibrationRun:
    """One run (``resume``: the rest of an unfinished one) with ``settings``, hosted by ``host``
    (a :class:`.host.RunHost`), for its ``course`` (default: a :class:`Calibration`)."""

    def __init__(self, host: RunHost, settings, resume, course: Course | None = None):
        self.course = Calibration() if course is None else course
        self.host, self.resume = host, resume
        self.settings = self.course.settings_of(settings)
        self.log = host.log
        self.record = None  #: the run's ``record.RunRecord`` once opened
        self.collection = protocol.CollectionProtocol.for_settings(self.settings)

    async def serve(self):
        """:meth:`run`, answered whatever happens: ``(success, message)``; then the recording is
        closed. Only ``GeneratorExit`` (the executor drops the task: the node is going down)
        and a shutdown leave the run to the node's ``destroy_node``."""
        host = self.host
        try:
            result = await self.run()
        except GeneratorExit:
            # Nothing may be awaited now (an await here would hang the garbage collector that
            # closes the coroutine); destroy_node() closes the recording and marks the run.
            host.postures.stop()
            raise
        except Exception as error:  # the node must survive any failure of a run
            if host.shutting_down():  # shut down meanwhile (Ctrl-C, SIGTERM): not a crash
                host.postures.stop()
                return False, 'the calibrator shut down'
            self.log.error(f'calibration crashed: {error}\n{traceback.format_exc()}')
            result = False, f'calibration failed: {error}'
        host.postures.stop()
        try:
            # Drain (the last progress, the result) and close the file off the executor.
            await host.in_thread(host.recorder.stop, drain_s=0.2)
        except Exception as error:
            self.log.error(f'recording not closed: {error}')
        finally:
            if self.record is not None:
                self.record.close()
        return result

    def interrupted(self):
        """The node goes down during the run: mark state.json ``interrupted``."""
        state = self.record.state if self.record is not None else None
        if state is not None and state.phase != PHASE_DONE:
            self.save_state(PHASE_INTERRUPTED, 'the calibrator shut down during the run')

    async def run(self):
        """The whole run, step by step: ``(success, message)``."""
        started = time.monotonic()
        try:
            reused, part = await self._open()
        except (reused_rows.ReusedRowsError, RunRefused) as error:
            self.log.error(str(error))
            return False, str(error)
        try:
            unheard = await self._wait_for_system()
            await self._choose_postures(part)
            # After the plan is in state.json: a resume of a run that heard nothing keeps it.
            self._fail_unless_ready(unheard)
            stopping = await self._collect(reused)
        except (RunFailed, RunWriteError) as error:
            return self._failed(error)
        self.host.postures.stop()
        judged = await self._judge(reused, stopping)
        judged = await self.course.write(self, judged)
        await self._record_in_history()
        if not judged.success:
            return self._not_judged(judged)
        self.save_state(PHASE_DONE)
        return await self.course.deliver(self, judged, started)

    def save_state(self, phase=None, stop_reason=None):
        """Rewrite state.json; an error is logged (the run is ending)."""
        try:
            if self.record is not None:
                self.record.save(phase, stop_reason)
        except RunWriteError as error:
            self.log.error(f'{STATE_FILE} not written: {error}')

    @property
    def planned(self):
        """The postures the run plans to command, additions included."""
        return postures.commanded_count(self.settings, self.record.state)

    async def _open(self):
        """Open the run's record and recording: ``(reused rows, recording file)`` (the rows of an
        earlier run identified with its own; None: the run goes on without a recording)."""
        settings, host, log = self.settings, self.host, self.log
        reused = await host.in_thread(reused_rows.load, settings)
        record = self.record = open_record(
            settings, self.resume, os.getpid(), host.command_publishers(), host.name
        )
        for recovered in record.recovered:
            log.warning(
                f'recovered {recovered["message_count"]} messages of a recording left '
                f'unfinished into {recovered["path"]}'
            )
        log.info(
            f'calibration {"resumed" if self.resume else "started"}: '
            f'run directory {record.directory}'
        )
        try:
            part = next_recording_file(record.directory.path)
            host.recorder.start(part, options=settings_options(settings))
        except (OSError, ValueError, ImportError) as error:
            part = None
            log.error(f'not recording the run: {error}')
        host.processing_lags.reset()
        host.postures.start(record, self.collection)
        return reused, part

    async def _wait_for_system(self):
        """Wait until platform_sim listens to commands and every sensor topic has spoken
        (``startup_timeout`` each: peers may be starting), then, for a new run with additions
        for the effects, until every stream has given
        :data:`~gsp_calibrator.collection.posture_state.RATE_MIN_STAMPS` stamps, its rate measured (at most ``topic_timeout``; else the route is timed at
        gsp_plan's rate). The message of the first check that timed out ('' when none did)."""
        settings, host, collection = self.settings, self.host, self.collection
        startup, timeout = settings.startup_timeout, settings.topic_timeout
        failure = await first_timeout(
            host.wait_for, startup, system_checks(host, collection.heard, startup)
        )
        new_route = self.record.state is None
        if new_route and postures.route_effect_groups(settings.free_parameters) and not failure:
            latest = collection.latest
            await host.wait_for(
                lambda: latest.sample_rate_hz(posture_state.RATE_MIN_STAMPS) is not None, timeout
            )
        return failure

    async def _choose_postures(self, part):
        """The course's plan (a resumed run keeps its own), written to state.json."""
        record = self.record
        planned = await self.course.plan(self)
        poses, additions = (None, None) if planned is None else planned
        record.begin(self.settings, poses, os.getpid(), part, additions)
        if record.resumed:
            self.log.info(
                f'resuming: {len(record.samples)} rows kept, {len(record.remaining)} postures to go'
            )
            if len(record.samples):
                self.collection.continue_after(record.samples.readings[-1])

    def _fail_unless_ready(self, unheard):
        """Fail the run on ``unheard`` (:meth:`_wait_for_system`) or a failed collection."""
        if unheard:
            raise RunFailed(unheard)
        if self.host.postures.failure is not None:
            raise RunFailed(self.host.postures.failure.message)

    async def _collect(self, reused=None):
        """For each posture left (a rejected one's replacement joins the end): command it,
        await its end, record it. RunFailed when an end is a failure of the run."""
        host, record, settings = self.host, self.record, self.settings
        legs = self.collection.latest_leg_lengths()
        stop = run_to_requirement.StoppingState.start(settings, record, legs, reused)
        try:
            while True:
                posture = record.next_posture()
                if posture is None and stop is not None:
                    posture = await self._posture_to_add(stop)
                if posture is None:
                    break
                k, pose = posture
                host.progress(k, names.PHASE_MOVING, f'posture {k} of {self.planned}: moving')
                record.note_command(k, pose, self.collection.latest_leg_lengths())
                # The row (samples.csv) or the skip is kept, and the outcome noted in the
                # recording, by the thread of the message that ended the posture, before this
                # await returns: a SIGTERM meanwhile loses nothing.
                event = await host.postures.command(k, pose)
                if not isinstance(event, POSTURE_ENDS):
                    raise RunFailed(event.message)
                report_posture_end(event, self.planned, settings.nominal, self.log, host.progress)
                record.save()
                if stop is not None and self._judged_enough(stop):
                    break
        finally:
            if stop is not None:
                stop.close()
        return None if stop is None else stop.record()

    def _judged_enough(self, stop):
        """Whether the latest finished judgement meets the requirement; else start judging the
        rows so far when due and no judgement is under way (never waits)."""
        judgement = stop.finished()
        if judgement is not None:
            self.log.info(run_to_requirement.judgement_line(judgement, stop.rule))
        if stop.met:
            return True
        stop.judge_if_due()
        return False

    async def _posture_to_add(self, stop):
        """After the plan (whose rows are then judged whole): ``(k, pose)`` of the pool posture
        to add, or None when the rows meet the requirement or no more may be added."""
        host = self.host
        if stop.added == 0:
            if stop.in_flight is not None:
                stop.note(await host.await_thread(stop.in_flight))
            if stop.judge_if_due(last=True):
                judgement = stop.note(await host.await_thread(stop.in_flight))
                self.log.info(run_to_requirement.judgement_line(judgement, stop.rule))
        if not stop.may_add():
            return None
        pose = await host.in_thread(stop.next_pose, self.collection.latest_leg_lengths())
        if pose is None:
            return None
        self.log.info(f'the plan is not enough: posture {stop.added} added from the pool')
        return self.record.add_posture(pose)

    async def _judge(self, reused, stopping):
        """The course's judgement of the collected rows (state.json: identifying)."""
        self.save_state(PHASE_IDENTIFYING)
        return await self.course.judge(self, reused, stopping)

    async def _record_in_history(self):
        """Index the run in the history of ``output_root`` once it has its result.json or
        check.json (a failure is logged: the history never fails a run)."""
        settings, directory = self.settings, self.record.directory.path
        try:
            await self.host.in_thread(
                history.record,
                history.database_path(settings.output_root),
                directory,
                settings.platform_id,
            )
        except CalibrationFileError:
            pass  # nothing to index: the run has no result
        except Exception as error:
            self.log.error(f'history not updated with {directory}: {error}')

    def _failed(self, error):
        """End a run whose collection failed: state.json, the log, the progress, the answer."""
        record = self.record
        self.save_state(PHASE_FAILED, str(error))
        message = failure_message(error, len(record.samples), record.directory)
        self.log.error(message)
        self.host.progress(len(record.samples), names.PHASE_FAILED, str(error))
        return False, message

    def _not_judged(self, judged):
        """End a run whose judge found no result: state.json, the log, the progress."""
        self.save_state(PHASE_FAILED, judged.failure)
        self.log.error(judged.summary)
        self.host.progress(self.planned, names.PHASE_FAILED, judged.progress, judged.residuals)
        return False, judged.summary


class Calibration:
    """A calibration's course: the selection in route order, the identification of every row
    judged against the requirement, its files, the result latched and, if accepted, applied."""

    def settings_of(self, settings):
        return settings

    async def plan(self, run):
        """A new run's selected postures in route order, with what the effect groups need."""
        settings, host = run.settings, run.host
        count = settings.posture_count
        host.progress(
            0, names.PHASE_SELECTING, f'selecting {count} postures from {settings.pool_size}'
        )
        try:
            run.record.replace = await host.in_thread(postures.PostureReplacer, settings)
        except (postures.CalibrationError, RuntimeError, ValueError) as error:
            run.log.warning(f'rejected postures will not be replaced: {error}')
        if run.record.state is not None:
            return None
        try:
            selection = await host.await_thread(host.selection(settings))
        except (postures.CalibrationError, RuntimeError, ValueError) as error:
            raise RunFailed(f'posture selection failed: {error}') from None
        run.log.info(
            f'{len(selection.poses)} postures selected (scaled condition number '
            f'{selection.condition_number:.4g})'
        )
        poses = postures.with_workspace_poses(settings, selection.poses)
        return await self._ordered(run, poses)

    async def _ordered(self, run, poses):
        """``(poses, record)``: ``poses`` in order with what the effect groups need
        (:func:`.postures.effect_route`) and its record (None: nothing added)."""
        settings, collection = run.settings, run.collection
        await run.host.wait_for(
            lambda: collection.latest_leg_lengths() is not None, settings.topic_timeout
        )
        start, reason = postures.route_start(settings.nominal, collection.latest_leg_lengths())
        if settings.posture_order == 'route':
            if reason:
                run.log.warning(f'route from the home pose: {reason}')
            route = postures.posture_route(settings, poses, start)
            x, y, z = start[:3] * 1e3
            run.log.info(
                f'route order from ({x:.1f}, {y:.1f}, {z:.1f}) mm: predicted travel '
                f'{route.travel_s:.1f} s (selection order {route.selection_order_s:.1f} s, '
                f'lower bound {route.lower_bound_s:.1f} s)'
            )
            poses = poses[route.order]
        else:  # nor first a posture the platform already holds
            poses = poses[postures.held_last(settings, poses, start)]
        # As heard (the run waited for its streams first): timed at the run's own rate.
        rate = collection.latest.sample_rate_hz()
        route = await run.host.in_thread(postures.effect_route, settings, poses, start, rate)
        if route is None:
            return poses, None
        groups = postures.route_effect_groups(settings.free_parameters)
        additions = postures.route_additions(route, groups, rate)
        line = postures.route_additions_line(additions)
        run.log.info(line)
        run.host.progress(0, names.PHASE_SELECTING, line)
        return route.poses, additions

    async def judge(self, run, reused, stopping):
        """Identify every row (and ``reused``) and judge the result (in a worker thread)."""
        settings, record, host = run.settings, run.record, run.host
        rows, extra = reused_rows.for_identification(record, reused)
        extra |= {} if stopping is None else {'run_to_requirement': stopping}
        host.progress(
            run.planned,
            names.PHASE_IDENTIFYING,
            f'identifying {settings.free_count} parameters from {len(rows)} postures',
        )
        outcome = await host.in_thread(identify_with_settings, settings, rows)
        residuals = outcome.result.residual_rms if outcome.result is not None else None
        collection = {
            **run.collection.summary(),
            'replacements': record.state.replacements,
            'settle': settle_statistics(record.state.rest_waits),
            'processing_lag': host.processing_lags.summary(),
            'route_additions': record.state.route_additions or None,
            **extra,
        }
        message = outcome.message
        return Judged(outcome.success, message, message, '', residuals, outcome, collection)

    async def write(self, run, judged):
        """result.json, report.md and its plots, and result.yaml of a successful result."""
        settings = run.settings
        written = await run.host.in_thread(
            write_run_files,
            run.record.directory,
            settings,
            judged.outcome,
            judged.data,
            settings_options(settings),
        )
        if written.report_error:
            run.log.error(f'report not written: {written.report_error}')
        summary = written.summary
        stopping = judged.data.get('run_to_requirement')
        if stopping is not None:
            summary += '\n' + run_to_requirement.summary_line(stopping)
        return dataclasses.replace(judged, summary=summary)

    async def deliver(self, run, judged, started):
        """Latch the result and apply it when it meets the requirement."""
        host, outcome = run.host, judged.outcome
        geometry = outcome.geometry
        success, note = await host.deliver_result(
            run.settings, geometry, outcome.verdicts, outcome.rigid_geometry
        )
        summary = judged.summary + ('\n' + note if note else '')
        summary += f'\ncalibration time: {time.monotonic() - started:.2f} s'
        if success:  # one call site per severity (rclpy requires it)
            run.log.info(summary)
        else:
            run.log.error(summary)
        host.progress(
            run.planned,
            names.PHASE_DONE if success else names.PHASE_FAILED,
            final_progress_message(summary, success, note),
            judged.residuals,
            run_directory=run.record.directory.path,
        )
        return success, format_response(summary, geometry)
