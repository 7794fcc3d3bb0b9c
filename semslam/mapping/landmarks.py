"""Slot landmarks while mapping: current corner estimates, label votes, merges, the pool.

Pure bookkeeping in the map frame (numpy, no gtsam): which slots exist, where
their corners are now, which painted IDs their accepted observations read,
and the pool of slots seen too few times to become landmarks yet.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from semslam.geometry import FloatArray
from semslam.types import SlotKind


@dataclass
class SlotLandmark:
    """A mapped slot: ``corners`` (4, 2) map frame (current estimate), ``kind``,
    ``votes`` label -> summed confidence, ``merged_into`` the surviving landmark's index."""

    index: int
    corners: FloatArray
    kind: SlotKind
    votes: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    merged_into: int | None = None

    def best_label(self) -> tuple[str | None, float]:
        """(label, share of the votes it holds); (None, 0) without votes."""
        return best_label(self.votes)


def best_label(votes: dict[str, float]) -> tuple[str | None, float]:
    """(label, share of the votes it holds) of label -> summed confidence; (None, 0)
    without votes."""
    if not votes:
        return None, 0.0
    label = max(votes, key=lambda k: votes[k])
    total = sum(votes.values())
    return label, votes[label] / total if total > 0 else 0.0


LABEL_ALPHABET = 100
"""Labels a misread is spread over in :func:`label_probability`. One reading gives its own
confidence whatever this is; it only weighs readings that disagree."""


def label_probability(
    readings: Iterable[tuple[str, float]], label: str, alphabet: int = LABEL_ALPHABET
) -> float:
    """Probability that a slot's painted ID is ``label``, from its readings.

    Each reading ``(label, confidence)`` is taken as independent, right with its confidence
    and, when wrong, any of the ``alphabet - 1`` other labels alike, over a uniform prior.
    So one reading gives its own confidence, readings that agree add their log-odds, and
    readings of other labels take it away. Confidences are clipped to [0.001, 0.999].

    Returns 0 when ``label`` was never read. An alphabet no larger than the number of
    distinct labels read is taken as one label larger.
    """
    readings = [(read, min(max(float(c), 1e-3), 0.999)) for read, c in readings]
    k = max(int(alphabet), len({read for read, _ in readings}) + 1)
    score: dict[str, float] = defaultdict(float)  # log(likelihood / that of an unread label)
    for read, c in readings:
        score[read] += math.log(c / (1.0 - c)) + math.log(k - 1)
    if label not in score:
        return 0.0
    top = max(max(score.values()), 0.0)
    total = sum(math.exp(v - top) for v in score.values()) + (k - len(score)) * math.exp(-top)
    return math.exp(score[label] - top) / total


def mean_corner_distance(a: FloatArray, b: FloatArray) -> FloatArray:
    """Mean distance between corresponding corners: ``a`` (4, 2), ``b`` (N, 4, 2) -> (N,)."""
    return np.linalg.norm(b - a[None], axis=2).mean(axis=1)


def overlap_ratio(a: FloatArray, b: FloatArray) -> float:
    """Area shared by two convex quadrilaterals (4, 2) over the smaller one's area, in [0, 1].
    Real slots only touch along their edges; a detection overlapping a known slot is a ghost."""
    pa, pb = np.asarray(a, dtype=np.float32), np.asarray(b, dtype=np.float32)
    area_a, area_b = abs(cv2.contourArea(pa)), abs(cv2.contourArea(pb))
    if min(area_a, area_b) <= 1e-9:
        return 0.0
    shared, _ = cv2.intersectConvexConvex(pa, pb)
    return float(shared) / min(area_a, area_b)


_CELL = 4.0  # m, side of the spatial hash cells over landmark centres


