"""The separators a map's slots imply, as line markings for the localizer."""

from __future__ import annotations

import numpy as np

from semslam.localization.slot_sides import slot_sides
from semslam.types import Marking, SemanticMap, Slot

RECTANGLE = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])


def _row(n: int) -> tuple[Slot, ...]:
    """``n`` perpendicular slots side by side along x, entrances on y = 0."""
    return tuple(Slot(i, None, 0.0, RECTANGLE + (2.5 * i, 0.0), np.zeros((4, 2, 2)),
                      "perpendicular", 5) for i in range(n))


def _as_sets(markings) -> set[tuple[float, ...]]:
    return {tuple(np.round(np.concatenate([m.a, m.b]), 6)) for m in markings}


def test_a_row_of_slots_gives_each_separator_once():
    sides = slot_sides(SemanticMap(slots=_row(3)))
    # four separators at x = 0, 2.5, 5, 7.5, from the entrance (y = 0) to the rear (y = 5)
    xs = sorted(float(m.a[0]) for m in sides)
    assert xs == [0.0, 2.5, 5.0, 7.5]
    for m in sides:
        assert m.a[1] == 0.0 and m.b[1] == 5.0 and m.a[0] == m.b[0]


def test_a_separator_the_map_already_holds_is_left_out_but_not_for_a_crossing_line():
    entrance = Marking(np.array([-1.0, 0.0]), np.array([9.0, 0.0]), 0.1)  # across every side
    held = Marking(np.array([2.5, 2.0]), np.array([2.5, 6.0]), 0.1)  # part of the x = 2.5 side
    sides = slot_sides(SemanticMap(slots=_row(3), markings=(entrance, held)))
    assert sorted(float(m.a[0]) for m in sides) == [0.0, 5.0, 7.5]
    # a line 0.5 m beside a separator is another line: the separator stays
    beside = Marking(np.array([5.5, 0.5]), np.array([5.5, 4.5]), 0.1)
    sides = slot_sides(SemanticMap(slots=_row(3), markings=(beside,)))
    assert _as_sets(sides) == _as_sets(slot_sides(SemanticMap(slots=_row(3))))


def test_no_slots_no_sides():
    assert slot_sides(SemanticMap()) == ()


def test_a_side_is_as_uncertain_across_itself_as_its_corners():
    # corners 0.04 m uncertain in x (across the row's separators), 0.01 m in y (along them)
    cov = np.tile(np.diag([0.04**2, 0.01**2]), (4, 1, 1))
    slots = tuple(Slot(i, None, 0.0, RECTANGLE + (2.5 * i, 0.0), cov, "perpendicular", 5)
                  for i in range(2))
    sides = slot_sides(SemanticMap(slots=slots))
    assert len(sides) == 3
    for side in sides:
        assert side.sigma is not None and abs(side.sigma - 0.04) < 1e-12
