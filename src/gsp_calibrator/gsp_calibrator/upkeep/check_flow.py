"""The course of a check, as the calibrator node drives it on ``/gsp/calibrator/check`` (no rclpy)."""

import dataclasses

from gsp_calibrator.files.calibration_files import CHECK_JSON
from gsp_calibrator.run import postures
from gsp_calibrator.run.flow import CalibrationRun, Judged, RunFailed
from gsp_calibrator.upkeep import check_run
from gsp_kinematics.fileio import write_json
from gsp_kinematics.upkeep import check
from gsp_msgs_py import names

PHASE_CHECKING = 'checking'


class Check:
    """A check's course: its own plan and judge (see the module)."""

    def __init__(self):
        self.reference = None  #: the ``check_run.CheckReference`` checked, once planned
        self.plan_s = None  #: the planned platform time (s), once planned

    def settings_of(self, settings):
        # A check measures its whole plan (it never stops early nor adds postures, workspace
        # postures included: its plan is its own) and judges its own rows only.
        return dataclasses.replace(
            settings, stop_when_accurate=False, reuse_rows_from='', workspace_postures=0
        )

    async def plan(self, run):
        """The check's postures, in route order from where the platform stands."""
        settings, host = run.settings, run.host
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
        collection = run.collection
        await host.wait_for(
            lambda: collection.latest_leg_lengths() is not None, settings.topic_timeout
        )
        start, reason = postures.route_start(
            self.reference.geometry, collection.latest_leg_lengths()
        )
        if reason:
            run.log.warning(f'check route from the home pose: {reason}')
        try:
            plan = await host.in_thread(
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
        run.settings = dataclasses.replace(settings, posture_count=len(plan.poses))
        self.plan_s = plan.platform_time_s
        run.log.info(
            f'check of {self.reference.source}: {len(plan.poses)} postures, planned '
            f'platform time {plan.platform_time_s:.1f} s'
        )
        return plan.poses, None

    async def judge(self, run, reused, stopping):
        """The collected rows against the geometry in use (``check.json``'s content)."""
        settings, record, host = run.settings, run.record, run.host
        host.progress(
            settings.posture_count, PHASE_CHECKING, f'checking from {len(record.samples)} postures'
        )
        try:
            data = await host.in_thread(
                check_run.evaluate_check,
                self.reference,
                record.samples,
                settings.sigmas,
                settings.requirement,
                settings.platform_id,
                self.plan_s,
            )
        except (check_run.CheckError, ValueError) as error:
            return _failed(run, error)
        return Judged(True, data=data)

    async def write(self, run, judged):
        """``check.json`` and the check's summary."""
        if not judged.success:
            return judged
        directory = run.record.directory.path
        try:
            await run.host.in_thread(write_json, directory / CHECK_JSON, judged.data)
        except (check_run.CheckError, OSError, ValueError) as error:
            return _failed(run, error)
        summary = check_run.check_summary(judged.data) + f'\nrun directory: {directory}'
        return dataclasses.replace(judged, summary=summary)

    async def deliver(self, run, judged, started):
        """Say the verdict; ``(True, summary)``."""
        summary = judged.summary
        if judged.data['verdict'] == check.VERDICTS[0]:  # one call site per severity (rclpy)
            run.log.info(summary)
        else:
            run.log.warning(summary)
        directory = run.record.directory.path
        run.host.progress(
            run.settings.posture_count,
            names.PHASE_DONE,
            summary.splitlines()[0],
            run_directory=directory,
        )
        return True, summary


def _failed(run, error):
    """The :class:`Judged` of a check that could not be judged or written."""
    summary = f'check failed: {error}\nrun directory: {run.record.directory.path}'
    return Judged(False, str(error), f'check failed: {error}', summary)


def new_check(host, settings, resume=False):
    """The run of one check with ``settings``, hosted by ``host`` (a check is never resumed)."""
    return CalibrationRun(host, settings, False, course=Check())
