"""The platform side of a pose command's life: moving -> settled, or superseded (pure, no rclpy)."""

from .health import ERROR, OK, WARN, Health


class SettleTracker:
    """Which accepted command is moving, and when it settles."""

    def __init__(self):
        self.moving = None  #: the id of the accepted command not settled yet, or None
        self._settles_ns = None

    def accept(self, command_id, now_ns, settle_time):
        """Start moving to ``command_id`` at ``now_ns``, to settle ``settle_time`` (s) later."""
        superseded = self.moving
        self.moving = command_id
        self._settles_ns = now_ns + max(0, round(settle_time * 1e9))
        return superseded

    def wait_ns(self, now_ns):
        """Nanoseconds until the moving command settles (0 if due), or None if none moves."""
        if self.moving is None:
            return None
        return max(0, self._settles_ns - now_ns)

    def due(self, now_ns):
        """The command id that has settled by ``now_ns`` (forgotten from then on), or None."""
        if self.moving is None or now_ns < self._settles_ns:
            return None
        settled, self.moving = self.moving, None
        return settled

    def forget(self):
        """The moving command ends without settling (it was rejected)."""
        self.moving = None


class CommandStatistics:
    """What became of the pose commands a platform node received, and how long the accepted ones
    took to settle; :meth:`health` reports them on ``/diagnostics`` (``<node>: commands``).
    """

    def __init__(self):
        self.counts = dict.fromkeys(
            ('commands', 'accepted', 'settled', 'refused', 'superseded', 'abandoned'), 0
        )
        self.last_rejection = ''  #: '<command id>: <reason>' of the latest rejected command
        self._accepted_ns = {}  # command id -> accept time of an accepted, unsettled command
        self._settle_times_s = []
        self._latest = None  # (outcome, command id, reason) of the latest command's latest event

    def refused(self, command_id, reason):
        self.counts['commands'] += 1
        self.counts['refused'] += 1
        self._rejected('refused', command_id, reason)

    def accepted(self, command_id, now_ns):
        self.counts['commands'] += 1
        self.counts['accepted'] += 1
        self._accepted_ns[command_id] = int(now_ns)
        self._latest = ('moving', command_id, '')

    def superseded(self, command_id, reason):
        self.counts['superseded'] += 1
        self._accepted_ns.pop(command_id, None)
        self.last_rejection = f'{command_id}: {reason}'

    def settled(self, command_id, now_ns):
        self.counts['settled'] += 1
        accepted_ns = self._accepted_ns.pop(command_id, None)
        if accepted_ns is not None:
            self._settle_times_s.append((int(now_ns) - accepted_ns) * 1e-9)
        self._latest = ('settled', command_id, '')

    def abandoned(self, command_id, reason):
        self.counts['abandoned'] += 1
        self._accepted_ns.pop(command_id, None)
        self._rejected('abandoned', command_id, reason)

    def _rejected(self, outcome, command_id, reason):
        self.last_rejection = f'{command_id}: {reason}'
        self._latest = (outcome, command_id, reason)

    def health(self):
        """``Health``: ERROR while the latest command is an abandoned goal, WARN while it was
        refused, OK otherwise (none yet, moving or settled)."""
        times = self._settle_times_s
        rejected = sum(self.counts[k] for k in ('refused', 'superseded', 'abandoned'))
        values = {**self.counts, 'rejected': rejected, 'last_rejection': self.last_rejection}
        values['settle_time_last_s'] = f'{times[-1]:.4f}' if times else ''
        values['settle_time_mean_s'] = f'{sum(times) / len(times):.4f}' if times else ''
        values['settle_time_max_s'] = f'{max(times):.4f}' if times else ''
        if self._latest is None:
            return Health(OK, 'no command yet', values)
        outcome, command_id, reason = self._latest
        if outcome == 'abandoned':
            return Health(ERROR, f'command {command_id} not reached: {reason}', values)
        if outcome == 'refused':
            return Health(WARN, f'command {command_id} rejected: {reason}', values)
        return Health(OK, f'command {command_id} {outcome}', values)
