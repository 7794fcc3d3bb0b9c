"""Parking slots from marking points, the way DMPR-PS and TiEV pair them.

Two marking points form a slot entrance when

* their distance fits a kind: perpendicular 2.2-3.8 m, slanted 2.2-3.9 m (measured along
  the entrance), parallel 5.5-7.5 m (the simulator draws 5.6-6.4 m, the real ps2.0
  samples 5.7-6.4 m; the lower bound stays above two perpendicular slots, 4.8-5.4 m, so a
  missed middle point does not invent a parallel slot);
* both directions (the separators, into the slot) are roughly perpendicular to the
  entrance (perpendicular, parallel), or parallel to each other at 30-75 deg to it
  (slanted), and point to the same side of it. An L point whose direction runs along
  the entrance toward its partner (the ps2.0 labelling of some end points, DMPR-PS's
  "l_down") takes its partner's separator;
* no third point lies on or near the segment between them.

Depth is a prior per kind (perpendicular 5.0 m, parallel 2.5 m; slanted: a 5.0 m
separator along the points' mean direction), as the simulated garages and ps2.0 have
it. Where two candidates share a point and overlap (the same side of it along the
entrance), the less confident one goes. Corners are ordered entrance-left,
entrance-right, rear-right, rear-left as seen from the aisle looking into the slot
(``[i, j]`` of the ps2.0 / simulator labels are entrance-left, entrance-right).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import cv2
import numpy as np

from semslam.geometry import FloatArray
from semslam.perception.marking_points import MarkingPoint, MarkingPointDetector
from semslam.perception.row_completion import row_completions
from semslam.rig import TopviewSpec
from semslam.types import JunctionShape, SlotKind, SlotObservation


@dataclass(frozen=True)
class SlotRules:
    """Geometry of an acceptable slot (metres, degrees)."""

    perpendicular_width: tuple[float, float] = (2.2, 3.8)
    slanted_width: tuple[float, float] = (2.2, 3.9)
    parallel_width: tuple[float, float] = (5.5, 7.5)
    perpendicular_depth: float = 5.0
    parallel_depth: float = 5.0 / 2.0
    slanted_separator: float = 5.0
    angle_tolerance_deg: float = 15.0  # separator off the expected angle
    slanted_angle_deg: tuple[float, float] = (30.0, 75.0)
    third_point_distance_m: float = 0.5  # from the entrance segment


@dataclass(frozen=True, eq=False)
class DetectedSlot:
    """A slot inferred from two marking points.

    Attributes:
        i, j: indices into the points list of the entrance-left and entrance-right point.
        uv_corners: (4, 2) pixels: entrance-left, entrance-right, rear-right, rear-left.
        kind: perpendicular, parallel or slanted.
        angle_deg: angle between the entrance (left to right) and the separator.
        confidence: in [0, 1], from the points' confidences and the geometric fit.
    """

    i: int
    j: int
    uv_corners: FloatArray
    kind: SlotKind
    angle_deg: float
    confidence: float


def _third_point(uv: list[tuple[float, float]], a: int, b: int, limit_px: float) -> bool:
    """Whether a point other than a, b lies near the open segment a-b."""
    (ax, ay), (bx, by) = uv[a], uv[b]
    ex, ey = bx - ax, by - ay
    length2 = ex * ex + ey * ey
    length = math.sqrt(length2)
    for k, (x, y) in enumerate(uv):
        if k in (a, b):
            continue
        t = ((x - ax) * ex + (y - ay) * ey) / length2
        if 0.0 < t < 1.0 and abs(ex * (y - ay) - ey * (x - ax)) / length < limit_px:
            return True
    return False


def _candidate(
    points: list[MarkingPoint],
    uv: list[tuple[float, float]],
    a: int,
    b: int,
    spec: TopviewSpec,
    rules: SlotRules,
) -> DetectedSlot | None:
    """The slot whose entrance runs from point ``a`` to point ``b``, if they make one.

    Plain floats, not 2-vectors: this runs for every pair of a view's points."""
    (ax, ay), (bx, by) = uv[a], uv[b]
    dist_px = math.hypot(bx - ax, by - ay)
    if dist_px < 1e-6:
        return None
    width = dist_px * spec.metres_per_px
    ex, ey = (bx - ax) / dist_px, (by - ay) / dist_px
    sax, say = math.cos(points[a].direction), math.sin(points[a].direction)
    sbx, sby = math.cos(points[b].direction), math.sin(points[b].direction)
    tol = math.radians(rules.angle_tolerance_deg)
    along = math.cos(tol)
    # an L pointing along the entrance at its partner takes the partner's separator
    a_along = points[a].shape is JunctionShape.L and sax * ex + say * ey > along
    b_along = points[b].shape is JunctionShape.L and -(sbx * ex + sby * ey) > along
    if a_along and b_along:
        return None
    if a_along:
        sax, say = sbx, sby
    if b_along:
        sbx, sby = sax, say
    # both separators on the same side of the entrance line
    side_a, side_b = ex * say - ey * sax, ex * sby - ey * sbx
    if side_a * side_b <= 0.0:
        return None
    kind: SlotKind | None = None
    cos_a, cos_b = sax * ex + say * ey, sbx * ex + sby * ey  # of the angles to the entrance
    perp_err = max(abs(cos_a), abs(cos_b))  # 0 = perpendicular
    if perp_err < math.sin(tol):
        fit_err = math.degrees(math.asin(min(perp_err, 1.0)))
        if rules.perpendicular_width[0] <= width <= rules.perpendicular_width[1]:
            kind = SlotKind.PERPENDICULAR
        elif rules.parallel_width[0] <= width <= rules.parallel_width[1]:
            kind = SlotKind.PARALLEL
    else:
        between = math.degrees(math.acos(min(max(sax * sbx + say * sby, -1.0), 1.0)))
        ang_a = math.degrees(math.acos(min(abs(cos_a), 1.0)))
        ang_b = math.degrees(math.acos(min(abs(cos_b), 1.0)))
        lo, hi = rules.slanted_angle_deg
        if (
            between < rules.angle_tolerance_deg
            and lo <= ang_a <= hi
            and lo <= ang_b <= hi
            and rules.slanted_width[0] <= width <= rules.slanted_width[1]
        ):
            kind = SlotKind.SLANTED
            fit_err = between
    if kind is None:
        return None
    if _third_point(uv, a, b, rules.third_point_distance_m / spec.metres_per_px):
        return None
    sep = np.array([sax + sbx, say + sby])
    sep /= np.linalg.norm(sep)
    # into the slot; left of a viewer facing it, in image coordinates (v down)
    normal = np.array([-ey, ex]) if ex * sep[1] - ey * sep[0] > 0 else np.array([ey, -ex])
    left = np.array([normal[1], -normal[0]])
    el, er = (a, b) if (ax - bx) * left[0] + (ay - by) * left[1] > 0 else (b, a)
    if kind is SlotKind.SLANTED:
        depth_vec = sep * rules.slanted_separator / spec.metres_per_px
    elif kind is SlotKind.PARALLEL:
        depth_vec = normal * rules.parallel_depth / spec.metres_per_px
    else:
        depth_vec = normal * rules.perpendicular_depth / spec.metres_per_px
    pl, pr = np.array(uv[el]), np.array(uv[er])
    corners = np.array([pl, pr, pr + depth_vec, pl + depth_vec])
    if kind is SlotKind.SLANTED:
        entrance = (pr - pl) / dist_px
        angle = math.degrees(math.acos(float(np.clip(entrance @ sep, -1.0, 1.0))))
    else:
        angle = 90.0
    fit = math.exp(-0.5 * (fit_err / rules.angle_tolerance_deg * 2.0) ** 2)
    conf = math.sqrt(points[a].confidence * points[b].confidence) * fit
    return DetectedSlot(el, er, corners, kind, angle, min(max(conf, 0.0), 1.0))


