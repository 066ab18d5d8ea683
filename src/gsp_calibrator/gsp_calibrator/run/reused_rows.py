"""The rows of an earlier run (a check's, most often) that a calibration identifies with its own
(``reuse_rows_from``; pure, no rclpy; docs/upkeep.md)."""

import dataclasses
from pathlib import Path

from gsp_calibrator.files.run_directory import SAMPLES_FILE, Rows, RunDirectoryError, read_samples
from gsp_calibrator.run.record import STATE_FILE, ResumeRefused, read_state, selection_options


class ReusedRowsError(ValueError):
    """The rows of ``reuse_rows_from`` cannot be used; the message says why."""


@dataclasses.dataclass(frozen=True)
class ReusedRows:
    """Rows of another run directory."""

    source: str  #: the run directory
    samples: Rows

    def record(self, first_posture):
        """``result.json`` ``collection.reused_rows`` (numbered from ``first_posture`` on)."""
        count = len(self.samples)
        return {
            'run_directory': self.source,
            'rows': count,
            'postures': list(range(first_posture, first_posture + count)),
        }


def load(settings):
    """The :class:`ReusedRows` of ``settings.reuse_rows_from`` (None when empty)."""
    if not settings.reuse_rows_from:
        return None
    path = Path(settings.reuse_rows_from)
    try:
        state = read_state(path)
        samples = read_samples(path / SAMPLES_FILE)
    except (ResumeRefused, RunDirectoryError, OSError) as error:
        raise ReusedRowsError(f'reuse_rows_from {path}: {error}') from None
    current = selection_options(settings)
    for key, what in (('nominal_digest', 'nominal geometry'), ('device_digest', 'device')):
        if state.selection.get(key) != current[key]:
            raise ReusedRowsError(
                f'reuse_rows_from {path}: its rows come from another {what} ({STATE_FILE}), '
                'not this calibration'
            )
    if not len(samples):
        raise ReusedRowsError(f'reuse_rows_from {path}: {SAMPLES_FILE} has no row')
    return ReusedRows(str(path), samples)


def joined(rows, reused, first):
    """``rows`` followed by ``reused``'s (None: none), numbered from ``first`` on."""
    if reused is None:
        return rows
    together = rows.rows(slice(0, len(rows)))
    other = reused.samples
    for m in range(len(other)):
        together.append(
            first + m,
            other.commanded_poses[m],
            other.leg_lengths[m],
            other.readings[m],
            other.n_samples[m],
            other.stamps[m],
            other.lag_sums[m],
            other.directions[m],  # as the legs arrived in their own run
        )
    return together


def for_identification(record, reused):
    """``(samples, record)``: a run ``record``'s rows and the ``reused`` ones (None: none),
    numbered after its postures, and ``{'reused_rows': ...}`` for ``result.json`` (else {})."""
    first = len(record.state.poses) + 1
    samples = joined(record.samples, reused, first)
    return samples, ({} if reused is None else {'reused_rows': reused.record(first)})
