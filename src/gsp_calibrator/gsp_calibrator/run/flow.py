"""The course of one calibration run, as the calibrator node drives it (no rclpy).

:meth:`CalibrationRun.run` reads as the run: open the run directory
(:func:`.session.open_session`) and start the recording; choose the postures (or keep a resumed
run's); wait for the system (its streams heard, their rate measured); order the postures from
where the platform stands, with the route's additions timed at that rate; then for each
posture, command it, await its end and record it (:meth:`CalibrationRun._collect`); then
identify (:func:`.identify.finish_run`), report, publish and apply the result. What it needs
from the node is one :class:`.host.RunHost`.
"""

import os
import time
import traceback

from gsp_calibrator.collection import posture_state, protocol, topics
from gsp_calibrator.recording.recorder import next_recording_file, settings_options
from gsp_calibrator.run import postures
from gsp_calibrator.run.host import POSTURE_ENDS, RunHost, first_timeout
from gsp_calibrator.run.identify import finish_run
from gsp_calibrator.run.response import (
    failure_message,
    final_progress_message,
    format_response,
    posture_report,
)
from gsp_calibrator.run.session import RunRefused, RunWriteError, open_session
from gsp_calibrator.run.state import (
    PHASE_DONE,
    PHASE_FAILED,
    PHASE_IDENTIFYING,
    PHASE_INTERRUPTED,
    STATE_FILE,
    settle_statistics,
)
from gsp_calibrator.upkeep import reused_rows, run_to_requirement
from gsp_msgs_py import names


class RunFailed(Exception):
    """Ends a run early; the message says why (e.g. names the silent topic)."""


