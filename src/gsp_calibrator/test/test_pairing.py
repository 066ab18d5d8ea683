"""StampPairing: the pairs kept up to date stamp by stamp equal the pairing rule applied afresh."""

import bisect

import numpy as np
import pytest

from gsp_calibrator.collection.pairing import StampPairing, nearest_pairs

MS = 1_000_000


def rule_afresh(leg_stamps, device_stamps, tolerance_ns):
    """The pairing rule written as plainly as it reads (the reference): each leg stamp in order
    takes the nearest device stamp within the tolerance no earlier leg took (ties: the earlier)."""
    taken, result = set(), []
    for leg in sorted(leg_stamps):
        free = [d for d in sorted(device_stamps) if d not in taken and abs(d - leg) <= tolerance_ns]
        if free:
            best = min(free, key=lambda d: (abs(d - leg), d))
            taken.add(best)
            result.append((leg, best))
    return result


@pytest.mark.parametrize('seed', range(20))
def test_pairs_kept_up_to_date_equal_the_rule_afresh_after_every_change(seed):
    """Stamps of two 200 Hz streams with jitter, added out of order and removed (oldest first,
    as a full buffer drops them, and at random): after each change the pairs equal the rule's."""
    rng = np.random.default_rng(seed)
    tolerance = int(rng.choice([1, 2.5, 4, 7]) * MS)
    legs = list(np.arange(60) * 5 * MS + rng.integers(-2 * MS, 2 * MS, 60))
    devices = list(np.arange(60) * 5 * MS + rng.integers(-3 * MS, 3 * MS, 60))
    changes = [('leg', int(s)) for s in set(legs)] + [('device', int(s)) for s in set(devices)]
    order = rng.permutation(len(changes))
    # Mostly in stamp order with some out of order, as messages arrive.
    changes = sorted(changes, key=lambda c: c[1] + int(rng.integers(0, 20 * MS)))
    changes = [changes[i] for i in order] if seed % 5 == 0 else changes
    pairing = StampPairing(tolerance)
    held = {'leg': [], 'device': []}
    for kind, stamp in changes:
        getattr(pairing, f'add_{kind}')(stamp)
        bisect.insort(held[kind], stamp)
        if rng.random() < 0.15:  # drop one: the oldest (a full buffer) or any
            kind = 'leg' if rng.random() < 0.5 else 'device'
            if held[kind]:
                index = 0 if rng.random() < 0.5 else int(rng.integers(len(held[kind])))
                getattr(pairing, f'remove_{kind}')(held[kind].pop(index))
        assert pairing.pairs == rule_afresh(held['leg'], held['device'], tolerance)
        assert pairing.pair_legs == [leg for leg, _ in pairing.pairs]
    assert nearest_pairs(held['leg'], held['device'], tolerance) == pairing.pairs


def test_take_changed_gives_the_first_changed_pair():
    pairing = StampPairing(2 * MS)
    for j in range(5):
        pairing.add_leg(10 * MS * j)
        pairing.add_device(10 * MS * j + MS)
    pairing.take_changed()
    revision = pairing.revision
    pairing.add_leg(45 * MS)  # no device within 2 ms: no pair changes
    assert pairing.take_changed() is None and pairing.revision == revision
    pairing.add_device(44 * MS)  # pairs with the leg at 45 ms: the last pair
    assert pairing.take_changed() == 5 and pairing.revision > revision
    pairing.remove_device(11 * MS)  # the pair of the leg at 10 ms
    assert pairing.take_changed() == 1
    assert [leg for leg, _ in pairing.pairs] == [0, 20 * MS, 30 * MS, 40 * MS, 45 * MS]
