"""Closed-form SE(2) alignment of point sets, and moving a whole map by an SE(2) transform.

A transform is a pose array ``(x, y, yaw)`` (metres, metres, radians; see
:mod:`semslam.geometry`). ``fit_se2`` solves the 2D Kabsch/Umeyama problem
without scale: the rotation from the weighted cross-covariance of the
centred point sets, the translation from their centroids.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from semslam.geometry import FloatArray, compose, rotation, transform_points, wrap_angle
from semslam.types import Marking, SemanticMap, Slot, Tag


def fit_se2(source: ArrayLike, target: ArrayLike, weights: ArrayLike | None = None) -> FloatArray:
    """The least-squares rigid transform ``T`` with ``target ≈ T * source``.

    Minimises ``sum_i w_i * ||R(yaw) @ source_i + (x, y) - target_i||^2`` in
    closed form. With a single point, or all source points coincident, the
    rotation is undetermined and returned as 0 (translation only).

    Args:
        source: (N, 2) points, metres.
        target: (N, 2) corresponding points, metres.
        weights: (N,) non-negative weights; None for all 1.

    Returns:
        (3,) transform ``(x, y, yaw)``: metres, metres, radians in (-pi, pi].

    Raises:
        ValueError: shapes differ or are not (N, 2) with N >= 1, a weight is
            negative or not finite, or the weights sum to 0.
    """
    src = np.asarray(source, dtype=float)
    dst = np.asarray(target, dtype=float)
    if src.ndim != 2 or src.shape[1] != 2 or src.shape != dst.shape or len(src) == 0:
        raise ValueError(
            f"fit_se2: source and target must both be (N, 2) with N >= 1, "
            f"got {src.shape} and {dst.shape}"
        )
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (len(src),) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"fit_se2: weights must be {len(src)} finite values >= 0 with sum > 0")
    w = w / w.sum()
    src_mean = w @ src
    dst_mean = w @ dst
    s = src - src_mean
    d = dst - dst_mean
    # Maximise sum w * d^T R s: cos term sum w (dx sx + dy sy), sin term sum w (dy sx - dx sy).
    cos_term = float(w @ (d[:, 0] * s[:, 0] + d[:, 1] * s[:, 1]))
    sin_term = float(w @ (d[:, 1] * s[:, 0] - d[:, 0] * s[:, 1]))
    yaw = math.atan2(sin_term, cos_term) if (cos_term or sin_term) else 0.0
    t = dst_mean - rotation(yaw) @ src_mean
    return np.array([t[0], t[1], wrap_angle(yaw)])


def apply_se2(transform: ArrayLike, points: ArrayLike) -> FloatArray:
    """Points moved by ``transform``: ``T * p`` for (2,) or (N, 2) points (metres)."""
    return transform_points(transform, points)


def transform_map(transform: ArrayLike, semantic_map: SemanticMap) -> SemanticMap:
    """A copy of ``semantic_map`` with every element moved by ``transform`` ``(x, y, yaw)``.

    Slot corners, tag poses and marking end points are transformed;
    covariances are rotated (``R C R^T``); labels, IDs and metadata are kept.
    """
    T = np.asarray(transform, dtype=float)
    R = rotation(float(T[2]))
    R3 = np.eye(3)
    R3[:2, :2] = R

    def slot(s: Slot) -> Slot:
        covs = np.einsum("ij,njk,lk->nil", R, np.asarray(s.corner_covariances, dtype=float), R)
        return replace(s, corners=transform_points(T, s.corners), corner_covariances=covs)

    def tag(t: Tag) -> Tag:
        return replace(t, mTt=compose(T, t.mTt), covariance=R3 @ t.covariance @ R3.T)

    def marking(m: Marking) -> Marking:
        return replace(m, a=transform_points(T, m.a), b=transform_points(T, m.b))

    return replace(
        semantic_map,
        slots=tuple(slot(s) for s in semantic_map.slots),
        tags=tuple(tag(t) for t in semantic_map.tags),
        markings=tuple(marking(m) for m in semantic_map.markings),
        metadata=dict(semantic_map.metadata),
    )
