"""The posture in collection, where the node's message threads and the run meet (no rclpy)."""

import threading

from gsp_calibrator.collection.events import FINAL_EVENTS, CommandAgain, PostureSkipped, RowReady
from gsp_calibrator.recording.mcap_format import RecordingError
from gsp_calibrator.recording.recorder import IN_PROGRESS, KEPT, SKIPPED
from gsp_calibrator.run.host import POSTURE_ENDS


class PostureLink:
    """The posture in collection, shared by the node's message threads and the run (thread-safe)."""

    def __init__(self, new_future, commander, recorder, on_event):
        self._new_future = new_future
        self._commander = commander
        self._recorder = recorder
        self._on_event = on_event
        self.lock = threading.RLock()  # guards every member below and the protocol
        self.protocol = None  #: the run's CollectionProtocol (kept after the run: summary)
        self.record = None  #: the run's RunRecord while collecting
        self.active = False  #: whether messages go to the protocol
        self.failure = None  #: the event that ended the run early, else None
        self.current = None  #: ``(posture, command_id, publish)`` commanded, not yet ended
        self._end = None  # the future of the current posture's end

    def start(self, record, protocol):
        """Feed messages to ``protocol`` and keep each posture's outcome in ``record``."""
        with self.lock:
            self.protocol, self.record = protocol, record
            self.failure = self.current = self._end = None
            self.active = True

    def stop(self):
        """Stop feeding the protocol; a posture in collection is noted in progress (left out)."""
        with self.lock:
            current, self.current, self.active = self.current, None, False
            if current is not None:
                self._note(current, IN_PROGRESS, 'the run stopped during its collection')

    def command(self, posture, pose):
        """Command ``posture`` (``pose``); the future of the event that ends it. A row is in
        samples.csv and the outcome in the recording before the future completes."""
        with self.lock:
            future = self._new_future()
            if self.failure is not None:  # the run failed between two postures
                future.set_result(self.failure)
                return future
            command_id, now_ns, publish = self._commander(pose)
            self.current, self._end = (int(posture), command_id, publish), future
            # The protocol knows the command before the platform can answer it.
            others = self._end_on(self.protocol.command(posture, pose, command_id, now_ns))
            publish()
        for event in others:
            self._on_event(event)
        return future

    def feed(self, step):
        """``step(protocol)`` (a message or a tick; its events) while a run collects (any
        thread): the end of the posture completes its future, other events go to ``on_event``."""
        with self.lock:
            if not self.active:
                return
            others = self._end_on(step(self.protocol))
        for event in others:
            self._on_event(event)

    def fail(self, event):
        """End the run with ``event`` (``message`` says why): a second source, a failed write."""
        with self.lock:
            if self.active and self.failure is None:
                self.failure = event
                self._finish(event)

    def _end_on(self, events):
        """End the posture on a final event among the protocol's ``events`` (the lock held);
        the other events, for ``on_event`` once the lock is released."""
        for event in events:
            if isinstance(event, FINAL_EVENTS):
                self._finish(event)
            elif isinstance(event, CommandAgain) and self.current is not None:
                self.current[2]()
        return [event for event in events if not isinstance(event, FINAL_EVENTS)]

    def _finish(self, event):
        """Keep the outcome of the current posture (the lock held) and complete its future."""
        future, current = self._end, self.current
        if future is None or current is None or not self.active:
            return
        self._end = self.current = None
        if isinstance(event, POSTURE_ENDS):
            event = self.record.end_posture(event)
        if isinstance(event, RowReady):
            self._note(current, KEPT)
        elif isinstance(event, PostureSkipped):
            self._note(current, SKIPPED, event.reason)
        else:
            self.failure = event
            self._note(current, IN_PROGRESS, event.message)
        future.set_result(event)

    def _note(self, current, outcome, reason=''):
        try:
            self._recorder.note_posture_end(current[1], current[0], outcome, reason)
        except (OSError, RecordingError):
            pass  # a full disk: the recorder's own write reports it and ends the run