def infer_slots(
    points: list[MarkingPoint],
    spec: TopviewSpec | None = None,
    rules: SlotRules | None = None,
    min_confidence: float = 0.0,
) -> list[DetectedSlot]:
    """Slots from the marking points of one top view, by decreasing confidence.

    Args:
        points: detected (or labelled) marking points, pixels of a ``spec`` image.
        spec: the top-view grid (metres per pixel); default ps2.0.
        rules: widths, depths and angle tolerances; default :class:`SlotRules`.
        min_confidence: slots below this are dropped.
    """
    spec = spec or TopviewSpec()
    rules = rules or SlotRules()
    if len(points) < 2:
        return []
    uv = np.array([np.asarray(p.uv, float) for p in points]).reshape(-1, 2)
    # only pairs as far apart as some kind of slot is wide can be one's entrance (a
    # nanometre's slack: _candidate measures the width again, in its own rounding)
    width = np.hypot(*(uv[None] - uv[:, None]).transpose(2, 0, 1)) * spec.metres_per_px
    wide_enough = np.zeros(width.shape, bool)
    for lo, hi in (rules.perpendicular_width, rules.parallel_width, rules.slanted_width):
        wide_enough |= (width >= lo - 1e-9) & (width <= hi + 1e-9)
    pixels = [(float(u), float(v)) for u, v in uv]
    cands = []
    for a, b in zip(*np.nonzero(np.triu(wide_enough, 1)), strict=True):
        c = _candidate(points, pixels, int(a), int(b), spec, rules)
        if c is not None and c.confidence >= min_confidence:
            cands.append(c)
    cands.sort(key=lambda s: -s.confidence)
    kept: list[DetectedSlot] = []
    for c in cands:
        clash = False
        for k in kept:
            for p, q in ((c.i, c.j), (c.j, c.i)):
                for r, t in ((k.i, k.j), (k.j, k.i)):
                    # sharing a point and leaving it to the same side along the entrance
                    (px, py), (qx, qy), (tx, ty) = pixels[p], pixels[q], pixels[t]
                    if p == r and (qx - px) * (tx - px) + (qy - py) * (ty - py) > 0.0:
                        clash = True
        if not clash:
            kept.append(c)
    return kept


