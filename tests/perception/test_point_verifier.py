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
    DEFAULT_THRESHOLD,
    GRID_THRESHOLD,
    MarkingPointDetector,
    verified_confidence,
)
from semslam.perception.onnx_model import model_path
from semslam.perception.point_verifier import (
    DEFAULT_MODELS,
    MIRROR_LOOK_BAND,
    PATCH_PX,
    SPAN_PX,
    PointVerifier,
    crop_point_patches,
    refined,
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
    assert len(DEFAULT_MODELS) == 2
    for name in DEFAULT_MODELS:
        assert model_path(name).is_file()
        assert model_path(name).stat().st_size < 10e6
    rng = np.random.default_rng(3)
    patches = rng.integers(0, 256, (7, PATCH_PX, PATCH_PX, 3), dtype=np.uint8)
    v = verifier.verdicts(patches)
    assert v.shape == (7, 5) and np.all((v[:, 0] >= 0) & (v[:, 0] <= 1))
    np.testing.assert_allclose(np.hypot(v[:, 3], v[:, 4]), 1.0, atol=1e-5)  # a turn
    assert np.array_equal(v, verifier.verdicts(patches))  # deterministic
    one_by_one = np.concatenate([verifier.verdicts(patches[k : k + 1]) for k in range(7)])
    np.testing.assert_allclose(v, one_by_one, atol=1e-5)  # the halves are the whole
    assert verifier.verdicts(np.zeros((0, PATCH_PX, PATCH_PX, 3), np.uint8)).shape == (0, 5)


def test_the_shipped_pair_gives_its_models_mean_verdict(verifier):
    """Two models' verdicts are averaged, the turn made a unit vector again; one model
    given alone is that model."""
    rng = np.random.default_rng(4)
    patches = rng.integers(0, 256, (5, PATCH_PX, PATCH_PX, 3), dtype=np.uint8)
    first, second = (PointVerifier(model_path(name), mirror_look=False).score(patches)
                     for name in DEFAULT_MODELS)
    assert not np.allclose(first, second, atol=1e-3)  # two different models
    mean = 0.5 * (first + second)
    mean[:, 3:] /= np.hypot(mean[:, 3], mean[:, 4])[:, None]
    pair = PointVerifier(mirror_look=False)
    assert [p.name for p in pair.paths] == list(DEFAULT_MODELS)
    np.testing.assert_allclose(pair.score(patches), mean, atol=1e-6)
    with pytest.raises(PerceptionError, match="no model"):
        PointVerifier([])


def test_refined_moves_along_the_patch_axes_and_turns():
    uv = np.array([[100.0, 200.0], [100.0, 200.0]])
    d = np.array([0.0, math.pi / 2])  # pointing right (+u), pointing down (+v)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    v = np.array([[0.9, 5.0, 3.0, c, s], [0.9, 5.0, 3.0, c, s]])
    moved, turned = refined(uv, d, v)
    # up = the direction, right = the direction turned +90 deg in image coordinates
    np.testing.assert_allclose(moved, [[103.0, 205.0], [95.0, 203.0]], atol=1e-9)
    np.testing.assert_allclose(turned, [math.radians(30), math.radians(120)], atol=1e-9)
    assert refined(uv, d, np.array([[0.5, 0, 0, -1.0, 1e-12]] * 2))[1] == pytest.approx(
        [math.pi, -math.pi / 2])  # wrapped


def _training_tool():
    """``tools/train_point_verifier.py`` as a module (tools/ is not a package)."""
    import importlib.util
    from pathlib import Path

    tool = Path(__file__).resolve().parents[2] / "tools" / "train_point_verifier.py"
    spec = importlib.util.spec_from_file_location("train_point_verifier", tool)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_training_targets_are_what_refined_undoes():
    """The training tool's targets, fed back through :func:`refined`, give the labelled
    points and directions: the network is trained in the frame the detector reads."""
    module = _training_tool()
    rng = np.random.default_rng(5)
    uv = rng.uniform(0, 600, (20, 2))
    d = rng.uniform(-math.pi, math.pi, 20)
    to_uv = uv + rng.normal(0, 8, (20, 2))
    to_d = d + rng.normal(0, 1.0, 20)
    t = module.refinement_target(uv, d, to_uv, to_d)
    moved, turned = refined(uv, d, np.column_stack([np.ones(20), t]))
    np.testing.assert_allclose(moved, to_uv, atol=1e-3)
    np.testing.assert_allclose(np.angle(np.exp(1j * (turned - to_d))), 0.0, atol=1e-5)


def test_bad_model_and_input(verifier):
    """(Missing and corrupt files: test_marking_points.py, for both models.)"""
    with pytest.raises(PerceptionError, match="expected input"):
        PointVerifier(model_path("marking_points.onnx"))  # another model's input
    with pytest.raises(PerceptionError, match="expected patches"):
        verifier.verdicts(np.zeros((2, 32, 32, 3), np.uint8))


@pytest.fixture(scope="module")
def candidates():
    """The grid's candidates on held-out views (worlds 0-19), each with whether a labelled
    point lies within 20 px that no stronger candidate took, and the view they came from."""
    grid_only = MarkingPointDetector(threshold=CANDIDATE_THRESHOLD, verify=False)
    assign_nearby = _training_tool().assign_nearby
    out = []
    for s in sample_topviews(range(0, 20), 2, 99):
        a = s.annotation
        pts = grid_only.detect(s.image)
        if not pts:
            continue
        uv = np.array([p.uv for p in pts])
        d = np.array([p.direction for p in pts])
        c = np.array([p.confidence for p in pts])
        labels = a.points[~a.occluded]
        near = assign_nearby(uv, c, labels) >= 0  # as the training labels are made
        far = np.ones(len(uv), bool)
        if a.occluded.any():
            far = np.linalg.norm(uv[:, None] - a.points[a.occluded][None], axis=2).min(1) > 20
        out.append((s.image, uv[far], d[far], c[far], near[far], labels,
                    a.directions[~a.occluded]))
    return out


def test_verifier_tells_true_candidates_from_false(verifier, candidates):
    """On views it never trained on, candidates with a point to move to score higher than
    those without: the verifier ranks them better than the grid's own confidence does."""
    probs, grid, hits = [], [], []
    for image, uv, d, c, hit, _, _ in candidates:
        probs.append(verifier.verify(image, uv, d)[0])
        grid.append(c)
        hits.append(hit)
    p, g, h = np.concatenate(probs), np.concatenate(grid), np.concatenate(hits)
    assert h.sum() >= 50 and (~h).sum() >= 10

    def auc(score: np.ndarray) -> float:  # P(a true candidate outscores a false one)
        t, f = score[h], score[~h]
        return float(((t[:, None] > f[None]) + 0.5 * (t[:, None] == f[None])).mean())

    assert auc(p) > 0.9
    assert auc(p) > auc(g)


def test_verifier_moves_candidates_onto_their_points(verifier, candidates):
    """The move and turn bring the candidates that have a point nearer to it: the
    verifier's places hit (10 px, 30 deg) more labelled points than the grid's."""
    hits_grid = hits_moved = 0
    for image, uv, d, c, _, labels, ldir in candidates:
        _, moved, turned = verifier.verify(image, uv, d)
        hits_grid += int((match_points(uv, d, c, labels, ldir) >= 0).sum())
        hits_moved += int((match_points(moved, turned, c, labels, ldir) >= 0).sum())
    assert hits_moved >= hits_grid


def test_verify_crops_and_scores_in_halves_as_one_by_one(verifier, candidates):
    """verify() crops and scores its two halves on two cores: each point as alone."""
    image, uv, d = next((im, u, dd) for im, u, dd, *_ in candidates if len(u) >= 3)
    whole = verifier.verify(image, uv, d)
    alone = [verifier.verify(image, uv[k : k + 1], d[k : k + 1]) for k in range(len(uv))]
    for part, each in zip(whole, zip(*alone, strict=True), strict=True):
        np.testing.assert_allclose(part, np.concatenate(each), atol=1e-5)
        assert len(part) == len(uv)


def test_mirror_look_where_the_first_is_uncertain(verifier, candidates):
    """Patches with a first verdict inside MIRROR_LOOK_BAND get the mean of it and the
    mirrored patch's verdict mirrored back (the turn a unit vector); the others keep
    their first. Where both a patch and its mirror are uncertain, their verdicts are then
    mirror images: the same probability and forward move, opposite sideways moves and
    turns."""
    patches = np.concatenate(
        [crop_point_patches(image, uv, d) for image, uv, d, *_ in candidates[:12]])
    raw = PointVerifier(mirror_look=False)
    first, mirrored = raw.score(patches), raw.score(np.ascontiguousarray(patches[:, :, ::-1]))
    lo, hi = MIRROR_LOOK_BAND
    unsure = (first[:, 0] >= lo) & (first[:, 0] <= hi)
    assert 0 < unsure.sum() < len(patches)
    sign = np.array([1.0, -1.0, 1.0, 1.0, -1.0])
    mean = 0.5 * (first + sign * mirrored)
    mean[:, 3:] /= np.hypot(mean[:, 3], mean[:, 4])[:, None]
    want = np.where(unsure[:, None], mean, first)
    np.testing.assert_allclose(verifier.score(patches), want, atol=1e-6)
    both = unsure & (mirrored[:, 0] >= lo) & (mirrored[:, 0] <= hi)
    assert both.any()
    np.testing.assert_allclose(
        verifier.score(np.ascontiguousarray(patches[both, :, ::-1])),
        verifier.score(patches[both]) * sign, atol=1e-6)


def test_no_candidate_left_out_could_be_kept():
    """A cell under the candidate threshold could not reach the kept confidence even with
    the verifier's full vote, so the threshold only saves work."""
    assert CANDIDATE_THRESHOLD <= DEFAULT_THRESHOLD**2
    assert verified_confidence(CANDIDATE_THRESHOLD - 1e-9, 1.0) < DEFAULT_THRESHOLD


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
