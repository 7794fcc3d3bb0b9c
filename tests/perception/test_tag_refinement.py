"""Tag corners from the border ring's middle: unmoved by overexposure, unchanged on a
clean tag, left alone where the ring cannot be read."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.stats import norm

from semslam.perception.tag_detection import DetectorSettings, detect_tags
from semslam.perception.tag_refinement import (
    border_contrast,
    refine_corners,
    refine_corners_and_count,
    ring_midpoints,
)

SUPER = 4  # supersampling of the synthetic render


def render_tag(gain: float, seed: int = 0, tag_id: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A 1280 x 800 grey image of a tag36h11 (8 cells of 0.0625 m) about 7 m away, turned
    35 deg, blurred (0.7 px), exposed with ``gain`` (white 200 x gain, clipped at 255)
    and noisy; and its true corners (OpenCV pixels, AprilTag's order)."""
    aruco = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    cell = 20
    code = cv2.aruco.generateImageMarker(aruco, tag_id, 8 * cell)  # black square, 8 cells
    src = cv2.copyMakeBorder(code, cell, cell, cell, cell, cv2.BORDER_CONSTANT, value=255)
    src = np.where(src > 127, 200.0, 30.0).astype(np.float32)
    # the black square's corners in the source, and where they land (4x image)
    a, b = cell - 0.5, 9 * cell - 0.5
    src_corners = np.array([[a, b], [b, b], [b, a], [a, a]], np.float32)  # BL, BR, TR, TL
    K = np.array([[640.0, 0, 639.5], [0, 640.0, 399.5], [0, 0, 1]])
    turn = math.radians(35.0)
    R = np.array([[math.cos(turn), 0, math.sin(turn)], [0, 1, 0],
                  [-math.sin(turn), 0, math.cos(turn)]])
    t = np.array([0.6, -0.2, 7.0])
    obj = np.array([[-0.25, -0.25, 0], [0.25, -0.25, 0], [0.25, 0.25, 0], [-0.25, 0.25, 0]])
    obj[:, 1] *= -1  # tag y up, camera y down
    uv, _ = cv2.projectPoints(obj, cv2.Rodrigues(R)[0], t, K, None)
    uv = uv.reshape(4, 2)
    big = (uv * SUPER + 1.5).astype(np.float32)  # pixel centres: x_big = 4 x + 1.5
    H = cv2.getPerspectiveTransform(src_corners, big)
    canvas = cv2.warpPerspective(src, H, (1280 * SUPER, 800 * SUPER), flags=cv2.INTER_LINEAR,
                                 borderValue=120.0)
    img = cv2.resize(canvas, (1280, 800), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), 0.7) * gain
    img += np.random.default_rng(seed).normal(0.0, 1.5, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), uv


def radial_error(corners: np.ndarray, truth: np.ndarray) -> float:
    """Mean corner error along the direction away from the tag's centre, px (negative:
    the square looks smaller)."""
    out = truth - truth.mean(axis=0)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return float(((corners - truth) * out).sum(axis=1).mean())


def test_ring_midpoint_of_a_clipped_blurred_ring_is_its_middle() -> None:
    x = np.linspace(-3.0, 3.0, 61)
    centre, width, sigma = 0.37, 1.0, 0.35
    ring = norm.cdf((x - centre + width / 2) / sigma) - norm.cdf((x - centre - width / 2) / sigma)
    for white in (200.0, 400.0):  # 400: clipped at 255, both edges eaten into
        profile = np.minimum(255.0, white - (white - 30.0) * ring)
        (mid,) = ring_midpoints(profile[None], x)
        assert mid == pytest.approx(centre, abs=0.01)
    # a trough at the end of the profile has no ring around it
    assert np.isnan(ring_midpoints(np.linspace(0.0, 100.0, 20)[None], np.arange(20.0)))[0]


def test_overexposed_tag_keeps_its_size_and_a_clean_one_its_corners() -> None:
    plain = DetectorSettings(quad_decimate=1.0, ring_refinement=False)
    ring = DetectorSettings(quad_decimate=1.0)
    for gain, seed in ((1.0, 1), (1.8, 2)):
        img, truth = render_tag(gain, seed)
        (raw,) = detect_tags(img, settings=plain)
        (refined,) = detect_tags(img, settings=ring)
        nearest = np.linalg.norm(raw.corners[:, None] - truth[None], axis=2).argmin(axis=1)
        truth = truth[nearest]  # in the detector's corner order
        bias_raw, bias_ring = radial_error(raw.corners, truth), radial_error(refined.corners, truth)
        if gain > 1.0:  # the clipped white eats into the square: AprilTag's corners move in
            assert bias_raw < -0.15
            assert abs(bias_ring) < abs(bias_raw) / 5
        assert np.abs(refined.corners - truth).max() < 0.2
        assert abs(bias_ring) < 0.08


def test_unreadable_ring_leaves_the_corners_alone() -> None:
    corners = np.array([[100.0, 200.0], [200.0, 200.0], [200.0, 100.0], [100.0, 100.0]])
    blank = np.full((300, 300), 128, np.uint8)
    assert np.array_equal(refine_corners(blank, corners, 8), corners)
    img, truth = render_tag(1.0)
    # a quad half a cell off: the ring is not where the grid says, no side is trusted
    shifted = truth + np.array([[-6.0, 6.0], [6.0, 6.0], [6.0, -6.0], [-6.0, -6.0]])
    assert np.array_equal(refine_corners(img, shifted, 8), shifted)


@pytest.mark.parametrize("gain", [0.5, 1.0])
def test_border_contrast_is_white_minus_black(gain: float) -> None:
    img, truth = render_tag(gain)
    contrast = border_contrast(img, truth, 8)
    assert contrast == pytest.approx(170.0 * gain, rel=0.08)  # white 200, black 30, blurred


def test_border_contrast_of_a_bad_quad_is_nan() -> None:
    img, _ = render_tag(1.0)
    assert math.isnan(border_contrast(img, np.full((4, 2), np.nan), 8))


def test_refinement_counts_the_white_cells_it_read_per_side() -> None:
    img, truth = render_tag(1.0, tag_id=5)
    aruco = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    code = cv2.aruco.generateImageMarker(aruco, 5, 8) > 127  # 1 px per cell
    inner = code[1:7, 1:7]  # the data cells; the ring is the outermost cell
    expected = sorted(int(v) for v in (inner[0].sum(), inner[-1].sum(), inner[:, 0].sum(),
                                       inner[:, -1].sum()))
    corners, read = refine_corners_and_count(img, truth, 8)
    assert sorted(read) == expected
    assert np.array_equal(corners, refine_corners(img, truth, 8))
    blank = np.full_like(img, 128)
    assert refine_corners_and_count(blank, truth, 8)[1] == (0, 0, 0, 0)