def slot_observation(
    slot: DetectedSlot,
    spec: TopviewSpec | None = None,
    label: str | None = None,
    label_confidence: float = 0.0,
    corner_sigma: float = 0.1,
    corner_sigma_own: tuple[float, float, float, float] | None = None,
    corner_sigma_shared: tuple[float, float, float, float] | None = None,
) -> SlotObservation:
    """``slot`` as a :class:`SlotObservation` with its corners in the vehicle frame (the
    sigmas as :class:`SlotObservation` defines them)."""
    spec = spec or TopviewSpec()
    vCorners = spec.pixel_to_vehicle(slot.uv_corners)
    return SlotObservation(
        vCorners=vCorners,
        kind=slot.kind,
        label=label,
        label_confidence=float(label_confidence) if label is not None else 0.0,
        confidence=float(slot.confidence),
        corner_sigma=float(corner_sigma),
        corner_sigma_own=corner_sigma_own,
        corner_sigma_shared=corner_sigma_shared,
    )


_RAY_STEP_M = 0.05  # sample spacing along the separator rays of refine_depth


def refine_depth(
    topview_bgr: np.ndarray,
    slot: DetectedSlot,
    spec: TopviewSpec | None = None,
    search_deg: float = 8.0,
    step_deg: float = 0.25,
    min_contrast: float = 12.0,
    min_visible_m: float = 1.0,
) -> DetectedSlot | None:
    """``slot`` with its depth direction snapped to the painted separators, or None when
    they cannot be measured in this image.

    The CNN's direction is good to a few degrees on the whole, but for slanted junctions
    (the slot's depth direction) 9-12 deg off at the median on the demo drives, which at a
    5 m separator moves the rear corners by most of a metre. From both entrance points,
    the paint brightness ((R + G) / 2, white or yellow) is averaged along rays at angles
    within ``search_deg`` of the slot's depth direction (0.25-3 m); the two separators are
    parallel, so their profiles add. Only angles at which both rays have at least
    ``min_visible_m`` inside the image count: a slot cut by the image border shows too
    little of its separators, and the border itself then wins (measured on the demo
    drives: with 1 m, 6 of 224 kept slanted slots ended more than 5 deg off; without
    the rule, 88 of 386). The brightest angle wins if it stands ``min_contrast`` grey
    levels above the median angle (a painted line, not floor). None if no angle has the
    rays in view or none stands out. The rear corners move, the entrance stays; a slot's
    kind and width are kept.
    """
    spec = spec or TopviewSpec()
    c = np.asarray(slot.uv_corners, float)
    depth_vec = c[3] - c[0]
    depth = float(np.hypot(*depth_vec))
    if depth < 1e-6:
        return slot
    h, w = topview_bgr.shape[:2]
    base = math.atan2(depth_vec[1], depth_vec[0])
    angles = base + np.radians(np.arange(-search_deg, search_deg + 1e-9, step_deg))
    t = np.arange(0.25, min(3.0, depth * spec.metres_per_px), _RAY_STEP_M) / spec.metres_per_px
    score = np.zeros(len(angles))
    counts = np.zeros(len(angles))
    in_view = np.ones(len(angles), bool)  # both rays show min_visible_m
    for start in c[:2]:
        u = start[0] + np.cos(angles)[:, None] * t[None, :]
        v = start[1] + np.sin(angles)[:, None] * t[None, :]
        inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        bgr = cv2.remap(topview_bgr, u.astype(np.float32), v.astype(np.float32), cv2.INTER_LINEAR)
        paint = (bgr[..., 1].astype(np.float32) + bgr[..., 2]) / 2.0  # only the rays' pixels
        score += np.where(inside, paint, 0.0).sum(axis=1)
        counts += inside.sum(axis=1)
        in_view &= inside.sum(axis=1) * _RAY_STEP_M >= min_visible_m
    if not in_view.any():
        return None
    profile = np.where(in_view, score / np.maximum(counts, 1), -np.inf)
    best = int(np.argmax(profile))
    floor = float(np.median(profile[in_view]))
    if profile[best] - floor < min_contrast:
        return None
    # a wide line is as bright over a small range of angles: take the middle of the top
    top = profile >= profile[best] - 0.2 * (profile[best] - floor)
    lo = hi = best
    while lo > 0 and top[lo - 1]:
        lo -= 1
    while hi < len(top) - 1 and top[hi + 1]:
        hi += 1
    a = float(angles[lo : hi + 1].mean())
    new_vec = np.array([math.cos(a), math.sin(a)]) * depth
    corners = np.array([c[0], c[1], c[1] + new_vec, c[0] + new_vec])
    angle = slot.angle_deg
    if slot.kind is SlotKind.SLANTED:  # the angle between entrance and the new separators
        entrance = (c[1] - c[0]) / max(float(np.hypot(*(c[1] - c[0]))), 1e-9)
        angle = math.degrees(math.acos(float(np.clip(entrance @ new_vec / depth, -1.0, 1.0))))
    return DetectedSlot(slot.i, slot.j, corners, slot.kind, angle, slot.confidence)


