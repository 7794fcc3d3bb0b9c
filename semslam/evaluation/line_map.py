"""Two-way comparison of a map of painted lines with a reference map of line segments.

- **completeness / placement** (reference -> mapped): for every reference end point in the
  area the drive saw, the distance to the nearest mapped segment: is every line there,
  in the right place?
- **correctness** (mapped -> reference): for every mapped end point in that area, the
  distance to the nearest reference segment: is what was mapped real?

Both report the median and the 95th percentile (and the share within a tolerance). The
area is the set of points within ``radius`` of the trajectory (the masks' reach); the
nearest segment is searched among *all* segments of the other map, so a line just outside
the area still counts as a match. End points are compared, not whole lines: an end
point carries both the position across a line and the extent along it, and it is what
the reference map is made of. Pure numpy, map frame, metres.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from semslam.evaluation.segments import nearest_segments
from semslam.geometry import FloatArray

_CHUNK = 4_000_000  # point-pose pairs evaluated at once


def point_segment_distances(points: FloatArray, segments: FloatArray) -> FloatArray:
    """(P,) distance from each point (P, 2) to the nearest of the segments (S, 2, 2)
    (:func:`~semslam.evaluation.segments.nearest_segments`); infinity when there is no
    segment."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    s = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    if len(s) == 0 or len(p) == 0:
        return np.full(len(p), np.inf)
    return nearest_segments(p, s[:, 0], s[:, 1])[0]


def near_path(points: FloatArray, path: FloatArray, radius: float) -> np.ndarray:
    """(P,) True where a point (P, 2) lies within ``radius`` of a position of ``path`` (T, 2)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    t = np.asarray(path, dtype=float).reshape(-1, 2)
    out = np.zeros(len(p), dtype=bool)
    if len(t) == 0 or len(p) == 0:
        return out
    step = max(1, _CHUNK // len(t))
    r2 = radius * radius
    for i in range(0, len(p), step):
        q = p[i : i + step, None, :] - t[None]
        out[i : i + step] = ((q * q).sum(-1) <= r2).any(axis=1)
    return out


@dataclass(frozen=True)
class DirectionStats:
    """Distances from one map's end points to the other map's segments."""

    points: int  # end points in the area
    median_m: float
    p95_m: float
    within_share: float  # share within the tolerance
    max_m: float


@dataclass(frozen=True)
class LineMapComparison:
    """Both directions, and the counts of segments compared."""

    reference_to_map: DirectionStats  # is everything there, in the right place?
    map_to_reference: DirectionStats  # is what was mapped real?
    reference_segments: int  # with at least one end point in the area
    mapped_segments: int  # likewise
    radius_m: float
    tolerance_m: float

    def to_dict(self) -> dict:
        return asdict(self)


def _stats(d: FloatArray, tolerance: float) -> DirectionStats:
    if len(d) == 0:
        return DirectionStats(0, float("nan"), float("nan"), float("nan"), float("nan"))
    with np.errstate(invalid="ignore"):  # infinite distances (nothing on the other side)
        median, p95 = float(np.median(d)), float(np.percentile(d, 95))
    # interpolating between two infinite distances gives NaN: the statistic is infinite
    median, p95 = (math.inf if math.isnan(v) else v for v in (median, p95))
    return DirectionStats(
        int(len(d)),
        median,
        p95,
        float(np.mean(d <= tolerance)),
        float(d.max()),
    )


def compare_line_maps(
    mapped: FloatArray,
    reference: FloatArray,
    path: FloatArray,
    radius: float = 5.0,
    tolerance: float = 0.3,
) -> LineMapComparison:
    """Compare mapped segments (M, 2, 2) with reference segments (R, 2, 2) over the area
    within ``radius`` of ``path`` (T, 2) (positions of the car).

    Returns:
        :class:`LineMapComparison`; a direction with no end point in the area has NaN
        statistics, and with no segments on the other side the distances are infinite.
    """
    m = np.asarray(mapped, dtype=float).reshape(-1, 2, 2)
    r = np.asarray(reference, dtype=float).reshape(-1, 2, 2)
    r_pts, m_pts = r.reshape(-1, 2), m.reshape(-1, 2)
    r_in, m_in = near_path(r_pts, path, radius), near_path(m_pts, path, radius)
    return LineMapComparison(
        reference_to_map=_stats(point_segment_distances(r_pts[r_in], m), tolerance),
        map_to_reference=_stats(point_segment_distances(m_pts[m_in], r), tolerance),
        reference_segments=int(r_in.reshape(-1, 2).any(axis=1).sum()),
        mapped_segments=int(m_in.reshape(-1, 2).any(axis=1).sum()),
        radius_m=float(radius),
        tolerance_m=float(tolerance),
    )


__all__ = [
    "DirectionStats",
    "LineMapComparison",
    "compare_line_maps",
    "near_path",
    "point_segment_distances",
]
