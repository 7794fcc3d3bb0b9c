"""Slot landmarks: the duplicate merge after a loop closure (semslam.mapping.landmarks)."""

import numpy as np

from semslam.mapping.landmarks import SlotLandmarks
from semslam.types import SlotKind

SLOT = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])


def test_a_merge_never_gives_one_slot_two_confident_ids():
    """An unlabelled slot between a B17 and a B18 (0.8 m apart, each 0.4 m from it) may
    absorb one of them, not both: the second is checked against what it absorbed."""
    slots = SlotLandmarks()
    keep = slots.add(SLOT, SlotKind.PERPENDICULAR)
    b17 = slots.add(SLOT + [0.4, 0.0], SlotKind.PERPENDICULAR)
    b17.votes["B17"] += 0.95
    b18 = slots.add(SLOT - [0.4, 0.0], SlotKind.PERPENDICULAR)
    b18.votes["B18"] += 0.95
    pairs = slots.duplicates(0.6, np.array([1.25, 2.5]), 25.0)
    assert len(pairs) == 1 and pairs[0][0] == keep.index


def test_slots_with_the_same_id_all_merge():
    slots = SlotLandmarks()
    keep = slots.add(SLOT, SlotKind.PERPENDICULAR)
    for dx in (0.3, -0.3):
        slots.add(SLOT + [dx, 0.0], SlotKind.PERPENDICULAR).votes["B17"] += 0.95
    assert [k for k, _ in slots.duplicates(0.6, np.array([1.25, 2.5]), 25.0)] == [keep.index] * 2
