"""The marking-point verifier: patch geometry, the shipped model's contract, bad model
files and input, and that it tells true candidates from false ones on held-out views."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from semslam.errors import PerceptionError
from semslam.evaluation.detection_metrics import match_points
from semslam.perception.marking_points import (
    CANDIDATE_THRESHOLD,
    GRID_THRESHOLD,
    MarkingPointDetector,
)
from semslam.perception.onnx_model import model_path
from semslam.perception.point_verifier import (
    DEFAULT_MODEL,
    PATCH_PX,
    SPAN_PX,
    PointVerifier,
    crop_point_patches,
)
from semslam.simulation.topview_samples import sample_topviews


@pytest.mark.parametrize("deg", [0.0, 30.0, 90.0, -135.0, 180.0])
def test_patch_turns_the_direction_up(deg):
    """A dot 30 px from the point along its direction lands 30 px (scaled) above the
    patch centre, whatever the direction."""
    image = np.zeros((600, 600, 3), np.uint8)
    u, v, a = 300.0, 250.0, math.radians(deg)
    dot = (int(round(u + 30 * math.cos(a))), int(round(v + 30 * math.sin(a))))
    cv2.circle(image, dot, 3, (255, 255, 255), -1)
    (patch,) = crop_point_patches(image, np.array([[u, v]]), np.array([a]))
    rows, cols = np.nonzero(patch[..., 0] > 100)
    c = (PATCH_PX - 1) / 2.0
    assert cols.mean() == pytest.approx(c, abs=0.6)
    assert rows.mean() == pytest.approx(c - 30 * PATCH_PX / SPAN_PX, abs=0.6)


def test_patch_mirror_and_outside():
    """The patch's right is the direction turned clockwise on screen (+90 deg in image
    coordinates), and view beyond the image is black."""
    image = np.full((600, 600, 3), 200, np.uint8)
    cv2.circle(image, (300, 330), 3, (0, 0, 255), -1)  # 30 px below the point (v down)
    (patch,) = crop_point_patches(image, np.array([[300.0, 300.0]]), np.array([0.0]))
    rows, cols = np.nonzero((patch[..., 2] > 150) & (patch[..., 0] < 100))
    c = (PATCH_PX - 1) / 2.0
    assert cols.mean() == pytest.approx(c + 30 * PATCH_PX / SPAN_PX, abs=0.6)
    assert rows.mean() == pytest.approx(c, abs=0.6)
    (corner,) = crop_point_patches(image, np.array([[0.0, 0.0]]), np.array([0.0]))
    # the bottom-left of the patch lies left of and above the image, its top-right inside
    assert corner[-1, 0].tolist() == [0, 0, 0] and corner[0, -1].tolist() == [200] * 3
    assert crop_point_patches(image, np.zeros((0, 2)), np.zeros(0)).shape == (
        0, PATCH_PX, PATCH_PX, 3)


@pytest.fixture(scope="module")
def verifier() -> PointVerifier:
    return PointVerifier()


def test_shipped_model_contract(verifier):
    assert model_path(DEFAULT_MODEL).is_file()
    assert model_path(DEFAULT_MODEL).stat().st_size < 10e6
    rng = np.random.default_rng(3)
    patches = rng.integers(0, 256, (7, PATCH_PX, PATCH_PX, 3), dtype=np.uint8)
    p = verifier.probabilities(patches)
    assert p.shape == (7,) and np.all((p >= 0) & (p <= 1))
    assert np.array_equal(p, verifier.probabilities(patches))  # deterministic
    one_by_one = np.concatenate([verifier.probabilities(patches[k : k + 1]) for k in range(7)])
    np.testing.assert_allclose(p, one_by_one, atol=1e-6)  # the halves are the whole
    assert verifier.probabilities(np.zeros((0, PATCH_PX, PATCH_PX, 3), np.uint8)).shape == (0,)


def test_bad_files_and_input(tmp_path, verifier):
    with pytest.raises(PerceptionError, match="not found"):
        PointVerifier(tmp_path / "nope.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00garbage" * 100)
    with pytest.raises(PerceptionError, match="bad.onnx"):
        PointVerifier(bad)
    with pytest.raises(PerceptionError, match="expected input"):
        PointVerifier(model_path("marking_points.onnx"))  # another model's input
    with pytest.raises(PerceptionError, match="expected patches"):
        verifier.probabilities(np.zeros((2, 32, 32, 3), np.uint8))


@pytest.fixture(scope="module")
def candidates():
    """The grid's candidates on held-out views (worlds 0-19), each with whether it is a
    ps2.0 hit, and the view and verifier they came from."""
    grid_only = MarkingPointDetector(threshold=CANDIDATE_THRESHOLD, verify=False)
    out = []
    for s in sample_topviews(range(0, 20), 2, 99):
        a = s.annotation
        pts = grid_only.detect(s.image)
        if not pts:
            continue
        uv = np.array([p.uv for p in pts])
        d = np.array([p.direction for p in pts])
        c = np.array([p.confidence for p in pts])
        vis = ~a.occluded
        hit = match_points(uv, d, c, a.points[vis], a.directions[vis]) >= 0
        far = np.ones(len(uv), bool)
        if a.occluded.any():
            far = np.linalg.norm(uv[:, None] - a.points[a.occluded][None], axis=2).min(1) > 10
        out.append((s.image, uv[far], d[far], c[far], hit[far]))
    return out


def test_verifier_tells_true_candidates_from_false(verifier, candidates):
    """On views it never trained on, true candidates score higher than false ones: the
    verifier ranks them better than the grid's own confidence does."""
    probs, grid, hits = [], [], []
    for image, uv, d, c, hit in candidates:
        probs.append(verifier.verify(image, uv, d))
        grid.append(c)
        hits.append(hit)
    p, g, h = np.concatenate(probs), np.concatenate(grid), np.concatenate(hits)
    assert h.sum() >= 50 and (~h).sum() >= 10

    def auc(score: np.ndarray) -> float:  # P(a true candidate outscores a false one)
        t, f = score[h], score[~h]
        return float(((t[:, None] > f[None]) + 0.5 * (t[:, None] == f[None])).mean())

    assert auc(p) > 0.9
    assert auc(p) > auc(g)


def test_detector_with_and_without_the_verifier(candidates):
    image = candidates[0][0]
    plain = MarkingPointDetector(verify=False)
    assert plain.threshold == GRID_THRESHOLD and plain.verifier is None
    assert all(p.confidence >= GRID_THRESHOLD for p in plain.detect(image))
    verified = MarkingPointDetector()
    pts = verified.detect(image)
    again = verified.detect(image)
    assert [p.confidence for p in pts] == [p.confidence for p in again]
    conf = [p.confidence for p in pts]
    assert conf == sorted(conf, reverse=True)
    assert all(verified.threshold <= c <= 1.0 for c in conf)