def system_checks(host, heard, timeout):
    """``[(predicate, failure message)]`` a run awaits before its first posture: a subscriber to
    the pose commands, a status publisher, and a message on each sensor topic (``heard(topic)``);
    ``host``: the :class:`.host.RunHost`; ``timeout`` (s) is for the messages."""
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
    (a :class:`.host.RunHost`)."""

    def __init__(self, host: RunHost, settings, resume):
        self.host, self.settings, self.resume = host, settings, resume
        self.log = host.log
        self.session = None
        self.collection = protocol.CollectionProtocol.for_settings(settings)

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
            if self.session is not None:
                self.session.close()
        return result

    def interrupted(self):
        """The node goes down during the run: mark state.json ``interrupted``."""
        state = self.session.state if self.session is not None else None
        if state is not None and state.phase != PHASE_DONE:
            self.save_state(PHASE_INTERRUPTED, 'the calibrator shut down during the run')

    async def run(self):
        """The whole run: ``(success, message)``."""
        settings, log, host = self.settings, self.log, self.host
        started = time.monotonic()
        try:  # the rows of an earlier run (a check's) this calibration identifies with its own
            reused = await host.in_thread(reused_rows.load, settings)
        except reused_rows.ReusedRowsError as error:
            log.error(str(error))
            return False, str(error)
        try:
            session = self.session = open_session(
                settings, self.resume, os.getpid(), host.command_publishers(), host.name
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
            host.recorder.start(part, options=settings_options(settings))
        except (OSError, ValueError, ImportError) as error:  # the run goes on without it
            part = None
            log.error(f'not recording the run: {error}')
        host.processing_lags.reset()
        host.postures.start(session, self.collection)
        try:
            unheard = await self._choose_postures(part)
            await self._wait_for_system(unheard)
            stopping = await self._collect(reused)
        except (RunFailed, RunWriteError) as error:
            self.save_state(PHASE_FAILED, str(error))
            message = failure_message(error, len(session.samples), session.run)
            log.error(message)
            host.progress(len(session.samples), names.PHASE_FAILED, str(error))
            return False, message
        host.postures.stop()
        return await self._identify(started, stopping, reused)

    def save_state(self, phase=None, stop_reason=None):
        """Rewrite state.json; an error is logged (the run is ending)."""
        try:
            if self.session is not None:
                self.session.save(phase, stop_reason)
        except RunWriteError as error:
            self.log.error(f'{STATE_FILE} not written: {error}')

    async def _choose_postures(self, part):
        """Select the postures of a new run (a resumed one keeps its own), hear the streams
        (:func:`_heard_streams`), then order the postures from where the platform is; write
        state.json. Returns why the system is not ready ('' when it is)."""
        settings, session, host = self.settings, self.session, self.host
        count = settings.posture_count
        host.progress(
            0, names.PHASE_SELECTING, f'selecting {count} postures from {settings.pool_size}'
        )
        poses = None
        if session.state is None:
            try:
                selection = await host.await_thread(host.selection(settings))
            except (postures.CalibrationError, RuntimeError, ValueError) as error:
                raise RunFailed(f'posture selection failed: {error}') from None
            self.log.info(
                f'{len(selection.poses)} postures selected (scaled condition number '
                f'{selection.condition_number:.4g})'
            )
            poses = postures.with_workspace_poses(settings, selection.poses)
        unheard = await _heard_streams(self, new_route=poses is not None)
        poses, additions = await _ordered(self, poses)
        try:
            session.replace = await host.in_thread(postures.PostureReplacer, settings)
        except (postures.CalibrationError, RuntimeError, ValueError) as error:
            self.log.warning(f'rejected postures will not be replaced: {error}')
        session.begin(settings, poses, os.getpid(), part, additions)
        if session.resumed:
            self.log.info(
                f'resuming: {len(session.samples)} rows kept, '
                f'{len(session.remaining)} postures to go'
            )
            if len(session.samples):
                self.collection.continue_after(session.samples.readings[-1])
        return unheard

    async def _route(self, poses):
        """``poses`` in route order from the latest leg lengths (state.json keeps this order: a
        resumed run keeps it); if none come, the system check fails the run next."""
        settings, collection = self.settings, self.collection
        await self.host.wait_for(
            lambda: collection.latest_leg_lengths() is not None, settings.topic_timeout
        )
        start, reason = postures.route_start(settings.nominal, collection.latest_leg_lengths())
        if reason:
            self.log.warning(f'route from the home pose: {reason}')
        route = postures.posture_route(settings, poses, start)
        x, y, z = start[:3] * 1e3
        self.log.info(
            f'route order from ({x:.1f}, {y:.1f}, {z:.1f}) mm: predicted travel '
            f'{route.travel_s:.1f} s (selection order {route.selection_order_s:.1f} s, '
            f'lower bound {route.lower_bound_s:.1f} s)'
        )
        return poses[route.order]

    async def _wait_for_system(self, unheard):
        """Fail the run on ``unheard`` (:func:`_heard_streams`) or a failed collection."""
        if unheard:
            raise RunFailed(unheard)
        if self.host.postures.failure is not None:
            raise RunFailed(self.host.postures.failure.message)

    async def _collect(self, reused=None):
        """For each posture left (a rejected one's replacement joins the end): command it,
        await its end, record it. RunFailed when an end is a failure of the run.

        With ``stop_when_accurate`` the rows so far (and ``reused``) are judged as they come, in
        a worker thread while the next posture is collected (:meth:`_judged_enough`): the loop
        stops once a judgement meets the requirement, and adds pool postures when the plan is
        not enough (:meth:`_posture_to_add`). Returns that run's record (else None)."""
        host, session, settings = self.host, self.session, self.settings
        count, legs = _planned(self), self.collection.latest_leg_lengths()
        stop = run_to_requirement.StoppingState.start(settings, session, legs, reused)
        try:
            while True:
                posture = session.next_posture()
                if posture is None and stop is not None:
                    posture = await self._posture_to_add(stop)
                if posture is None:
                    break
                k, pose = posture
                host.progress(k, names.PHASE_MOVING, f'posture {k} of {count}: moving')
                session.note_command(k, pose, self.collection.latest_leg_lengths())
                # The row (samples.csv) or the skip is kept, and the outcome noted in the
                # recording, by the thread of the message that ended the posture, before this
                # await returns: a SIGTERM meanwhile loses nothing.
                event = await host.postures.command(k, pose)
                if not isinstance(event, POSTURE_ENDS):
                    raise RunFailed(event.message)
                self._report(event)
                session.save()
                if stop is not None and self._judged_enough(stop):
                    break
        finally:
            if stop is not None:
                stop.close()
        return None if stop is None else stop.record(settings, session)

    def _judged_enough(self, stop):
        """Whether the latest finished judgement meets the requirement; else start judging the
        rows so far when due and no judgement is under way (never waits)."""
        judgement = stop.finished()
        if judgement is not None:
            self.log.info(run_to_requirement.judgement_line(judgement, stop.rule))
        if stop.met:
            return True
        if stop.judge_now(len(self.session.samples)):
            stop.submit(self.settings, stop.rows(self.session))
        return False

    async def _posture_to_add(self, stop):
        """After the plan (whose rows are then judged whole): ``(k, pose)`` of the pool posture
        to add, or None when the rows meet the requirement or no more may be added."""
        host, session, settings = self.host, self.session, self.settings
        if stop.added == 0:
            if stop.in_flight is not None:
                stop.note(await host.await_thread(stop.in_flight))
            if stop.judge_now(len(session.samples), last=True):
                stop.submit(settings, stop.rows(session))
                judgement = stop.note(await host.await_thread(stop.in_flight))
                self.log.info(run_to_requirement.judgement_line(judgement, stop.rule))
        if not stop.may_add():
            return None
        legs = self.collection.latest_leg_lengths()
        pose = await host.in_thread(stop.next_pose, settings, session.state.poses, legs)
        if pose is None:
            return None
        self.log.info(f'the plan is not enough: posture {stop.added} added from the pool')
        return session.add_posture(pose)

    def _report(self, event):
        """Log and publish the end of a posture (a row or a skip)."""
        report = posture_report(event, _planned(self), self.settings.nominal)
        for level, line in report.log:  # one call site per severity (rclpy requires it)
            if level == 'warning':
                self.log.warning(line)
            else:
                self.log.info(line)
        extra = {} if report.skipped is None else {'skipped': report.skipped}
        self.host.progress(
            event.posture, report.phase, report.message, report.residuals, report.warning, **extra
        )

    async def _identify(self, started, stopping=None, reused=None):
        """Identify over every row (and ``reused``), write the results (``stopping``: the record
        of a run that stops when good enough), publish and apply; ``(success, text)``."""
        settings, session, host, log = self.settings, self.session, self.host, self.log
        count = _planned(self)
        self.save_state(PHASE_IDENTIFYING)
        samples, extra = reused_rows.for_identification(session, reused)
        extra |= {} if stopping is None else {'run_to_requirement': stopping}
        host.progress(
            count,
            names.PHASE_IDENTIFYING,
            f'identifying {settings.free_count} parameters from {len(samples)} postures',
        )
        finished = await host.in_thread(
            finish_run,
            session.run,
            settings,
            samples,
            {
                **self.collection.summary(),
                'replacements': session.state.replacements,
                'settle': settle_statistics(session.state.rest_waits),
                'processing_lag': host.processing_lags.summary(),
                'route_additions': session.state.route_additions or None,
                **extra,
            },
            settings_options(settings),
        )
        if finished.report_error:
            log.error(f'report not written: {finished.report_error}')
        outcome, summary = finished.outcome, finished.summary
        if stopping is not None:
            summary += '\n' + run_to_requirement.summary_line(stopping)
        residuals = outcome.result.residual_rms if outcome.result is not None else None
        if not outcome.success:
            log.error(summary)
            self.save_state(PHASE_FAILED, outcome.message)
            host.progress(count, names.PHASE_FAILED, outcome.message, residuals)
            return False, summary
        self.save_state(PHASE_DONE)
        geometry, rigid = outcome.geometry, outcome.rigid_geometry
        # A result that misses the required accuracy is written and latched, never applied.
        success, note = await host.deliver_result(settings, geometry, outcome.verdicts, rigid)
        if note:
            summary += '\n' + note
        summary += f'\ncalibration time: {time.monotonic() - started:.2f} s'
        if success:  # one call site per severity (rclpy requires it)
            log.info(summary)
        else:
            log.error(summary)
        phase = names.PHASE_DONE if success else names.PHASE_FAILED
        host.progress(
            count,
            phase,
            final_progress_message(summary, success, note),
            residuals,
            run_directory=session.run.path,
        )
        return success, format_response(summary, geometry)


def _planned(run):
    """The postures ``run`` (a :class:`CalibrationRun`) plans to command, additions included."""
    return postures.commanded_count(run.settings, run.session.state)


async def _heard_streams(run, new_route):
    """Wait until platform_sim listens to commands and every sensor topic has spoken
    (``topic_timeout`` each), then, for a ``new_route`` with additions for the effects, until
    every stream has given :data:`~gsp_calibrator.collection.posture_state.RATE_MIN_STAMPS`
    stamps, its rate measured (at most ``topic_timeout``; else the route is timed at gsp_plan's
    rate). ``run``: the :class:`CalibrationRun`. The message of the first check that timed out
    ('' when none did). The streams come before the route so that its additions are timed at
    the rate heard; a run that hears none still plans its route and writes state.json, then
    fails naming the silent topic."""
    settings, host, collection = run.settings, run.host, run.collection
    timeout = settings.topic_timeout
    failure = await first_timeout(
        host.wait_for, timeout, system_checks(host, collection.heard, timeout)
    )
    if new_route and postures.route_effect_groups(settings.free_parameters) and not failure:
        latest = collection.latest
        await host.wait_for(
            lambda: latest.sample_rate_hz(posture_state.RATE_MIN_STAMPS) is not None, timeout
        )
    return failure


async def _ordered(run, poses):
    """``(poses, record)``: a new run's selected ``poses`` (None: a resumed run keeps its own)
    in route order (``posture_order: route``), with the additions the effect groups to identify
    need (:func:`.postures.effect_route`: reference revisits, approach directions) and their
    record (:func:`.postures.route_additions`; None: nothing added), said in the progress."""
    if poses is None:
        return None, None
    settings = run.settings
    if settings.posture_order == 'route':
        poses = await run._route(poses)
    start, _ = postures.route_start(settings.nominal, run.collection.latest_leg_lengths())
    if settings.posture_order != 'route':  # nor first a posture the platform already holds
        poses = poses[postures.held_last(settings, poses, start)]
    # As heard (the run heard its streams first): the route's time at the run's own rate.
    rate = run.collection.latest.sample_rate_hz()
    route = await run.host.in_thread(postures.effect_route, settings, poses, start, rate)
    if route is None:
        return poses, None
    groups = postures.route_effect_groups(settings.free_parameters)
    additions = postures.route_additions(route, groups, rate)
    line = postures.route_additions_line(additions)
    run.log.info(line)
    run.host.progress(0, names.PHASE_SELECTING, line)
    return route.poses, additions
