"""Slot landmarks: the duplicate merge after a loop closure, the probability of a
slot's label from its readings, and the pool of slots not yet confirmed
(semslam.mapping.landmarks)."""

import itertools
import math

import numpy as np
import pytest

from semslam.mapping.landmarks import SlotLandmarks, SlotPool, label_probability
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


def _posterior_by_enumeration(readings, label, alphabet):
    """P(label | readings) over an explicit alphabet: a reading is right with its
    confidence, else any of the other labels alike; uniform prior."""
    read = sorted({r for r, _ in readings})
    labels = read + [f"unread{i}" for i in range(alphabet - len(read))]

    def likelihood(truth):
        return math.prod(c if r == truth else (1 - c) / (alphabet - 1) for r, c in readings)

    return likelihood(label) / sum(likelihood(t) for t in labels)


@pytest.mark.parametrize(
    "readings",
    [
        [("B17", 0.9)],
        [("B17", 0.9), ("B17", 0.7)],
        [("B17", 0.9), ("B18", 0.9)],
        [("B17", 0.6), ("B17", 0.55), ("B18", 0.95), ("17", 0.5)],
        [("B17", 0.02)],
        [("B17", 0.02), ("B17", 0.02), ("B17", 0.02)],
    ],
)
def test_label_probability_is_the_posterior_of_independent_readings(readings):
    for label in {r for r, _ in readings}:
        for alphabet in (5, 100):
            expected = _posterior_by_enumeration(readings, label, alphabet)
            assert label_probability(readings, label, alphabet) == pytest.approx(expected, rel=1e-9)


def test_one_reading_gives_its_own_confidence_and_agreement_adds_up():
    """A slot read once at 0.02 is not sure of its label (the share of the votes said 1.0)."""
    assert label_probability([("B17", 0.02)], "B17") == pytest.approx(0.02)
    assert label_probability([("B17", 0.9)], "B17") == pytest.approx(0.9)
    assert label_probability([("B17", 0.9)] * 2, "B17") > 0.999
    split = label_probability([("B17", 0.9), ("B18", 0.9)], "B17")
    assert split == pytest.approx(label_probability([("B17", 0.9), ("B18", 0.9)], "B18"))
    assert split < 0.5
    assert label_probability([("B17", 0.9)], "B18") == 0.0
    for confidence in (0.0, 1.0):  # clipped, never 0 or 1 from one reading
        assert 0.0 < label_probability([("B17", confidence)], "B17") < 1.0
    readings = list(itertools.repeat(("B17", 1.0), 500))  # no overflow
    assert label_probability(readings, "B17") == pytest.approx(1.0)
    many = [(f"L{i}", 0.6) for i in range(150)]  # more labels than the alphabet: no error
    assert 0.0 < label_probability(many, "L0") < 0.05


def _pool_by_hand(sightings, radius, max_age):
    """The pool's rule written as a plain loop over the pooled slots: a sighting joins the
    slot of its kind whose mean corners lie nearest (the first on a tie) within ``radius``,
    else starts one; slots unseen for ``max_age`` keyframes are forgotten."""
    groups: list[tuple[list, list, SlotKind, list]] = []  # corners, sightings, kind, [last]
    for i, (corners, kind, keyframe) in enumerate(sightings):
        groups = [g for g in groups if keyframe - g[3][0] <= max_age]
        best, best_d = None, radius
        for g in groups:
            d = np.linalg.norm(np.mean(g[0], axis=0) - corners, axis=1).mean()
            if g[2] == kind and d < best_d:
                best, best_d = g, d
        if best is None:
            best = ([], [], kind, [keyframe])
            groups.append(best)
        best[0].append(corners)
        best[1].append(i)
        best[3][0] = keyframe
    return sorted(g[1] for g in groups)


def test_the_pool_groups_sightings_as_the_plain_rule_does():
    """Hundreds of sightings, true slots seen again and again among false ones of every
    kind, some slots expiring: the stacked pool groups them exactly as the loop does."""
    rng = np.random.default_rng(3)
    kinds = list(SlotKind)
    places = rng.uniform(0, 30, (40, 2))
    sightings = []
    for n in range(600):
        keyframe = n // 6
        if rng.random() < 0.5:  # a true slot: the same place and kind, 10 cm noise
            j = int(rng.integers(len(places)))
            corners, kind = SLOT + places[j] + rng.normal(0, 0.1, (4, 2)), kinds[j % 3]
        else:  # a false one anywhere
            corners, kind = SLOT + rng.uniform(0, 30, 2), kinds[int(rng.integers(3))]
        sightings.append((corners, kind, keyframe))
    pool = SlotPool(radius=0.5, max_age=10)
    for i, (corners, kind, keyframe) in enumerate(sightings):
        pool.expire(keyframe)
        pool.add(corners, kind, i, keyframe)
    expected = _pool_by_hand(sightings, 0.5, 10)
    assert sorted(item.sightings for item in pool.items) == expected
    assert max(len(g) for g in expected) > 3  # slots were seen again and grouped


def test_a_slot_leaves_the_pool_and_the_others_stay_searchable():
    pool = SlotPool(radius=0.5, max_age=10)
    a = pool.add(SLOT, SlotKind.PERPENDICULAR, 0, 0)
    b = pool.add(SLOT + [5.0, 0.0], SlotKind.PERPENDICULAR, 1, 0)
    pool.remove(a)
    assert pool.items == [b]
    assert pool.add(SLOT + [5.1, 0.0], SlotKind.PERPENDICULAR, 2, 1) is b
    assert pool.add(SLOT + [5.1, 0.0], SlotKind.PARALLEL, 3, 1) is not b  # another kind
    assert pool.add(SLOT, SlotKind.PERPENDICULAR, 4, 1) is not a  # a is gone
    np.testing.assert_allclose(b.mean_corners, SLOT + [5.05, 0.0])


def test_a_sighting_is_compared_with_the_mean_of_a_pooled_slot_not_its_first_sighting():
    pool = SlotPool(radius=0.5, max_age=10)
    first = pool.add(SLOT, SlotKind.PERPENDICULAR, 0, 0)
    assert pool.add(SLOT + [0.4, 0.0], SlotKind.PERPENDICULAR, 1, 0) is first
    assert pool.add(SLOT + [0.6, 0.0], SlotKind.PERPENDICULAR, 2, 0) is first  # 0.4 from 0.2