class SlotDetector:
    """Marking points (the CNN) and the slots they form, for one top view at a time.

    The slots' pixel geometry assumes the top view's scale ``spec.metres_per_px``
    (ps2.0: 1/60 m per px); non-square images are handled by the point detector.
    ``model_path``, ``threshold``, ``verify``, ``verifier_path`` and ``check_entrance`` go
    to :class:`MarkingPointDetector` (``verify=False``: the grid's points without the
    verifier's second look; ``check_entrance=False``: bare line ends kept).
    ``complete_rows``: add the junction one slot width beyond each slot of two T
    junctions where the CNNs see none (:mod:`semslam.perception.row_completion`; a worn
    separator), and infer the slots again with it.
    """

    def __init__(
        self,
        model_path: str | os.PathLike[str] | None = None,
        threshold: float | None = None,
        spec: TopviewSpec | None = None,
        rules: SlotRules | None = None,
        verify: bool = True,
        verifier_path: str | os.PathLike[str] | list | tuple | None = None,
        check_entrance: bool = True,
        complete_rows: bool = True,
    ) -> None:
        self.complete_rows = complete_rows
        self.points = MarkingPointDetector(
            model_path, threshold, verify, verifier_path, check_entrance
        )
        self.spec = spec or TopviewSpec()
        self.rules = rules or SlotRules()

    def detect(self, topview_bgr: np.ndarray) -> tuple[list[MarkingPoint], list[DetectedSlot]]:
        """The marking points and slots of one uint8 BGR top view."""
        pts = self.points.detect(topview_bgr)
        slots = infer_slots(pts, self.spec, self.rules)
        if self.complete_rows and slots:
            added = row_completions(
                topview_bgr, pts, [(s.i, s.j) for s in slots], self.points.verifier
            )
            if added:
                pts = pts + added
                slots = infer_slots(pts, self.spec, self.rules)
        # perpendicular and parallel slots take their depth from the entrance line (good
        # to about a degree); slanted ones from the CNN's directions: snap those to paint,
        # and drop the ones whose separators this view does not show (refine_depth)
        out = []
        for s in slots:
            if s.kind is SlotKind.SLANTED:
                s = refine_depth(topview_bgr, s, self.spec, search_deg=20.0)
            if s is not None:
                out.append(s)
        return pts, out


__all__ = [
    "DetectedSlot",
    "SlotDetector",
    "SlotRules",
    "infer_slots",
    "refine_depth",
    "slot_observation",
]
