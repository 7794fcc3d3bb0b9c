import numpy as np
import pytest

from semslam.errors import SimulationError
from semslam.simulation.world import make_world, with_placed_tags
from semslam.types import JunctionShape, SlotKind


@pytest.mark.parametrize(("preset", "lo", "hi"), [("small", 30, 50), ("garage", 150, 250)])
def test_presets_have_the_promised_size(preset, lo, hi):
    world = make_world(preset, 3)
    assert lo <= len(world.slots) <= hi
    assert len(world.tags) >= (4 if preset == "small" else 8)


def test_large_preset_has_about_2000_slots():
    world = make_world("large", 0)
    assert 1500 <= len(world.slots) <= 2500


def test_same_seed_same_world_other_seed_other_world():
    a, b, c = make_world("garage", 5), make_world("garage", 5), make_world("garage", 6)
    assert np.array_equal(
        np.array([s.corners for s in a.slots]), np.array([s.corners for s in b.slots])
    )
    assert [s.label for s in a.slots] == [s.label for s in b.slots]
    assert (
        [s.label for s in a.slots] != [s.label for s in c.slots]
        or a.line_colour != c.line_colour
        or not np.allclose(a.markings[0].width, c.markings[0].width)
    )


def test_garage_mixes_slot_kinds_and_labels_are_unique_and_short():
    world = make_world("garage", 1)
    assert {s.kind for s in world.slots} == set(SlotKind)
    labels = [s.label for s in world.slots]
    assert len(set(labels)) == len(labels)
    assert all(2 <= len(label) <= 4 for label in labels)


def test_slot_corner_order_entrance_left_right_as_seen_from_aisle():
    world = make_world("small", 0)
    for slot in world.slots:
        el, er, rr, rl = slot.corners
        into = (rl + rr) / 2 - (el + er) / 2  # from the entrance into the slot
        across = er - el
        # looking along `into`, `el` is on the left: cross(into, el->er) < 0
        assert into[0] * across[1] - into[1] * across[0] < 0


def test_marking_points_sit_on_slot_corners_with_t_and_l_shapes():
    world = make_world("garage", 2)
    points = np.array([p.position for p in world.marking_points])
    entrance = np.array([s.corners[:2] for s in world.slots]).reshape(-1, 2)
    d = np.min(np.linalg.norm(entrance[:, None] - points[None], axis=2), axis=1)
    assert d.max() < 1e-9
    shapes = [p.shape for p in world.marking_points]
    assert JunctionShape.T in shapes and JunctionShape.L in shapes


def test_line_widths_in_range_and_tags_on_pillars():
    world = make_world("garage", 4)
    assert all(0.10 <= m.width <= 0.25 for m in world.markings)
    pillars = np.array([p.centre for p in world.pillars])
    for tag in world.tags:
        assert np.min(np.linalg.norm(pillars - tag.mTt[:2], axis=1)) < 0.35


def test_unknown_preset_is_refused():
    with pytest.raises(SimulationError, match="unknown preset"):
        make_world("huge", 0)


@pytest.mark.parametrize("seed", [2, 7])
def test_large_worlds_paint_each_slot_id_once(seed):
    """Rows of more than 99 slots are lettered: numbered, they ran into the next row's."""
    labels = [s.label for s in make_world("large", seed).slots if s.label]
    assert len(set(labels)) == len(labels)
    assert all(2 <= len(label) <= 4 for label in labels)


def test_placed_tags_take_the_lowest_free_ids_and_keep_the_world():
    world = make_world("small", 2)
    poses = np.array([[3.0, 4.0, 0.5], [6.0, -1.0, -2.0]])
    placed = with_placed_tags(world, poses)
    assert placed.tags[: len(world.tags)] == world.tags and placed.slots == world.slots
    new = placed.tags[len(world.tags):]
    used = {t.tag_id for t in world.tags}
    free = [i for i in range(587) if i not in used][:2]
    assert [t.tag_id for t in new] == free
    np.testing.assert_array_equal(np.array([t.mTt for t in new]), poses)
    assert all(t.size == 0.5 and t.height == 1.6 for t in new)
    with pytest.raises(SimulationError, match="codes left"):
        with_placed_tags(world, np.zeros((600, 3)))
    assert with_placed_tags(world, None) is world
    assert with_placed_tags(world, np.zeros((0, 3))) is world
