"""Slot detections between keyframes fused into the keyframe's detection."""

import math
from dataclasses import replace

import numpy as np
import pytest

from semslam.geometry import inverse_transform_points, transform_points
from semslam.mapping.frame_fusion import fuse_detection, slots_in_keyframe
from semslam.types import FrameObservations, SlotKind, SlotObservation

SLOT = np.array([[3.0, 1.0], [3.0, -1.5], [8.0, -1.5], [8.0, 1.0]])


def _obs(corners, kind=SlotKind.PERPENDICULAR, label="A1", sigma=0.05):
    return SlotObservation(np.asarray(corners, float), kind, label, 0.9, 1.0, sigma)


def test_a_slot_seen_from_an_earlier_frame_lands_where_the_keyframe_sees_it():
    keyframe = np.array([1.0, 0.2, 0.1])  # in the previous keyframe's frame
    earlier = np.array([0.4, 0.05, 0.03])
    world = transform_points(keyframe, SLOT)  # slot in the previous keyframe's frame
    frame = FrameObservations(1.0, (_obs(inverse_transform_points(earlier, world)),), (), ())
    moved = slots_in_keyframe([(frame, earlier)], keyframe)
    assert len(moved) == 1
    np.testing.assert_allclose(moved[0].vCorners, SLOT, atol=1e-12)


def test_detections_of_the_same_slot_average_and_sharpen():
    rng = np.random.default_rng(0)
    others = [_obs(SLOT + rng.normal(0, 0.05, (4, 2))) for _ in range(4)]
    primary = _obs(SLOT + rng.normal(0, 0.05, (4, 2)))
    fused, count = fuse_detection(primary, others, radius=0.3, max_count=3)
    assert count == 3
    assert fused.corner_sigma == pytest.approx(0.05 / math.sqrt(3))
    assert fused.label == primary.label and fused.kind == primary.kind


def test_a_shared_error_is_not_sharpened_by_fusion():
    """Of a declared error model, the own part averages over the fused frames, the part
    every frame of the slot shares does not."""
    rng = np.random.default_rng(1)
    model = {"corner_sigma_own": (0.02, 0.02, 0.04, 0.04),
             "corner_sigma_shared": (0.01, 0.01, 0.02, 0.02)}
    others = [replace(_obs(SLOT + rng.normal(0, 0.02, (4, 2))), **model) for _ in range(3)]
    primary = replace(_obs(SLOT), **model)
    fused, count = fuse_detection(primary, others, radius=0.3, max_count=4)
    assert count == 4
    np.testing.assert_allclose(fused.corner_sigma_own, np.array([0.02, 0.02, 0.04, 0.04]) / 2)
    assert fused.corner_sigma_shared == model["corner_sigma_shared"]


def test_the_closest_detections_are_the_ones_averaged():
    """Four others 0.04-0.16 m off, room for two: the mean of the primary and the two
    closest, whatever order they come in."""
    offsets = [0.16, 0.04, 0.12, 0.08]
    others = [_obs(SLOT + [d, 0.0]) for d in offsets]
    fused, count = fuse_detection(_obs(SLOT), others, radius=0.3, max_count=3)
    assert count == 3
    np.testing.assert_allclose(fused.vCorners, SLOT + [(0.0 + 0.04 + 0.08) / 3, 0.0],
                               atol=1e-12)


def test_other_slots_and_other_kinds_are_not_fused():
    neighbour = _obs(SLOT + [0.0, 2.5])
    slanted = _obs(SLOT + 0.02, kind=SlotKind.SLANTED)
    shifted = _obs(SLOT + [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.5, 0.0]])  # one corner off
    fused, count = fuse_detection(_obs(SLOT), [neighbour, slanted, shifted], 0.3, 3)
    assert count == 1
    np.testing.assert_array_equal(fused.vCorners, SLOT)


def test_max_count_one_turns_fusion_off():
    primary = _obs(SLOT)
    fused, count = fuse_detection(primary, [_obs(SLOT + 0.01)], 0.3, 1)
    assert count == 1 and fused is primary


def test_fusion_averages_noise_on_a_simulated_drive():
    """Monte Carlo: the fused corner error shrinks by about sqrt(count)."""
    rng = np.random.default_rng(1)
    errors = {1: [], 3: []}
    for _ in range(400):
        dets = [_obs(SLOT + rng.normal(0, 0.05, (4, 2))) for _ in range(3)]
        for cap in errors:
            fused, _ = fuse_detection(dets[0], dets[1:], 0.3, cap)
            errors[cap].append(np.sqrt(np.mean((fused.vCorners - SLOT) ** 2)))
    ratio = np.sqrt(np.mean(np.square(errors[1]))) / np.sqrt(np.mean(np.square(errors[3])))
    assert ratio == pytest.approx(math.sqrt(3), rel=0.1)
