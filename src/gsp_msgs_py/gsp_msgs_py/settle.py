"""The platform side of a pose command's life: moving -> settled, or superseded (pure, no rclpy).

An accepted command is ``moving`` until ``settle_time`` has passed, then ``settled``. A command
accepted while another is still moving supersedes it: the older one is ``rejected`` with
:func:`superseded_reason` and never settles. Times are integer nanoseconds of one clock.
"""


def superseded_reason(command_id):
    """The reason a moving command is rejected when ``command_id`` supersedes it."""
    return f'superseded by command {command_id} before settling'


class SettleTracker:
    """Which accepted command is moving, and when it settles."""

    def __init__(self):
        self._moving = None  # command id of the accepted command not settled yet
        self._settles_ns = None

    @property
    def moving(self):
        """The command id that is moving, or None."""
        return self._moving

    def accept(self, command_id, now_ns, settle_time):
        """Start moving to ``command_id`` at ``now_ns``, to settle ``settle_time`` (s) later.

        Returns the command id it supersedes (still moving), or None.
        """
        superseded = self._moving
        self._moving = command_id
        self._settles_ns = now_ns + max(0, round(settle_time * 1e9))
        return superseded

    def wait_ns(self, now_ns):
        """Nanoseconds until the moving command settles (0 if due), or None if none moves."""
        if self._moving is None:
            return None
        return max(0, self._settles_ns - now_ns)

    def due(self, now_ns):
        """The command id that has settled by ``now_ns`` (forgotten from then on), or None."""
        if self._moving is None or now_ns < self._settles_ns:
            return None
        settled, self._moving = self._moving, None
        return settled

    def forget(self):
        """The moving command ends without settling (it was rejected)."""
        self._moving = None
