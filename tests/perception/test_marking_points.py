"""Marking-point CNN: grid decoding on hand-made tensors, the shipped model's contract,
bad model files and input, and a loose recall check on rendered held-out views."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semslam.errors import PerceptionError
from semslam.perception.marking_points import (
    DEFAULT_MODELS,
    FLOAT_MODELS,
    INT8_AVX2_MODELS,
    INT8_MODELS,
    MarkingPointDetector,
    cpu_flags,
    decode_grid,
    default_models,
)
from semslam.perception.onnx_model import model_path
from semslam.perception.point_verifier import PointVerifier
from semslam.simulation.topview_samples import sample_topviews
from semslam.types import JunctionShape

G = 16


def grid_with(cells) -> np.ndarray:
    """(6, G, G) grid with points at ``(row, col, conf, p_l, ox, oy, direction)``."""
    g = np.zeros((6, G, G), np.float32)
    g[4] = 1.0
    for r, c, conf, p_l, ox, oy, d in cells:
        g[:, r, c] = [conf, p_l, ox, oy, math.cos(d), math.sin(d)]
    return g


def test_decode_position_direction_shape():
    g = grid_with([(3, 5, 0.9, 0.8, 0.5, 0.25, 1.0), (10, 2, 0.7, 0.1, 0.0, 1.0, -2.0)])
    pts = decode_grid(g[None], 600, 0.5)
    assert len(pts) == 2
    a, b = pts  # by decreasing confidence
    np.testing.assert_allclose(a.uv, [5.5 * 37.5 - 0.5, 3.25 * 37.5 - 0.5])
    assert a.direction == pytest.approx(1.0, abs=1e-6)
    assert a.shape is JunctionShape.L and a.confidence == pytest.approx(0.9)
    np.testing.assert_allclose(b.uv, [2 * 37.5 - 0.5, 11 * 37.5 - 0.5])
    assert b.direction == pytest.approx(-2.0, abs=1e-6)
    assert b.shape is JunctionShape.T


def test_decode_threshold_and_scale():
    g = grid_with([(3, 5, 0.4, 0.0, 0.5, 0.5, 0.0)])
    assert decode_grid(g, 600, 0.5) == []
    (p,) = decode_grid(g, 320, 0.3)
    np.testing.assert_allclose(p.uv, [5.5 * 20 - 0.5, 3.5 * 20 - 0.5])


def test_decode_suppresses_close_points():
    # neighbouring cells decoding to points under 10 px apart: the stronger stays
    g = grid_with([(3, 5, 0.8, 0.0, 0.99, 0.5, 0.0), (3, 6, 0.95, 0.0, 0.01, 0.5, 0.0)])
    (p,) = decode_grid(g, 600, 0.5)
    assert p.confidence == pytest.approx(0.95)
    g = grid_with([(3, 5, 0.8, 0.0, 0.5, 0.5, 0.0), (3, 6, 0.95, 0.0, 0.5, 0.5, 0.0)])
    assert len(decode_grid(g, 600, 0.5)) == 2


def test_decode_rejects_bad_grid():
    with pytest.raises(PerceptionError):
        decode_grid(np.zeros((5, G, G)), 600, 0.5)


@pytest.mark.parametrize("load", [MarkingPointDetector, PointVerifier])
def test_missing_and_corrupt_model(tmp_path, load):
    """The grid model and its verifier alike."""
    with pytest.raises(PerceptionError, match="not found"):
        load(tmp_path / "nope.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00garbage" * 100)
    with pytest.raises(PerceptionError, match="bad.onnx"):
        load(bad)


@pytest.fixture(scope="module")
def detector() -> MarkingPointDetector:
    return MarkingPointDetector()


@pytest.fixture(scope="module")
def views():
    # held-out world seeds (the model never trained on 0-99)
    return list(sample_topviews(range(0, 3), 2, 4242))


def test_shipped_model_exists():
    assert model_path("marking_points.onnx").is_file()
    assert all(model_path(name).is_file() for name in DEFAULT_MODELS)


def test_default_grid_is_the_mean_of_the_shipped_models(detector, views):
    """The default detector averages the two shipped models' grids, cell by cell."""
    names = DEFAULT_MODELS
    assert len(names) == 2
    singles = [MarkingPointDetector(model_path(n)) for n in names]
    image = views[0].image
    grids = [d.grid(image)[0] for d in singles]
    mean, side, pad = detector.grid(image)
    assert side == 600 and pad == (0, 0)
    assert np.allclose(mean, (grids[0] + grids[1]) / 2, atol=1e-6)
    assert not np.allclose(grids[0], grids[1], atol=1e-3)  # two different models
    pair = MarkingPointDetector([model_path(n) for n in names])  # runs the two at once
    assert np.allclose(pair.grid(image)[0], mean, atol=1e-6)
    assert np.array_equal(pair.grid(image)[0], pair.grid(image)[0])


