"""The next junction of a row of slots, where its separator is worn away.

Slots in a row are painted at one width, so two neighbouring T junctions of a row (a
slot's entrance, both points T: the entrance line runs on past each) tell where the next
one lies: one slot width further along the entrance, on either side. Real garages wear
their separators away where cars drive over them, most of all at the entrance, and there
the CNNs see a bare entrance line and no junction; a person labelling the view (ps2.0)
still marks the junction, from the row around it. On the real ps2.0 samples this is the
commonest miss the CNNs leave (BENCHMARKS.md, "The next junction of a row").

A point is added one slot width beyond a detected slot when

* both of the slot's points are T junctions (an L ends its row);
* the place is in view: no black (the ego box, padding) within :data:`SEEN_RADIUS_PX` of it,
  and at least :data:`BORDER_PX` from the image's border (ps2.0 labels no point nearer);
* no detected point lies within half a slot width of it.

Its direction is the mean of the pair's, its shape T, its confidence the lower of the
pair's times :data:`ROW_SHARE_RIGHT`. With a verifier, the point is moved as the verifier
places it (its probability is not used: with no separator to see, the verifier is unsure by
design), unless the move is more than :data:`MAX_MOVE_PX`.

Pixels are the top view's (u right, v down), at ps2.0's scale (600 px for 10 m; other
square sizes scale the distances); directions in radians, ``atan2(dv, du)``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from semslam.perception.marking_points import MarkingPoint
from semslam.perception.point_verifier import PointVerifier
from semslam.rig import TOPVIEW_BLACK
from semslam.types import JunctionShape

BORDER_PX = 30.0
"""No point is added nearer the image's border than this (ps2.0 labels none there)."""

SEEN_RADIUS_PX = 12.0
"""No point is added where black (not seen) lies within this of it."""

MAX_MOVE_PX = 15.0
"""A verifier's move of an added point larger than this is not taken."""

ROW_SHARE_RIGHT = 0.8
"""The share of added points that lie on a junction: 10 of 12 on the simulated validation
and test views (1,000) and the real ps2.0 samples together, the two under a parked car left
out; the two wrong ones end a simulated row whose last junction looks like a T. On simulated
views with 30 % of the separators worn away, 104 of 108 (BENCHMARKS.md, "The next junction
of a row"); the lower figure is taken."""


def _seen(topview_bgr: np.ndarray, uv: np.ndarray, radius: int) -> bool:
    """Whether no pixel within ``radius`` (a square) of ``uv`` is black."""
    col, row = int(round(uv[0])), int(round(uv[1]))
    window = topview_bgr[max(0, row - radius): row + radius + 1,
                         max(0, col - radius): col + radius + 1]
    return bool(window.size) and bool((window.max(axis=2) > TOPVIEW_BLACK).all())


def row_completions(
    topview_bgr: np.ndarray,
    points: list[MarkingPoint],
    pairs: list[tuple[int, int]],
    verifier: PointVerifier | None = None,
) -> list[MarkingPoint]:
    """The junctions one slot width beyond each slot of T junctions (see the module).

    Args:
        topview_bgr: uint8 (H, W, 3) top view.
        points: the detected marking points.
        pairs: each detected slot's two point indices into ``points``.
        verifier: moves each added point as it places it; None: not moved.

    Returns:
        The added points (none closer than half a slot width to a detected point or to
        each other).
    """
    h, w = topview_bgr.shape[:2]
    scale = max(h, w) / 600.0
    border = BORDER_PX * scale
    uv = np.array([p.uv for p in points], float).reshape(-1, 2)
    added: list[MarkingPoint] = []
    for i, j in pairs:
        if points[i].shape is not JunctionShape.T or points[j].shape is not JunctionShape.T:
            continue
        for a, b in ((i, j), (j, i)):
            step = uv[b] - uv[a]
            q = uv[b] + step
            if not (border <= q[0] <= w - 1 - border and border <= q[1] <= h - 1 - border):
                continue
            half = 0.5 * float(np.hypot(*step))
            taken = np.vstack([uv, [p.uv for p in added]]) if added else uv
            if np.hypot(*(taken - q).T).min() < half:
                continue
            if not _seen(topview_bgr, q, int(round(SEEN_RADIUS_PX * scale))):
                continue
            da, db = points[a].direction, points[b].direction
            direction = math.atan2(math.sin(da) + math.sin(db), math.cos(da) + math.cos(db))
            confidence = ROW_SHARE_RIGHT * min(points[a].confidence, points[b].confidence)
            added.append(MarkingPoint(q, direction, JunctionShape.T, confidence, from_row=True))
    if verifier is None or not added:
        return added
    _, moved, _ = verifier.verify(
        topview_bgr, np.array([p.uv for p in added]), np.array([p.direction for p in added])
    )
    return [
        replace(p, uv=m) if np.hypot(*(m - p.uv)) <= MAX_MOVE_PX * scale else p
        for p, m in zip(added, moved, strict=True)
    ]


__all__ = ["BORDER_PX", "MAX_MOVE_PX", "ROW_SHARE_RIGHT", "SEEN_RADIUS_PX", "row_completions"]
