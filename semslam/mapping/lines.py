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
    detections: list[tuple[int, FloatArray, float, float]] = field(default_factory=list)
    # (keyframe, end points (2, 2) in the vehicle frame, width m, sigma across the line m)
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
        """Extend the extent to cover points ``mE`` (N, 2); use LineLandmarks.grow."""
        s = self.along(mE)
        self.s_min, self.s_max = min(self.s_min, float(s.min())), max(self.s_max, float(s.max()))


def end_covariance(covariance: FloatArray, s0: float, s1: float) -> FloatArray:
    """(2, 2) covariance (m^2) of a line's offsets across itself at ``s = s0`` and ``s = s1``
    (its two ends, m along the line from its foot point), given the 2x2 covariance of its
    variable ``(theta, d)`` (rad, m): at ``s`` the across offset ``n(theta) . (p - anchor) -
    d`` has the Jacobian ``[s, -1]``. Anywhere between, the offset is the ends' blended
    linearly (:mod:`semslam.line_uncertainty`)."""
    J = np.array([[s0, -1.0], [s1, -1.0]])
    C = J @ np.asarray(covariance, dtype=float) @ J.T
    return 0.5 * (C + C.T)


def segment_sigma(ends: FloatArray) -> float:
    """RMS over a segment of the 1-sigma (m) of its position across itself, from the
    (2, 2) covariance ``C`` of its across offsets at its two ends (:func:`end_covariance`):
    the mean of ``(1 - t)^2 C_aa + 2 t (1 - t) C_ab + t^2 C_bb`` over ``t`` in [0, 1] is
    ``(C_aa + C_ab + C_bb) / 3``."""
    C = np.asarray(ends, dtype=float)
    return math.sqrt(max(0.0, (C[0, 0] + C[0, 1] + C[1, 1]) / 3.0))


_CELL = 4.0  # m, side of a grid cell of LineLandmarks (10 m: association 10 % slower, same map)


def _cell_range(lo: FloatArray, hi: FloatArray) -> tuple[int, int, int, int]:
    return (math.floor(lo[0] / _CELL), math.floor(lo[1] / _CELL),
            math.floor(hi[0] / _CELL), math.floor(hi[1] / _CELL))


def _cells(cell_range: tuple[int, int, int, int]):
    i0, j0, i1, j1 = cell_range
    return ((i, j) for i in range(i0, i1 + 1) for j in range(j0, j1 + 1))


def fit_line(points: FloatArray) -> tuple[FloatArray, float]:
    """Anchor (centroid) and normal angle of the principal line through ``points`` (N, 2)."""
    points = np.asarray(points, dtype=float)
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre)
    u = vt[0]
    return centre, math.atan2(u[0], -u[1])  # normal = u rotated by -90 deg


