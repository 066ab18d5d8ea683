"""The course of a check, as the calibrator node drives it on ``/gsp/calibrator/check`` (no rclpy).

A :class:`CheckRun` is a calibration run (:class:`gsp_calibrator.run.flow.CalibrationRun`: its
run directory, recording, system checks and collection) with two steps of its own: the postures
are the check's (:func:`.check_run.check_plan`, from where the platform stands, against the
geometry the controller runs), and instead of an identification the collected rows are judged
(:func:`.check_run.evaluate_check`), ``check.json`` is written and the check enters the history.
"""

import dataclasses
import os

from gsp_calibrator.run import postures
from gsp_calibrator.run.flow import CalibrationRun, RunFailed
from gsp_calibrator.run.state import PHASE_DONE, PHASE_FAILED, PHASE_IDENTIFYING
from gsp_calibrator.upkeep import check_run, history
from gsp_calibrator.upkeep.calibration_files import RESULT_JSON
from gsp_kinematics.upkeep import check
from gsp_msgs_py import names

PHASE_CHECKING = 'checking'


class CheckRun(CalibrationRun):
    """One check with ``settings``, hosted by ``host`` (a ``run.host.RunHost``)."""

    def __init__(self, host, settings, resume=False):
        # A check measures its whole plan (it never stops early nor adds postures, workspace
        # postures included: its plan is its own) and judges its own rows only.
        settings = dataclasses.replace(
            settings, stop_when_accurate=False, reuse_rows_from='', workspace_postures=0
        )
        super().__init__(host, settings, resume=False)
        self.reference = None
        self.plan = None

    async def _choose_postures(self, part):
        """The check's postures, in route order from where the platform stands."""
        settings, session, host = self.settings, self.session, self.host
        host.progress(0, names.PHASE_SELECTING, 'choosing the check postures')
        try:
            self.reference = await host.in_thread(
                check_run.check_reference,
                settings.output_root,
                settings.platform_id,
                settings.check_geometry_file,
            )
        except check_run.CheckError as error:
            raise RunFailed(str(error)) from None
        collection = self.collection
        await host.wait_for(
            lambda: collection.latest_leg_lengths() is not None, settings.topic_timeout
        )
        start, reason = postures.route_start(
            self.reference.geometry, collection.latest_leg_lengths()
        )
        if reason:
            self.log.warning(f'check route from the home pose: {reason}')
        try:
            self.plan = await host.in_thread(
                check_run.check_plan,
                self.reference,
                start,
                settings.pool_size,
                settings.seed,
                settings.sigmas,
                settings.pairs_per_posture,
                settings.motion_limits,
            )
        except (ValueError, RuntimeError) as error:
            raise RunFailed(f'check postures: {error}') from None
        self.settings = dataclasses.replace(settings, posture_count=len(self.plan.poses))
        self.log.info(
            f'check of {self.reference.source}: {len(self.plan.poses)} postures, planned '
            f'platform time {self.plan.platform_time_s:.1f} s'
        )
        session.begin(self.settings, self.plan.poses, os.getpid(), part)

    async def _identify(self, started, stopping=None, reused=None):
        """Judge the collected rows, write check.json, index the check; ``(success, text)``."""
        settings, session, host, log = self.settings, self.session, self.host, self.log
        count = settings.posture_count
        self.save_state(PHASE_IDENTIFYING)
        host.progress(count, PHASE_CHECKING, f'checking from {len(session.samples)} postures')
        try:
            data = await host.in_thread(
                check_run.evaluate_check,
                self.reference,
                session.samples,
                settings.sigmas,
                settings.requirement,
                settings.platform_id,
                self.plan.platform_time_s,
            )
            await host.in_thread(check_run.write_check, session.run.path, data)
        except (check_run.CheckError, OSError, ValueError) as error:
            self.save_state(PHASE_FAILED, str(error))
            host.progress(count, names.PHASE_FAILED, f'check failed: {error}')
            log.error(f'check failed: {error}')
            return False, f'check failed: {error}\nrun directory: {session.run.path}'
        self.save_state(PHASE_DONE)
        await record_in_history(host, settings, session.run.path)
        summary = check_run.check_summary(data) + f'\nrun directory: {session.run.path}'
        if data['verdict'] == check.VERDICTS[0]:  # one call site per severity (rclpy)
            log.info(summary)
        else:
            log.warning(summary)
        host.progress(
            count, names.PHASE_DONE, summary.splitlines()[0], run_directory=session.run.path
        )
        return True, summary


async def record_in_history(host, settings, run_dir):
    """Index ``run_dir`` in the history of ``settings.output_root`` (a failure is logged)."""
    log = host.log
    try:
        await host.in_thread(
            history.record,
            history.database_path(settings.output_root),
            run_dir,
            settings.platform_id,
        )
    except Exception as error:  # the history never fails a run that is done
        log.error(f'history not updated with {run_dir}: {error}')


async def record_calibration(host, settings, run_dir):
    """Index a calibration's ``run_dir`` in the history once it has a result.json."""
    if os.path.isfile(os.path.join(run_dir, RESULT_JSON)):
        await record_in_history(host, settings, run_dir)
