"""The two-way comparison of line maps on hand-made segments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semslam.evaluation.line_map import compare_line_maps, near_path, point_segment_distances


def test_point_segment_distances() -> None:
    seg = np.array([[[0.0, 0.0], [2.0, 0.0]], [[5.0, 0.0], [5.0, 3.0]]])
    pts = np.array([[1.0, 0.5], [-1.0, 0.0], [3.0, 4.0], [5.2, 1.0], [1.0, 0.0]])
    d = point_segment_distances(pts, seg)
    assert np.allclose(d, [0.5, 1.0, math.hypot(2.0, 1.0), 0.2, 0.0])
    assert np.isinf(point_segment_distances(pts, np.zeros((0, 2, 2)))).all()
    assert point_segment_distances(np.zeros((0, 2)), seg).shape == (0,)
    # a zero-length segment is a point
    assert np.allclose(point_segment_distances([[3.0, 4.0]], [[[0.0, 0.0], [0.0, 0.0]]]), 5.0)


def test_near_path() -> None:
    path = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert near_path([[0.0, 4.9], [5.0, 0.5], [10.0, -5.1]], path, 5.0).tolist() == [
        True, False, False,
    ]


def test_two_way_comparison() -> None:
    # reference: a row of three separators 2.5 m apart and a back line, along y = 3..8
    ref = np.array([[[x, 3.0], [x, 8.0]] for x in (0.0, 2.5, 5.0)] + [[[0.0, 8.0], [5.0, 8.0]]])
    shift = np.array([0.1, 0.0])
    mapped = np.concatenate(
        [
            ref[:3] + shift,  # the separators, 10 cm off across
            [[[20.0, 3.0], [20.0, 5.0]]],  # a line that is not in the reference
        ]
    )
    path = np.column_stack([np.linspace(-5, 25, 61), np.zeros(61)])
    c = compare_line_maps(mapped, ref, path, radius=5.0)
    # reference end points within 5 m of the path: the three separators' lower ends
    assert c.reference_to_map.points == 3 and c.reference_segments == 3
    assert np.isclose(c.reference_to_map.median_m, 0.1)
    # mapped end points near the path: three separators' lower ends + the false line's two
    assert c.map_to_reference.points == 5 and c.mapped_segments == 4
    d = np.sort([0.1, 0.1, 0.1, 15.0 + 0.0, math.hypot(15.0, 0.0)])
    assert np.isclose(c.map_to_reference.median_m, np.median(d))
    assert np.isclose(c.map_to_reference.p95_m, np.percentile([0.1, 0.1, 0.1, 15.0, 15.0], 95))
    assert np.isclose(c.map_to_reference.within_share, 0.6)
    # a wider area takes the back line too; its ends lie 0.1 m from the shifted separators
    wide = compare_line_maps(mapped, ref, path, radius=9.0)
    assert wide.reference_to_map.points == 8
    assert wide.to_dict()["radius_m"] == 9.0


def test_nothing_to_compare() -> None:
    ref = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    c = compare_line_maps(np.zeros((0, 2, 2)), ref, np.zeros((1, 2)))
    assert c.reference_to_map.points == 2 and np.isinf(c.reference_to_map.median_m)
    assert np.isinf(c.reference_to_map.p95_m) and np.isinf(c.reference_to_map.max_m)
    assert c.map_to_reference.points == 0 and math.isnan(c.map_to_reference.p95_m)
    far = compare_line_maps(ref, ref, np.array([[100.0, 100.0]]))
    assert far.reference_to_map.points == 0


@pytest.mark.parametrize("n", [1, 7, 2000])
def test_chunks_agree(n: int) -> None:
    rng = np.random.default_rng(n)
    seg = rng.uniform(-10, 10, (n, 2, 2))
    pts = rng.uniform(-10, 10, (50, 2))
    brute = [
        min(
            np.linalg.norm(
                p - (a + np.clip(np.dot(p - a, b - a) / max(np.dot(b - a, b - a), 1e-18), 0, 1)
                     * (b - a))
            )
            for a, b in seg
        )
        for p in pts
    ]
    assert np.allclose(point_segment_distances(pts, seg), brute)
