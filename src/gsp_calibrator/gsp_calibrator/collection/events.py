"""The events of the collection protocol (:mod:`.protocol`): what ends or reports a posture."""

import dataclasses

import numpy as np

from gsp_calibrator.collection.synchroniser import PostureRow


@dataclasses.dataclass(frozen=True)
class CollectionStarted:
    """Posture ``posture`` settled: samples stamped from ``start_ns`` count."""

    posture: int
    command_id: str
    start_ns: int


@dataclasses.dataclass(frozen=True)
class CommandAgain:
    """Send the command ``command_id`` again: no status has come for it."""

    command_id: str


@dataclasses.dataclass(frozen=True, eq=False)
class RowReady:
    """The averaged row of posture ``posture``; ``dropped`` inconsistent pairs before it."""

    posture: int
    pose: np.ndarray  #: (6,) commanded [x, y, z, psi, theta, phi], m and rad
    sample: PostureRow
    dropped: int = 0


@dataclasses.dataclass(frozen=True)
class PostureSkipped:
    """Posture ``posture`` gives no row; ``reason`` says why."""

    posture: int
    reason: str
    rejected_by_platform: bool = False
    platform_reason: str = ''  #: the platform's own reason of a rejection


@dataclasses.dataclass(frozen=True)
class TopicSilent:
    """``topic`` said nothing for ``topic_timeout`` while ``doing``: the run cannot go on."""

    topic: str
    doing: str
    message: str


@dataclasses.dataclass(frozen=True)
class NoSynchronisedPair:
    """Messages come but no synchronised pair did for ``topic_timeout``: the run cannot go on."""

    posture: int
    message: str


#: Why a platform is not where it was sent (:class:`PlatformElsewhere`, and the identification's
#: refusal of such rows).
ELSEWHERE_CAUSES = (
    'another assembly after passing near a singularity, or a swapped or miswired sensor'
)


@dataclasses.dataclass(frozen=True)
class PlatformElsewhere:
    """At posture ``posture`` the device measured the platform ``distance_m`` (m) from where it
    was commanded: it is not where it was sent, and the run cannot go on."""

    posture: int
    distance_m: float
    limit_m: float

    @property
    def message(self):
        return (
            f'at posture {self.posture} the device measures the platform '
            f'{self.distance_m * 1e3:.0f} mm from the commanded position (max_posture_error '
            f'{self.limit_m * 1e3:.0f} mm): it is not where it was sent ({ELSEWHERE_CAUSES}). '
            'Its row is not kept; bring the platform back to a known posture and resume'
        )


@dataclasses.dataclass(frozen=True)
class SampleDropped:
    """A sensor message was dropped (``non_finite``: counted, see ``non_finite_dropped``)."""

    topic: str
    reason: str
    non_finite: bool
    count: int = 0  #: non-finite readings dropped on the topic's stream so far

    @property
    def message(self):
        if self.non_finite:
            return f'dropped a non-finite reading on {self.topic} ({self.count} so far)'
        return f'ignoring a malformed message on {self.topic}: {self.reason}'


@dataclasses.dataclass(frozen=True, eq=False)
class PairsCollected:
    """``keep_pairs``: every synchronised pair of a posture (None: before the first command)."""

    posture: object
    command_id: str
    pose: object  #: (6,) commanded pose, None before the first command
    stamps: np.ndarray  #: (N,) leg-length stamps, ns
    leg_lengths: np.ndarray  #: (N, 6) q_i, m
    readings: np.ndarray  #: (N, 4) [alpha, beta, phi, d_m]


#: Events after which the posture (or the run) is over.
FINAL_EVENTS = (RowReady, PostureSkipped, TopicSilent, NoSynchronisedPair, PlatformElsewhere)
