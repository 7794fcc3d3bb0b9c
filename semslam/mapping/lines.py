"""Line-marking landmarks of the mapper: bookkeeping and association (no gtsam here).

A painted line is an infinite line ``n(theta) . (p - anchor) = d`` (the graph variable
``(theta, d)``, see :func:`semslam.mapping.factors.marking_observation_residual`) plus an
extent ``[s_min, s_max]`` along its direction ``u = (-sin theta, cos theta)`` from the
foot point ``anchor + d n``, grown from the detections. The anchor is fixed when the line is
created, near the line, so theta and d stay well conditioned anywhere in the map.

A detection (two end points, placed in the map by the current keyframe estimate) belongs
to a line when its direction is within ``angle_tolerance``, both end points lie within
``distance_gate`` of the line, and its extent overlaps the line's extended by ``gap`` (a
detection is often a piece of a long line, clipped by the edge of the top view). A
detection that fits no line starts a tentative line; a tentative line joins the graph
once it has ``min_support`` detections and is forgotten if it has not within
``max_age`` keyframes (false detections come and go). Everything is in the map frame,
metres and radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from semslam.geometry import FloatArray


@dataclass
class LineLandmark:
    """One painted line: its estimate, extent and the detections that saw it."""

    index: int
    anchor: FloatArray
    theta: float
    d: float
    s_min: float
    s_max: float
    created: int  # keyframe
    detections: list[tuple[int, FloatArray, float]] = field(default_factory=list)
    # (keyframe, end points (2, 2) in the vehicle frame, width m)
    in_graph: bool = False
    merged_into: int | None = None

    @property
    def normal(self) -> FloatArray:
        return np.array([math.cos(self.theta), math.sin(self.theta)])

    @property
    def direction(self) -> FloatArray:
        return np.array([-math.sin(self.theta), math.cos(self.theta)])

    def foot(self) -> FloatArray:
        return self.anchor + self.d * self.normal

    def along(self, points: FloatArray) -> FloatArray:
        return (np.asarray(points) - self.foot()) @ self.direction

    def across(self, points: FloatArray) -> FloatArray:
        return (np.asarray(points) - self.anchor) @ self.normal - self.d

    def end_points(self) -> tuple[FloatArray, FloatArray]:
        f, u = self.foot(), self.direction
        return f + self.s_min * u, f + self.s_max * u

    def grow(self, mE: FloatArray) -> None:
        s = self.along(mE)
        self.s_min, self.s_max = min(self.s_min, float(s.min())), max(self.s_max, float(s.max()))


def fit_line(points: FloatArray) -> tuple[FloatArray, float]:
    """Anchor (centroid) and normal angle of the principal line through ``points`` (N, 2)."""
    points = np.asarray(points, dtype=float)
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre)
    u = vt[0]
    return centre, math.atan2(u[0], -u[1])  # normal = u rotated by -90 deg


class LineLandmarks:
    """All line landmarks of a map being built."""

    def __init__(
        self,
        angle_tolerance_deg: float = 5.0,
        distance_gate: float = 0.2,
        gap: float = 1.0,
        min_support: int = 3,
        max_age: int = 20,
    ) -> None:
        self.items: list[LineLandmark] = []
        self.sin_tolerance = math.sin(math.radians(angle_tolerance_deg))
        self.distance_gate = distance_gate
        self.gap = gap
        self.min_support = min_support
        self.max_age = max_age

    # ------------------------------------------------------------------ association
    def candidates(self, mE: FloatArray) -> list[tuple[int, float]]:
        """Lines a detection with map end points ``mE`` (2, 2) may belong to, with the mean
        distance of its end points from each, nearest first."""
        live = [line for line in self.items if line.merged_into is None]
        if not live:
            return []
        theta = np.array([line.theta for line in live])
        d = np.array([line.d for line in live])
        anchor = np.array([line.anchor for line in live])
        lo = np.array([line.s_min for line in live]) - self.gap
        hi = np.array([line.s_max for line in live]) + self.gap
        n = np.column_stack([np.cos(theta), np.sin(theta)])
        u = np.column_stack([-n[:, 1], n[:, 0]])
        seg = mE[1] - mE[0]
        length = float(np.linalg.norm(seg))
        if length < 1e-9:
            return []
        parallel = np.abs(n @ (seg / length)) < self.sin_tolerance
        across = np.abs(np.einsum("lk,elk->el", n, mE[:, None, :] - anchor[None]) - d)  # (2, L)
        foot = anchor + d[:, None] * n
        s = np.einsum("lk,elk->el", u, mE[:, None, :] - foot[None])
        overlap = (s.max(axis=0) >= lo) & (s.min(axis=0) <= hi)
        ok = parallel & (across.max(axis=0) < self.distance_gate) & overlap
        hits = np.flatnonzero(ok)
        cost = across.mean(axis=0)[hits]
        order = np.argsort(cost)
        return [(live[hits[i]].index, float(cost[i])) for i in order]

    def start(self, mE: FloatArray, keyframe: int) -> LineLandmark:
        """A tentative line through one detection."""
        anchor, theta = fit_line(mE)
        line = LineLandmark(len(self.items), anchor, theta, 0.0, 0.0, 0.0, keyframe)
        line.s_min = line.s_max = float(line.along(mE[:1])[0])
        line.grow(mE)
        self.items.append(line)
        return line

    def refit(self, index: int, map_points: FloatArray) -> None:
        """Re-estimate a tentative line from all its end points (map frame)."""
        line = self.items[index]
        anchor, theta = fit_line(map_points)
        if math.cos(theta - line.theta) < 0:  # keep the normal's sense
            theta += math.pi
        line.anchor, line.theta, line.d = anchor, math.remainder(theta, 2 * math.pi), 0.0
        s = line.along(map_points)
        line.s_min, line.s_max = float(s.min()), float(s.max())

    def expire(self, keyframe: int) -> list[LineLandmark]:
        """Forget tentative lines that waited too long; returns them."""
        gone = [
            line
            for line in self.items
            if not line.in_graph
            and line.merged_into is None
            and keyframe - line.created > self.max_age
        ]
        for line in gone:
            line.merged_into = -1  # dropped: a false or passing detection
        return gone

    def resolve(self, index: int) -> int:
        while self.items[index].merged_into is not None and self.items[index].merged_into >= 0:
            index = self.items[index].merged_into
        return index

    def duplicates(self, near: FloatArray, radius: float) -> list[tuple[int, int]]:
        """Pairs (keep, drop) of graph lines within ``radius`` of ``near`` that are one line:
        parallel, each one's ends on the other, extents overlapping."""
        live = [
            line
            for line in self.items
            if line.in_graph and line.merged_into is None and self._near(line, near, radius)
        ]
        pairs = []
        taken: set[int] = set()
        for i, a in enumerate(live):
            for b in live[i + 1 :]:
                if a.index in taken or b.index in taken:
                    continue
                if abs(math.sin(a.theta - b.theta)) > self.sin_tolerance / 2:
                    continue
                ends_b = np.array(b.end_points())
                if np.abs(a.across(ends_b)).max() > self.distance_gate / 2:
                    continue
                s = a.along(ends_b)
                if s.max() < a.s_min - self.gap / 2 or s.min() > a.s_max + self.gap / 2:
                    continue
                keep, drop = (a, b) if len(a.detections) >= len(b.detections) else (b, a)
                pairs.append((keep.index, drop.index))
                taken.update((a.index, b.index))
        return pairs

    @staticmethod
    def _near(line: LineLandmark, point: FloatArray, radius: float) -> bool:
        a, b = line.end_points()
        ab = b - a
        t = np.clip((point - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
        return float(np.linalg.norm(a + t * ab - point)) < radius