def test_the_default_pair_suits_the_cpus_8_bit_instructions():
    assert default_models(cpu_flags()) == DEFAULT_MODELS
    assert default_models({"fpu", "avx2", "avx512f", "avx512_vnni"}) == INT8_MODELS
    assert default_models({"avx2", "avx_vnni"}) == INT8_MODELS
    assert default_models({"fpu", "sse2", "avx2", "fma"}) == INT8_AVX2_MODELS
    assert default_models({"fpu", "sse2"}) == FLOAT_MODELS
    assert default_models(set()) == FLOAT_MODELS
    for twins in (INT8_MODELS, INT8_AVX2_MODELS):
        for f, q in zip(FLOAT_MODELS, twins, strict=True):
            assert model_path(q).stat().st_size < 0.5 * model_path(f).stat().st_size


def test_cpu_flags_are_read_from_the_flags_lines():
    text = "processor\t: 0\nmodel name\t: avx512_vnni in the name\nflags\t\t: fpu avx2 fma\n"
    assert cpu_flags(text) == {"fpu", "avx2", "fma"}
    assert cpu_flags("") == set()


@pytest.mark.skipif(DEFAULT_MODELS == FLOAT_MODELS, reason="the float pair runs on this CPU")
def test_the_default_8_bit_twins_find_the_float_pairs_points(views):
    """Where an 8-bit pair is the default (tools/quantize_models.py), its grid is near the
    float pair's and it finds the same points to within a pixel or two."""
    int8 = MarkingPointDetector([model_path(n) for n in DEFAULT_MODELS])
    floats = MarkingPointDetector([model_path(n) for n in FLOAT_MODELS])
    kept = total = 0
    for s in views:
        g_float, g_int8 = floats.grid(s.image)[0], int8.grid(s.image)[0]
        assert np.abs(g_float[0] - g_int8[0]).max() < 0.1  # confidence
        ref = floats.detect(s.image)
        uv = np.array([p.uv for p in int8.detect(s.image)]).reshape(-1, 2)
        for p in ref:
            total += 1
            kept += bool(len(uv)) and np.hypot(*(uv - p.uv).T).min() < 2.0
    assert total >= 10 and kept >= 0.9 * total


def test_no_model_list_is_refused():
    with pytest.raises(PerceptionError, match="no model"):
        MarkingPointDetector([])


def test_bad_input(detector):
    with pytest.raises(PerceptionError, match="uint8"):
        detector.detect(np.zeros((600, 600, 3), np.float32))
    with pytest.raises(PerceptionError, match="shape"):
        detector.detect(np.zeros((600, 600), np.uint8))


def test_contract_on_rendered_view(detector, views):
    img = views[0].image
    pts = detector.detect(img)
    again = detector.detect(img)
    assert len(pts) == len(again)
    for p, q in zip(pts, again, strict=True):
        np.testing.assert_array_equal(p.uv, q.uv)
        assert p.direction == q.direction and p.confidence == q.confidence
    for p in pts:
        assert p.uv.shape == (2,)
        assert -0.5 <= p.uv[0] <= 599.5 and -0.5 <= p.uv[1] <= 599.5
        assert 0.0 <= p.confidence <= 1.0
        assert -math.pi <= p.direction <= math.pi
        assert isinstance(p.shape, JunctionShape)


def test_the_entrance_check_only_drops_points(detector, views):
    unchecked = MarkingPointDetector(check_entrance=False)
    for s in views:
        img = s.image
        kept = detector.detect(img)
        everything = unchecked.detect(img)
        assert {tuple(p.uv) for p in kept} <= {tuple(p.uv) for p in everything}


def test_non_square_image_padded(detector, views):
    img = views[0].image[:, 60:540]  # 600 rows x 480 columns
    full = detector.detect(views[0].image)
    pts = detector.detect(img)
    for p in pts:
        assert -0.5 <= p.uv[0] <= 479.5 and -0.5 <= p.uv[1] <= 599.5
    # padding back to 600 x 600 restores the geometry: points well inside agree
    inner = [p for p in full if 120 < p.uv[0] < 480]
    for p in inner:
        d = [np.hypot(*(q.uv + [60, 0] - p.uv)) for q in pts]
        assert d and min(d) < 10.0


def test_finds_most_labelled_points(detector, views):
    found = total = false = 0
    for s in views:
        a = s.annotation
        pts = detector.detect(s.image)
        uv = np.array([p.uv for p in pts]).reshape(-1, 2)
        for k in np.nonzero(~a.occluded)[0]:
            total += 1
            if len(uv):
                d = np.hypot(*(uv - a.points[k]).T)
                found += int(d.min() <= 10.0)
        for p in pts:
            false += int(np.hypot(*(a.points - p.uv).T).min(initial=1e9) > 10.0)
    assert total >= 10
    assert found >= 0.8 * total
    assert false <= max(2, 0.2 * total)


@pytest.mark.parametrize("side, size", [(600, 256), (512, 256), (601, 256), (1000, 256)])
def test_shrink_is_opencvs_area_resize_to_the_bit(side, size):
    import cv2

    from semslam.perception.marking_points import shrink

    image = (np.random.default_rng(side).random((side, side, 3)) * 255).astype(np.uint8)
    expected = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(shrink(image, size), expected)
