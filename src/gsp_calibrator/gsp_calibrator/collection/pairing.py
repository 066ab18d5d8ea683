"""Nearest-stamp pairing of leg-length and device stamps, kept up to date message by message
(pure, no rclpy). See docs/architecture.md#synchronisation."""

import bisect


def nearest_pairs(leg_stamps, device_stamps, tolerance_ns):
    """``[(leg_stamp, device_stamp), ...]``: the pairing rule applied at once to the sorted
    ``leg_stamps`` and ``device_stamps`` (ns)."""
    pairing = StampPairing(tolerance_ns)
    pairing.legs.extend(int(s) for s in leg_stamps)
    pairing.devices.extend(int(s) for s in device_stamps)
    for leg in pairing.legs:
        pairing._retake(leg)
    return list(pairing.pairs)


class StampPairing:
    """The pairs of the leg stamps and device stamps added so far."""

    def __init__(self, tolerance_ns):
        self.tolerance_ns = int(tolerance_ns)
        self.legs = []  # sorted leg stamps
        self.devices = []  # sorted device stamps
        self.pairs = []
        self.pair_legs = []
        self.revision = 0
        self._choice = {}  # leg stamp -> its device stamp
        self._taker = {}  # device stamp -> the leg stamp that took it
        self._changed = None  # lowest index of self.pairs changed since take_changed()

    def clear(self):
        self.legs.clear()
        self.devices.clear()
        self.pairs.clear()
        self.pair_legs.clear()
        self._choice.clear()
        self._taker.clear()
        self._changed = 0
        self.revision += 1

    def take_changed(self):
        """Lowest index of :attr:`pairs` changed since the previous call (None: none)."""
        changed, self._changed = self._changed, None
        return changed

    def add_leg(self, stamp):
        """A new leg stamp (not held yet)."""
        index = bisect.bisect_left(self.legs, stamp)
        self.legs.insert(index, stamp)
        self._repair(index, set(), first_too=True)

    def remove_leg(self, stamp):
        """Forget the held leg stamp ``stamp``."""
        index = bisect.bisect_left(self.legs, stamp)
        device = self._choice.get(stamp)
        self._set(stamp, device, None)
        del self.legs[index]
        self._repair(index, set() if device is None else {device})

    def add_device(self, stamp):
        """A new device stamp (not held yet)."""
        bisect.insort(self.devices, stamp)
        self._repair(bisect.bisect_left(self.legs, stamp - self.tolerance_ns), {stamp})

    def remove_device(self, stamp):
        """Forget the held device stamp ``stamp``."""
        del self.devices[bisect.bisect_left(self.devices, stamp)]
        leg = self._taker.get(stamp)
        if leg is None:  # no leg took it: no leg's choice changes
            return
        self._set(leg, stamp, None)
        self._repair(bisect.bisect_left(self.legs, leg), {stamp}, first_too=True)

    def _repair(self, index, changed, first_too=False):
        """Take the legs from ``index`` on again until none can see a difference: ``changed``
        holds the device stamps held, or taken by the legs so far, differently than before."""
        legs, tolerance = self.legs, self.tolerance_ns
        for k in range(index, len(legs)):
            leg = legs[k]
            if not first_too and all(device < leg - tolerance for device in changed):
                return
            first_too = False
            old, new = self._retake(leg)
            if old != new:
                changed ^= {device for device in (old, new) if device is not None}

    def _retake(self, leg):
        """Apply the rule to ``leg`` (the legs before it done); ``(old, new)`` device stamps."""
        devices, tolerance = self.devices, self.tolerance_ns
        best = None
        i = bisect.bisect_left(devices, leg - tolerance)
        while i < len(devices) and devices[i] <= leg + tolerance:
            device = devices[i]
            taker = self._taker.get(device)
            # A taker at or after this leg is an old choice of a leg not yet taken again.
            if (taker is None or taker >= leg) and (
                best is None or abs(device - leg) < abs(best - leg)
            ):
                best = device
            i += 1
        old = self._choice.get(leg)
        if best != old:
            self._set(leg, old, best)
        return old, best

    def _set(self, leg, old, new):
        index = bisect.bisect_left(self.pair_legs, leg)
        if old is not None:
            if self._taker.get(old) == leg:
                del self._taker[old]
            del self._choice[leg], self.pairs[index], self.pair_legs[index]
        if new is not None:
            self._taker[new] = leg  # (a later leg's old choice: that leg is taken again)
            self._choice[leg] = new
            self.pairs.insert(index, (leg, new))
            self.pair_legs.insert(index, leg)
        if old is not None or new is not None:
            self._changed = index if self._changed is None else min(self._changed, index)
            self.revision += 1
