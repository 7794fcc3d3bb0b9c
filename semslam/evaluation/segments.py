"""The nearest of many segments to each of many points, exactly, in time near linear.

Scoring a map's painted lines (simulated or the real garage's) or a trajectory against the
nearest marking compares every point with every segment when done plainly: P x S pairs,
quadratic when both grow with the garage. Here a KD-tree over the midpoints of the
segments' pieces (at most 2 m long) gives each point an upper bound (its distance to the
segment of the nearest piece); a segment can only be nearer if one of its pieces'
midpoints lies within that bound plus a piece's half-length, so only those are compared.
The distances are computed by the same formula as the plain comparison and the nearest is
the first of equals, so the result is the plain one.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from semslam.geometry import FloatArray, segment_pieces

_PLAIN_PAIRS = 1 << 16  # below this many point-segment pairs, compare them all
_CHUNK = 1 << 20  # pairs per block
_PIECE = 2.0  # m: the longest piece of a segment in the KD-tree


def _pair_distances(p: FloatArray, a: FloatArray, ab: FloatArray, safe: FloatArray) -> FloatArray:
    """Distance from each point ``p[i]`` to the segment ``a[i]``, ``a[i] + ab[i]``."""
    ap = p - a
    t = np.clip(np.einsum("pi,pi->p", ap, ab) / safe, 0.0, 1.0)
    return np.linalg.norm(ap - t[:, None] * ab, axis=1)


def _candidates(pts, a, ab, safe) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(point, segment) pairs that may be nearest, sorted by point. Long segments enter the
    KD-tree as pieces at most :data:`_PIECE` long (a painted line 50 m long would otherwise
    make every point's reach 25 m)."""
    middles, owner = segment_pieces(a, ab, _PIECE)
    tree = cKDTree(middles)
    _, q0 = tree.query(pts)
    s0 = owner[q0]
    bound = _pair_distances(pts, a[s0], ab[s0], safe[s0])
    lists = tree.query_ball_point(pts, bound + 0.5 * _PIECE + 1e-9)
    counts = np.array([len(c) for c in lists])
    pi = np.repeat(np.arange(len(pts)), counts)
    sj = owner[np.concatenate([np.asarray(c, dtype=np.intp) for c in lists])]
    pairs = np.unique(pi * len(a) + sj)  # one pair per segment, sorted by point
    return pairs // len(a), pairs % len(a)


def nearest_segments(
    points: ArrayLike, a: ArrayLike, b: ArrayLike
) -> tuple[FloatArray, NDArray[np.intp]]:
    """Distance (m) from each point to the nearest segment ``a[k]``-``b[k]``, and its index.

    Args:
        points: (P, 2) points, metres.
        a, b: (S, 2) segment end points, S >= 1; a zero-length segment is a point.

    Returns:
        (P,) distances and (P,) indices into the segments (the lowest of equally near).
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():  # a point that is not one has no nearest segment: NaN, index 0
        d, index = np.full(len(pts), np.nan), np.zeros(len(pts), dtype=np.intp)
        d[finite], index[finite] = nearest_segments(pts[finite], a, b)
        return d, index
    a = np.asarray(a, dtype=float).reshape(-1, 2)
    ab = np.asarray(b, dtype=float).reshape(-1, 2) - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    safe = np.where(length2 > 0, length2, 1.0)
    n_pts, n_seg = len(pts), len(a)
    if n_pts * n_seg <= _PLAIN_PAIRS:
        pi, sj = np.repeat(np.arange(n_pts), n_seg), np.tile(np.arange(n_seg), n_pts)
    else:
        pi, sj = _candidates(pts, a, ab, safe)
    d = np.empty(len(pi))
    for s in range(0, len(pi), _CHUNK):
        i, j = pi[s : s + _CHUNK], sj[s : s + _CHUNK]
        d[s : s + _CHUNK] = _pair_distances(pts[i], a[j], ab[j], safe[j])
    order = np.lexsort((sj, d, pi))  # by point, then distance, then segment index
    first = order[np.r_[0, np.flatnonzero(np.diff(pi[order])) + 1]] if len(order) else order
    return d[first], sj[first].astype(np.intp)


def sample_segments(a: ArrayLike, b: ArrayLike, step: float) -> tuple[FloatArray, NDArray[np.intp]]:
    """Points along each segment ``a[k]``-``b[k]`` (S, 2), metres, both ends included and at
    most ``step`` m apart (at least two per segment), and the segment of each point: (N, 2)
    and (N,), segment by segment in order. A KD-tree over them finds the segments near a
    place without a test against every segment."""
    a = np.asarray(a, dtype=float).reshape(-1, 2)
    b = np.asarray(b, dtype=float).reshape(-1, 2)
    count = np.maximum(2, np.ceil(np.hypot(*(b - a).T) / step).astype(int) + 1)
    owner = np.repeat(np.arange(len(a)), count)
    t = np.concatenate([np.linspace(0.0, 1.0, n) for n in count]) if len(a) else np.zeros(0)
    return a[owner] + t[:, None] * (b - a)[owner], owner


__all__ = ["nearest_segments", "sample_segments"]
