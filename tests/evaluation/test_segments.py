"""The nearest segment to each point through a KD-tree: the plain all-pairs answer
(semslam.evaluation.segments)."""

import numpy as np
import pytest

from semslam.evaluation.segments import nearest_segments


def _all_pairs(points, a, b):
    ab = b - a
    ap = points[:, None] - a[None]
    t = np.clip((ap * ab).sum(axis=2) / np.maximum((ab * ab).sum(axis=1), 1e-300), 0.0, 1.0)
    d = np.linalg.norm(ap - t[..., None] * ab, axis=2)
    return d.min(axis=1), d.argmin(axis=1)


@pytest.mark.parametrize("long_lines", [False, True])
def test_the_nearest_segment_is_the_one_all_pairs_find(long_lines):
    """Thousands of short marks, some of zero length, and optionally a few 80 m lines
    that reach past the KD-tree's nearest midpoints."""
    rng = np.random.default_rng(7)
    a = rng.uniform(0, 200, (2000, 2))
    b = a + rng.normal(0, 2.0, (2000, 2))
    b[::13] = a[::13]  # points, not lines
    if long_lines:
        b[:5] = a[:5] + [80.0, 0.0]
    points = rng.uniform(-10, 210, (3000, 2))
    d, index = nearest_segments(points, a, b)
    d_all, index_all = _all_pairs(points, a, b)
    np.testing.assert_allclose(d, d_all, rtol=0, atol=1e-12)
    assert (index == index_all).mean() == 1.0


def test_equally_near_segments_give_the_first():
    a = np.array([[0.0, 1.0], [0.0, -1.0], [5.0, 5.0]])
    b = a + [1.0, 0.0]
    d, index = nearest_segments(np.array([[0.5, 0.0]]), a, b)
    assert d.tolist() == [1.0] and index.tolist() == [0]


def test_a_point_that_is_not_a_number_has_no_nearest_segment():
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 100, (500, 2))
    points = rng.uniform(0, 100, (300, 2))
    points[3] = np.nan
    d, index = nearest_segments(points, a, a + 1.0)
    assert np.isnan(d[3]) and np.isfinite(np.delete(d, 3)).all() and index[3] == 0
