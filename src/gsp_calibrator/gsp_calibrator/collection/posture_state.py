"""The state of the posture a collection awaits, and the latest readings received (pure, no
rclpy): parts of :class:`~gsp_calibrator.collection.protocol.CollectionProtocol`."""

import collections
import dataclasses

import numpy as np

from gsp_calibrator.collection.synchroniser import LEG_LENGTHS
from gsp_calibrator.collection.topics import DEVICE_STREAMS, SENSOR_TOPICS
from gsp_kinematics import channels

#: Device instants kept for the latest complete one (the previous posture's readings): more
#: than a listener's batch of one device topic can lead the others by.
MAX_RECENT_INSTANTS = 4000
#: Recent stamps per stream the sample rate is measured over.
RATE_WINDOW = 64
#: Distinct stamps per stream a run awaits before it takes the rate as measured and times its
#: route with it: two stamps of a stream published late by a loaded machine can be closer than
#: its period (a fifth of a second at 50 Hz).
RATE_MIN_STAMPS = 10


AWAIT_STATUS, AWAIT_SETTLE, COLLECTING = 'status', 'settle', 'collecting'


@dataclasses.dataclass
class Posture:
    number: int
    pose: np.ndarray
    command_id: str
    commanded_ns: int
    state: str = AWAIT_STATUS
    sent_ns: int = None  # the latest time the command was sent again (no status by then)
    first_status_ns: int = None
    move_s: float = 0.0  # the planned move time: the settle may take that much longer
    start_ns: int = None  # collection start (stamps), set when settled
    started_ns: int = None  # receive time of the settle (time base of the timeouts)
    progress: int = 0  # pairs at the last change
    progress_ns: int = None  # receive time of the last change of the pairs
    progress_data_ns: int = None  #: data time of the last change of the pairs (or first sample)
    #: the receive time every stream has reached with the samples handled since the start (the
    #: settle's until each has given one): one stream's batch ahead is no lack of progress
    received_ns: int = None
    #: stream -> latest receive time of its samples handled since the start
    received_by_stream: dict = dataclasses.field(default_factory=dict)
    #: stream -> latest stamp (ns) of its samples stamped from the start (the data's time)
    latest_ns: dict = dataclasses.field(default_factory=dict)

    def data_ns(self):
        """The data's time: the stamp every stream has reached with its samples from the start;
        None until each has given one (the receive times judge a stream that gives none)."""
        if len(self.latest_ns) < len(SENSOR_TOPICS):
            return None
        return min(self.latest_ns.values())


class LatestReadings:
    """The latest leg lengths and the latest complete device instant received."""

    def __init__(self):
        self._legs = None  # (6,) m
        #: stamp -> {device stream: values} of the latest device instants (the device topics
        #: come in batches of their own: their latest messages need not share a stamp)
        self._instants = collections.OrderedDict()
        self._stamps = {}  # stream -> its recent stamps (ns)

    def note(self, stream, stamp_ns, values):
        """A usable sample (``values`` as for the collector's ``add_<stream>``)."""
        self._stamps.setdefault(stream, collections.deque(maxlen=RATE_WINDOW)).append(stamp_ns)
        if stream == LEG_LENGTHS:
            self._legs = values[0]
            return
        self._instants.setdefault(int(stamp_ns), {})[stream] = values
        if len(self._instants) > MAX_RECENT_INSTANTS:
            self._instants.popitem(last=False)

    def device_readings(self):
        """Latest complete device instant ``[alpha, beta, phi, d_m]``, or None."""
        for instant in reversed(self._instants.values()):
            if len(instant) == len(DEVICE_STREAMS):
                return np.concatenate(
                    [np.asarray(instant[stream], dtype=float) for stream in DEVICE_STREAMS]
                )
        return None

    def leg_lengths(self):
        """Latest leg lengths (6,) m, or None."""
        legs = self._legs
        return None if legs is None else np.asarray(legs, dtype=float).reshape(channels.LEG_COUNT)

    def sample_rate_hz(self, min_stamps=2):
        """The rate (Hz) synchronised samples can come at: the slowest stream's, from its
        recent distinct stamps; None until every stream has given ``min_stamps`` (>= 2)."""
        rates = []
        for stream in (LEG_LENGTHS, *DEVICE_STREAMS):
            stamps = np.unique(np.asarray(self._stamps.get(stream, ()), dtype=np.int64))
            if stamps.size < max(2, int(min_stamps)):
                return None
            rates.append((stamps.size - 1) / ((stamps[-1] - stamps[0]) * 1e-9))
        return float(min(rates))
