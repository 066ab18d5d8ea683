"""A component's health as plain data: what a node publishes on /diagnostics (pure, no rclpy)."""

from dataclasses import dataclass, field

OK = 0
WARN = 1
ERROR = 2
STALE = 3

LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR', STALE: 'STALE'}


@dataclass(frozen=True)
class Health:
    """One component's level (OK, WARN, ERROR or STALE), a one-line message and key/values."""

    level: int
    message: str
    values: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        if self.level not in LEVEL_NAMES:
            raise ValueError(
                f'health level must be one of {sorted(LEVEL_NAMES)}, got {self.level!r}'
            )
        # Key/values go out as text (DiagnosticStatus KeyValue): keep them text here too.
        object.__setattr__(self, 'values', {str(k): str(v) for k, v in self.values.items()})


def worst(levels):
    """The worst of ``levels`` (OK if there are none); STALE counts as worse than ERROR."""
    return max(levels, default=OK)
