"""Slot inference from marking points: hand-made point sets with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semslam.perception.marking_points import MarkingPoint
from semslam.perception.slots import DetectedSlot, infer_slots, slot_observation
from semslam.rig import TopviewSpec
from semslam.types import JunctionShape, SlotKind

UP = -math.pi / 2  # image direction "up" (v decreasing): atan2(-1, 0)
DOWN = math.pi / 2


def mp(u: float, v: float, direction: float, shape=JunctionShape.T, conf: float = 0.9):
    return MarkingPoint(np.array([u, v], float), direction, shape, conf)


def pairs(slots: list[DetectedSlot]) -> set[tuple[int, int]]:
    return {(s.i, s.j) for s in slots}


def test_perpendicular_slot_corners_and_order():
    # 150 px = 2.5 m apart, separators pointing up: the slot lies above the entrance
    pts = [mp(200, 300, UP), mp(350, 300, UP)]
    (slot,) = infer_slots(pts)
    assert slot.kind is SlotKind.PERPENDICULAR
    assert slot.angle_deg == pytest.approx(90.0)
    # viewer in the aisle faces up: entrance-left is the image-left point
    assert (slot.i, slot.j) == (0, 1)
    np.testing.assert_allclose(slot.uv_corners, [[200, 300], [350, 300], [350, 0], [200, 0]])
    assert 0.0 < slot.confidence <= 0.9 + 1e-9


def test_slot_facing_down_swaps_left_and_right():
    pts = [mp(200, 300, DOWN), mp(350, 300, DOWN)]
    (slot,) = infer_slots(pts)
    assert (slot.i, slot.j) == (1, 0)  # facing down, image-right is the viewer's left
    np.testing.assert_allclose(slot.uv_corners[2:], [[200, 600], [350, 600]])


def test_parallel_slot():
    pts = [mp(100, 300, UP), mp(460, 300, UP)]  # 6 m
    (slot,) = infer_slots(pts)
    assert slot.kind is SlotKind.PARALLEL
    np.testing.assert_allclose(slot.uv_corners[2:], [[460, 150], [100, 150]])


def test_slanted_slot():
    d = math.atan2(-1.0, 1.0)  # up and to the right, 45 deg to the entrance
    pts = [mp(200, 300, d), mp(410, 300, d)]  # 3.5 m along the entrance
    (slot,) = infer_slots(pts)
    assert slot.kind is SlotKind.SLANTED
    assert slot.angle_deg == pytest.approx(45.0)
    sep = 5.0 * 60.0 * np.array([math.cos(d), math.sin(d)])
    np.testing.assert_allclose(slot.uv_corners[3], np.array([200.0, 300.0]) + sep)


def test_slanted_needs_parallel_separators():
    pts = [mp(200, 300, math.atan2(-1.0, 1.0)), mp(410, 300, math.atan2(-1.0, -1.0))]
    assert infer_slots(pts) == []


def test_third_point_on_the_line_rejects_the_pair():
    # A-B and B-C are 3 m slots; A-C (6 m) would be parallel but B lies between them
    pts = [mp(100, 300, UP), mp(280, 300, UP), mp(460, 300, UP)]
    slots = infer_slots(pts)
    assert pairs(slots) == {(0, 1), (1, 2)}
    assert all(s.kind is SlotKind.PERPENDICULAR for s in slots)
    # a middle point that forms no slot itself still blocks A-C
    pts[1] = mp(280, 300, 0.0)
    assert infer_slots(pts) == []


def test_wrong_side_directions_rejected():
    assert infer_slots([mp(200, 300, UP), mp(350, 300, DOWN)]) == []


def test_width_out_of_range_rejected():
    assert infer_slots([mp(200, 300, UP), mp(300, 300, UP)]) == []  # 1.67 m
    assert infer_slots([mp(100, 300, UP), mp(400, 300, UP)]) == []  # 5 m: neither kind
    assert infer_slots([mp(200, 300, 0.3 + UP), mp(350, 300, UP)]) == []  # 17 deg off


def test_l_point_along_the_entrance_takes_partner_separator():
    # ps2.0 labels some end L points along the entrance toward their partner
    pts = [mp(100, 300, UP), mp(460, 300, math.pi, JunctionShape.L)]
    (slot,) = infer_slots(pts)
    assert slot.kind is SlotKind.PARALLEL
    assert (slot.i, slot.j) == (0, 1)


def test_confidence_follows_points():
    strong = infer_slots([mp(200, 300, UP, conf=1.0), mp(350, 300, UP, conf=1.0)])[0]
    weak = infer_slots([mp(200, 300, UP, conf=0.5), mp(350, 300, UP, conf=0.5)])[0]
    assert strong.confidence == pytest.approx(1.0)
    assert weak.confidence == pytest.approx(0.5)
    assert infer_slots([mp(200, 300, UP), mp(350, 300, UP)], min_confidence=0.95) == []


def test_slot_observation_in_vehicle_frame():
    spec = TopviewSpec()
    (slot,) = infer_slots([mp(200, 300, UP), mp(350, 300, UP)], spec)
    obs = slot_observation(slot, spec, "B17", 0.8, 0.12)
    c = spec.centre_px / 60.0
    expect = np.array(
        [
            [c - 300 / 60.0, c - 200 / 60.0],
            [c - 300 / 60.0, c - 350 / 60.0],
            [c, c - 350 / 60.0],
            [c, c - 200 / 60.0],
        ]
    )
    np.testing.assert_allclose(obs.vCorners, expect, atol=1e-9)
    assert obs.kind is SlotKind.PERPENDICULAR
    assert (obs.label, obs.label_confidence, obs.corner_sigma) == ("B17", 0.8, 0.12)
    assert obs.confidence == pytest.approx(slot.confidence)
    # entrance-left has the larger y (vehicle left) when the slot lies ahead
    assert obs.vCorners[0, 1] > obs.vCorners[1, 1]


def test_refine_depth_snaps_a_slanted_slot_to_its_painted_separators():
    import math

    import cv2

    from semslam.perception.slots import DetectedSlot, refine_depth
    from semslam.types import SlotKind

    image = np.full((600, 600, 3), 90, np.uint8)
    el, er = np.array([200.0, 300.0]), np.array([380.0, 300.0])
    true = math.radians(130.0)  # separators 50 deg off the entrance, down the image
    d = np.array([math.cos(true), math.sin(true)]) * 300.0
    for p in (el, er):
        cv2.line(image, tuple(int(v) for v in p), tuple(int(v) for v in p + d), (230, 230, 230), 7)
    guess = true + math.radians(12.0)
    g = np.array([math.cos(guess), math.sin(guess)]) * 300.0
    slot = DetectedSlot(0, 1, np.array([el, er, er + g, el + g]), SlotKind.SLANTED, 50.0, 0.9)
    out = refine_depth(image, slot, search_deg=20.0)
    got = np.asarray(out.uv_corners[3] - out.uv_corners[0])
    assert abs(math.degrees(math.atan2(got[1], got[0]) - true)) < 0.5
    np.testing.assert_allclose(out.uv_corners[:2], slot.uv_corners[:2])
    assert abs(np.hypot(*got) - 300.0) < 1e-9
    # on bare floor the separators cannot be measured
    blank = np.full((600, 600, 3), 90, np.uint8)
    assert refine_depth(blank, slot, search_deg=20.0) is None
    # nor when the slot lies across the image border: the entrance 30 px (0.5 m) from the
    # bottom edge, the separators running out of the image
    low = np.full((600, 600, 3), 90, np.uint8)
    low[270:] = image[:330]
    slot_at = DetectedSlot(
        0, 1, np.array([el, er, er + g, el + g]) + [0.0, 270.0], SlotKind.SLANTED, 50.0, 0.9
    )
    assert refine_depth(low, slot_at, search_deg=20.0) is None


def test_a_slanted_slots_angle_follows_its_separators_when_refined():
    """The CNN's directions 10 deg off the painted 60 deg separators: refine_depth turns the
    separators onto the paint, and the slot's angle with them."""
    import cv2

    from semslam.perception.slots import refine_depth

    img = np.full((600, 600, 3), 80, np.uint8)
    a = np.array([200.0, 200.0])
    b = a + [3.0 * 60 / math.sin(math.radians(60.0)), 0.0]
    d = np.array([math.cos(math.radians(60.0)), math.sin(math.radians(60.0))])
    for p in (a, b):
        cv2.line(img, tuple(int(round(x)) for x in p), tuple(int(round(x)) for x in p + 300 * d),
                 (255, 255, 255), 9)
    cv2.line(img, (150, 200), (500, 200), (255, 255, 255), 9)
    (slot,) = infer_slots([mp(*a, math.radians(50.0)), mp(*b, math.radians(50.0))])
    assert slot.kind is SlotKind.SLANTED
    refined = refine_depth(img, slot, search_deg=20.0)
    c = refined.uv_corners
    entrance, sep = c[1] - c[0], c[3] - c[0]
    cos_painted = entrance @ sep / np.linalg.norm(entrance) / np.linalg.norm(sep)
    painted = math.degrees(math.acos(cos_painted))
    assert abs(refined.angle_deg - painted) < 1e-6
    assert abs(refined.angle_deg - slot.angle_deg) > 5.0