class LineLandmarks:
    """All line landmarks of a map being built.

    Association runs for every detection, so the lines are also kept as arrays (one row
    per line, ``_live`` masking dropped and merged ones) and in a grid of ``_CELL`` m
    cells (each live line in every cell its segment's box, widened by the gates, touches):
    a query looks only at the lines in the cells around it, so its cost does not grow with
    the map. Every change goes through the methods here, which keep the rows and the grid
    in step with the objects."""

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
        self._rows = np.zeros((0, 6))  # theta, d, anchor x, anchor y, s_min, s_max
        self._live = np.zeros(0, dtype=bool)
        self._in_graph = np.zeros(0, dtype=bool)
        self._grid: dict[tuple[int, int], set[int]] = {}
        self._cells_of: dict[int, tuple[int, int, int, int]] = {}  # line -> its cell range

    def _sync(self, line: LineLandmark) -> None:
        self._rows[line.index] = (line.theta, line.d, *line.anchor, line.s_min, line.s_max)
        self._live[line.index] = line.merged_into is None
        self._in_graph[line.index] = line.in_graph
        self._file(line)

    def _file(self, line: LineLandmark) -> None:
        """Keep ``line`` in the grid cells its (widened) segment box touches, if live."""
        cells = None
        if line.merged_into is None:
            ends = np.array(line.end_points())
            margin = self.gap + self.distance_gate
            cells = _cell_range(ends.min(axis=0) - margin, ends.max(axis=0) + margin)
        old = self._cells_of.get(line.index)
        if cells == old:
            return
        if old is not None:
            for cell in _cells(old):
                self._grid[cell].discard(line.index)
            del self._cells_of[line.index]
        if cells is not None:
            for cell in _cells(cells):
                self._grid.setdefault(cell, set()).add(line.index)
            self._cells_of[line.index] = cells

    def _filed_near(self, lo: FloatArray, hi: FloatArray) -> FloatArray:
        """Sorted indices of the lines filed in the cells that the box ``lo``-``hi`` touches."""
        found: set[int] = set()
        for cell in _cells(_cell_range(lo, hi)):
            found.update(self._grid.get(cell, ()))
        return np.array(sorted(found), dtype=int)

    def grow(self, index: int, mE: FloatArray) -> None:
        self.items[index].grow(mE)
        self._sync(self.items[index])

    def set_line(self, index: int, theta: float, d: float) -> None:
        line = self.items[index]
        line.theta, line.d = float(theta), float(d)
        self._sync(line)

    def join_graph(self, index: int) -> None:
        self.items[index].in_graph = True
        self._sync(self.items[index])

    def merge(self, keep: int, drop: int) -> None:
        """``drop`` is the same painted line as ``keep``: extents joined, drop retired."""
        self.grow(keep, np.array(self.items[drop].end_points()))
        self.items[drop].merged_into = keep
        self._sync(self.items[drop])

    def near(self, point: FloatArray, radius: float) -> FloatArray:
        """Indices of graph lines whose segment passes within ``radius`` of ``point``."""
        point = np.asarray(point, dtype=float)
        filed = self._filed_near(point - radius, point + radius)
        rows = self._rows[filed]
        n = np.column_stack([np.cos(rows[:, 0]), np.sin(rows[:, 0])])
        u = np.column_stack([-n[:, 1], n[:, 0]])
        foot = rows[:, 2:4] + rows[:, 1:2] * n
        s = np.clip(np.einsum("lk,lk->l", point - foot, u), rows[:, 4], rows[:, 5])
        closest = foot + s[:, None] * u
        close = np.hypot(*(closest - point).T) < radius
        return filed[close & self._live[filed] & self._in_graph[filed]]

    # ------------------------------------------------------------------ association
    def candidates(self, mE: FloatArray) -> list[tuple[int, float]]:
        """Lines a detection with map end points ``mE`` (2, 2) may belong to, with the mean
        distance of its end points from each, nearest first.

        A candidate is live, parallel to the detection within the angle tolerance, has both
        end points within the distance gate across it, and overlaps its extent (plus the
        gap) along it. In Python floats: a few dozen lines are filed near a detection."""
        (ax, ay), (bx, by) = np.asarray(mE, dtype=float).tolist()
        length = math.hypot(bx - ax, by - ay)
        if length < 1e-9:
            return []
        filed = self._filed_near(mE.min(axis=0), mE.max(axis=0))
        if filed.size == 0:
            return []
        ex, ey = (bx - ax) / length, (by - ay) / length  # the detection's direction
        found = []
        for i, live, (theta, d, px, py, s_lo, s_hi) in zip(
            filed.tolist(), self._live[filed].tolist(), self._rows[filed].tolist(), strict=True
        ):
            nx, ny = math.cos(theta), math.sin(theta)  # the line's normal; (-ny, nx) along
            across_a = abs((ax - px) * nx + (ay - py) * ny - d)
            across_b = abs((bx - px) * nx + (by - py) * ny - d)
            fx, fy = px + d * nx, py + d * ny  # foot of the normal from the anchor
            along_a = (ax - fx) * -ny + (ay - fy) * nx
            along_b = (bx - fx) * -ny + (by - fy) * nx
            if (
                live
                and abs(nx * ex + ny * ey) < self.sin_tolerance
                and max(across_a, across_b) < self.distance_gate
                and max(along_a, along_b) >= s_lo - self.gap
                and min(along_a, along_b) <= s_hi + self.gap
            ):
                found.append((i, (across_a + across_b) / 2))
        return sorted(found, key=lambda hit: hit[1])

    def start(self, mE: FloatArray, keyframe: int) -> LineLandmark:
        """A tentative line through one detection."""
        anchor, theta = fit_line(mE)
        line = LineLandmark(len(self.items), anchor, theta, 0.0, 0.0, 0.0, keyframe)
        line.s_min = line.s_max = float(line.along(mE[:1])[0])
        line.grow(mE)
        self.items.append(line)
        self._rows = np.vstack([self._rows, np.zeros((1, 6))])
        self._live = np.append(self._live, True)
        self._in_graph = np.append(self._in_graph, False)
        self._sync(line)
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
        self._sync(line)

    def expire(self, keyframe: int) -> list[LineLandmark]:
        """Forget tentative lines that waited too long; returns them."""
        waiting = np.flatnonzero(self._live & ~self._in_graph)
        gone = [self.items[i] for i in waiting if keyframe - self.items[i].created > self.max_age]
        for line in gone:
            line.merged_into = -1  # dropped: a false or passing detection
            self._sync(line)
        return gone

    def resolve(self, index: int) -> int:
        while self.items[index].merged_into is not None and self.items[index].merged_into >= 0:
            index = self.items[index].merged_into
        return index

    def duplicates(self, near: FloatArray, radius: float) -> list[tuple[int, int]]:
        """Pairs (keep, drop) of graph lines within ``radius`` of ``near`` that are one line:
        parallel, the second one's ends on the first one's line, extents overlapping. Pairs
        are taken greedily in index order, each line in one pair at most."""
        index = self.near(near, radius)
        if index.size < 2:
            return []
        rows = self._rows[index]
        theta, d, anchor = rows[:, 0], rows[:, 1], rows[:, 2:4]
        s_min, s_max = rows[:, 4], rows[:, 5]
        n = np.column_stack([np.cos(theta), np.sin(theta)])
        u = np.column_stack([-n[:, 1], n[:, 0]])
        foot = anchor + d[:, None] * n
        ends = np.stack([foot + s_min[:, None] * u, foot + s_max[:, None] * u], axis=1)  # (k, 2, 2)
        # [i, j, e]: end e of line j measured from line i
        across = ((ends[None] - anchor[:, None, None]) * n[:, None, None]).sum(-1)
        across -= d[:, None, None]
        along = ((ends[None] - foot[:, None, None]) * u[:, None, None]).sum(-1)
        same = (
            (np.abs(np.sin(theta[:, None] - theta[None, :])) <= self.sin_tolerance / 2)
            & (np.abs(across).max(axis=-1) <= self.distance_gate / 2)
            & (along.max(axis=-1) >= s_min[:, None] - self.gap / 2)
            & (along.min(axis=-1) <= s_max[:, None] + self.gap / 2)
        )
        pairs = []
        taken: set[int] = set()
        for i, j in zip(*np.nonzero(np.triu(same, 1)), strict=True):
            a, b = self.items[index[i]], self.items[index[j]]
            if a.index in taken or b.index in taken:
                continue
            keep, drop = (a, b) if len(a.detections) >= len(b.detections) else (b, a)
            pairs.append((keep.index, drop.index))
            taken.update((a.index, b.index))
        return pairs
