"""The painted separators a map's slots imply, as line markings for the localizer.

A slot's two sides (entrance corner -> rear corner, :class:`~semslam.types.Slot`'s corners
1 -> 2 and 0 -> 3) are its separators, painted lines the map knows through its corners even
where its painted-line layer holds none: the mapper keeps a line only once its detections
support it, so a row that the mapping drive saw from afar comes with its slots and without
their separators. A car that then drives along that row sees the separators, and with
painted lines alone nothing else tells it where it is along the aisle (BENCHMARKS.md,
Localizer, "Held out: eight more worlds").

A side is left out where a map line of about its direction (within
:data:`PARALLEL_DEG`) already lies within :data:`SAME_LINE_M` of one of its ends or its
middle: two candidates for one painted line would fail the association's ratio test. Two
neighbouring slots share a separator, so of two sides whose middles lie within
:data:`SAME_LINE_M` the first is kept. Map frame, metres; no I/O.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from semslam.evaluation.segments import nearest_segments, sample_segments
from semslam.types import Marking, SemanticMap

SAME_LINE_M = 0.3  # m: a map line or another side this near is the same painted line
PARALLEL_DEG = 10.0  # deg: a map line turned less than this from a side may be the same line
SIDE_WIDTH = 0.1  # m: nominal width given to a side (the localizer reads end points only)
_SAMPLE_M = 1.0  # m between points sampled along the map's lines to find those near a side


def slot_sides(semantic_map: SemanticMap) -> tuple[Marking, ...]:
    """The separators of ``semantic_map``'s slots that its line markings do not already
    hold, each once, as :class:`~semslam.types.Marking` (sigma from the corners), in slot
    order."""
    if not semantic_map.slots:
        return ()
    corners = np.array([s.corners for s in semantic_map.slots], dtype=float)  # (S, 4, 2)
    sides = np.concatenate([corners[:, [1, 2]], corners[:, [0, 3]]], axis=1).reshape(-1, 2, 2)
    covs = np.array([s.corner_covariances for s in semantic_map.slots], dtype=float)
    side_covs = np.concatenate([covs[:, [1, 2]], covs[:, [0, 3]]], axis=1).reshape(-1, 2, 2, 2)
    length = np.hypot(*(sides[:, 1] - sides[:, 0]).T)
    normal = (sides[:, 1] - sides[:, 0]) @ np.array([[0.0, 1.0], [-1.0, 0.0]]) / np.maximum(
        length, 1e-9)[:, None]  # (N, 2) unit, across the side
    across = np.einsum("ni,nkij,nj->nk", normal, side_covs, normal)  # (N, 2 corners), m^2
    sigma = np.sqrt(np.clip(across, 0.0, None).mean(axis=1))
    keep = length > 1e-6
    middles = sides.mean(axis=1)
    lines = semantic_map.markings
    if lines:
        a = np.array([m.a for m in lines], dtype=float)
        b = np.array([m.b for m in lines], dtype=float)
        u = (b - a) / np.maximum(np.hypot(*(b - a).T), 1e-9)[:, None]
        # points every _SAMPLE_M along each line: a line within SAME_LINE_M of a side has one
        # within SAME_LINE_M + _SAMPLE_M / 2 of it, so within that of the side's middle
        # plus half the side's length
        samples, owner = sample_segments(a, b, _SAMPLE_M)
        found = cKDTree(samples).query_ball_point(
            middles, 0.5 * length + SAME_LINE_M + 0.5 * _SAMPLE_M)
        cos_parallel = math.cos(math.radians(PARALLEL_DEG))
        for i in np.flatnonzero(keep):
            near = np.unique(owner[np.array(found[i], dtype=int)])
            if not len(near):
                continue
            v = (sides[i, 1] - sides[i, 0]) / length[i]
            near = near[np.abs(u[near] @ v) > cos_parallel]
            if not len(near):
                continue
            probes = np.vstack([sides[i], middles[i]])
            if nearest_segments(probes, a[near], b[near])[0].min() < SAME_LINE_M:
                keep[i] = False
    for i, j in sorted(cKDTree(middles).query_pairs(SAME_LINE_M)):
        if keep[i] and keep[j]:
            keep[j] = False
    return tuple(Marking(sides[i, 0].copy(), sides[i, 1].copy(), SIDE_WIDTH,
                         float(sigma[i]) if np.isfinite(sigma[i]) else None)
                 for i in np.flatnonzero(keep))


__all__ = ["PARALLEL_DEG", "SAME_LINE_M", "slot_sides"]