class SlotLandmarks:
    """All slot landmarks, with a spatial hash of their centres so that every query
    touches only the neighbourhood (mapping time stays linear in the drive length).
    Merged landmarks stay (their variables do) but are inactive."""

    def __init__(self) -> None:
        self.items: list[SlotLandmark] = []
        self._grid: dict[tuple[int, int], set[int]] = defaultdict(set)
        self._cell: dict[int, tuple[int, int]] = {}

    @staticmethod
    def _cell_of(point: FloatArray) -> tuple[int, int]:
        return int(np.floor(point[0] / _CELL)), int(np.floor(point[1] / _CELL))

    def add(self, corners: FloatArray, kind: SlotKind) -> SlotLandmark:
        landmark = SlotLandmark(len(self.items), np.array(corners, dtype=float), kind)
        self.items.append(landmark)
        self.set_corners(landmark.index, landmark.corners)
        return landmark

    def set_corners(self, index: int, corners: FloatArray) -> None:
        """Move landmark ``index`` to new corner estimates (4, 2)."""
        self.items[index].corners = np.asarray(corners, dtype=float)
        cell = self._cell_of(self.items[index].corners.mean(axis=0))
        old = self._cell.get(index)
        if old != cell:
            if old is not None:
                self._grid[old].discard(index)
            self._grid[cell].add(index)
            self._cell[index] = cell

    def near(self, point: FloatArray, radius: float) -> list[SlotLandmark]:
        """Active landmarks whose centre cell lies within ``radius`` (m) of ``point``."""
        reach = int(np.ceil(radius / _CELL))
        ci, cj = self._cell_of(point)
        out = []
        for i in range(ci - reach, ci + reach + 1):
            for j in range(cj - reach, cj + reach + 1):
                for index in self._grid.get((i, j), ()):
                    if self.items[index].merged_into is None:
                        out.append(self.items[index])
        return sorted(out, key=lambda s: s.index)

    def active(self) -> list[SlotLandmark]:
        return [s for s in self.items if s.merged_into is None]

    def resolve(self, index: int) -> int:
        """Follow merges to the surviving landmark."""
        while self.items[index].merged_into is not None:
            index = self.items[index].merged_into  # type: ignore[assignment]
        return index

    def candidates(
        self,
        corners: FloatArray,
        label: str | None,
        label_confidence: float,
        gate: float,
        id_gate: float,
        id_confidence: float,
        max_candidates: int,
    ) -> list[tuple[int, float, bool]]:
        """Landmarks an observation (map-frame ``corners`` (4, 2)) may belong to.

        Returns (index, mean corner distance, proposed by ID) for the nearest
        active landmarks within ``gate`` and, when the observation's label is
        confident, the landmark holding that label within ``id_gate``.
        """
        nearby = self.near(corners.mean(axis=0), max(gate, id_gate) + 1.0)
        if not nearby:
            return []
        d = mean_corner_distance(corners, np.array([s.corners for s in nearby]))
        order = np.argsort(d, kind="stable")
        out: dict[int, tuple[int, float, bool]] = {}
        for k in order[:max_candidates]:
            if d[k] <= gate:
                out[nearby[k].index] = (nearby[k].index, float(d[k]), False)
        if label is not None and label_confidence >= id_confidence:
            for k in order:
                if d[k] > id_gate:
                    break
                if nearby[k].best_label()[0] == label:
                    out[nearby[k].index] = (nearby[k].index, float(d[k]), True)
                    break
        return sorted(out.values(), key=lambda c: c[1])

    def overlapping(self, corners: FloatArray, threshold: float) -> bool:
        """Does a slot at ``corners`` (4, 2) overlap an active landmark by more than
        ``threshold`` of the smaller area?"""
        return any(
            overlap_ratio(corners, s.corners) > threshold
            for s in self.near(corners.mean(axis=0), 7.0)
        )

    def duplicates(
        self, distance: float, around: FloatArray, radius: float
    ) -> list[tuple[int, int]]:
        """Pairs (keep, drop) of active landmarks within ``radius`` of ``around`` closer than
        ``distance`` to each other whose labels do not contradict each other (equal, or one
        of them without a confident label)."""
        nearby = self.near(around, radius)
        if len(nearby) < 2:
            return []
        stack = np.array([s.corners for s in nearby])
        pairs = []
        taken: set[int] = set()
        for i, a in enumerate(nearby):
            if a.index in taken:
                continue
            votes = defaultdict(float, a.votes)  # a's and those it absorbs here
            d = mean_corner_distance(a.corners, stack[i + 1 :])
            for j in np.flatnonzero(d < distance):
                b = nearby[i + 1 + j]
                if b.index in taken or b.kind != a.kind:
                    continue
                (la, ca), (lb, cb) = best_label(votes), b.best_label()
                if la is not None and lb is not None and la != lb and min(ca, cb) > 0.5:
                    continue
                pairs.append((a.index, b.index))
                taken.add(b.index)
                for label, weight in b.votes.items():
                    votes[label] += weight
        return pairs


@dataclass(eq=False)
class PooledSlot:
    """A slot seen too few times to be a landmark: the map-frame corners of each sighting
    and the sightings themselves (keyframe key, observation index in the audit)."""

    corners: list[FloatArray]
    sightings: list[int]
    kind: SlotKind
    last_keyframe: int

    @property
    def mean_corners(self) -> FloatArray:
        return np.mean(self.corners, axis=0)


_KIND_CODES = {kind: code for code, kind in enumerate(SlotKind)}


class SlotPool:
    """Tentative slots; one becomes a landmark after M consistent sightings (TiEV).

    The pooled slots' mean corners are kept stacked, (N, 4, 2) map frame, so a sighting
    is compared with all of them at once: false detections fill the pool, and a pool of
    N costs one array operation per sighting, not N Python steps (with half the
    detections false a sighting met 84 pooled slots on average, garage seed 1)."""

    def __init__(self, radius: float, max_age: int) -> None:
        self.radius, self.max_age = radius, max_age
        self.items: list[PooledSlot] = []
        self._means = np.empty((0, 4, 2))
        self._kinds = np.empty(0, int)  # index into SlotKind

    def add(self, corners: FloatArray, kind: SlotKind, sighting: int, keyframe: int) -> PooledSlot:
        """Put a sighting in the pool: it joins the pooled slot of its kind whose mean
        corners are nearest (mean corner distance, the first on a tie) if that is within
        ``radius``, else starts one. Returns the pooled slot it joined (or started)."""
        corners = np.array(corners, float)
        d = mean_corner_distance(corners, self._means)
        d[self._kinds != _KIND_CODES[kind]] = np.inf
        nearest = int(np.argmin(d)) if len(d) else -1
        if nearest >= 0 and d[nearest] < self.radius:
            best = self.items[nearest]
        else:
            best = PooledSlot([], [], kind, keyframe)
            self.items.append(best)
            self._kinds = np.append(self._kinds, _KIND_CODES[kind])
            self._means = np.concatenate([self._means, corners[None]])
            nearest = len(self.items) - 1
        best.corners.append(corners)
        best.sightings.append(sighting)
        best.last_keyframe = keyframe
        self._means[nearest] = best.mean_corners
        return best

    def remove(self, item: PooledSlot) -> None:
        self._keep([s is not item for s in self.items])

    def expire(self, keyframe: int) -> None:
        """Forget pooled slots not seen for ``max_age`` keyframes."""
        self._keep([keyframe - s.last_keyframe <= self.max_age for s in self.items])

    def _keep(self, keep: list[bool]) -> None:
        if all(keep):
            return
        self.items = [s for s, k in zip(self.items, keep, strict=True) if k]
        self._kinds = self._kinds[np.asarray(keep, bool)]
        self._means = self._means[np.asarray(keep, bool)]
