"""Stages 5-7 of the detector: centre pixels grown into short straight segments,
segments clustered into lines (principal axis, ends where the paint fades), and each
line's confidence by logistic regression over its features. Pixels: the padded working
image; :class:`MarkingLines` holds the result in image pixels."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from semslam.geometry import FloatArray
from semslam.perception.markings.params import FEATURE_SCALES, FEATURES, MarkingParams
from semslam.types import MarkingObservation


@dataclass(frozen=True, eq=False)
class MarkingLines:
    """Detected lines in image pixels, before conversion to the vehicle frame.

    Attributes:
        a, b: (K, 2) end points, pixels (u right, v down).
        width_px: (K,) painted widths, pixels.
        confidence: (K,) logistic-regression confidence.
        features: (K, len(FEATURES)) unscaled features (for tuning).
        metres_per_px: ground resolution of the pixels.
        centre_px: (u, v) of the vehicle centre.
    """

    a: FloatArray
    b: FloatArray
    width_px: FloatArray
    confidence: FloatArray
    features: FloatArray
    metres_per_px: float
    centre_px: tuple[float, float]

    @staticmethod
    def empty(mpp: float, centre_px: tuple[float, float]) -> MarkingLines:
        z = np.zeros((0, 2))
        return MarkingLines(
            z, z, np.zeros(0), np.zeros(0), np.zeros((0, len(FEATURES))), mpp, centre_px
        )

    def to_vehicle(self, q: FloatArray) -> FloatArray:
        """(N, 2) pixels to vehicle-frame metres (x forward = up, y left)."""
        (cu, cv), s = self.centre_px, self.metres_per_px
        q = np.asarray(q, float).reshape(-1, 2)
        return np.stack([(cv - q[:, 1]) * s, (cu - q[:, 0]) * s], axis=1)

    def observations(self) -> tuple[MarkingObservation, ...]:
        """The lines as :class:`MarkingObservation` (vehicle frame, metres)."""
        va, vb = self.to_vehicle(self.a), self.to_vehicle(self.b)
        s = self.metres_per_px
        return tuple(
            MarkingObservation(va[k], vb[k], float(self.width_px[k] * s), float(self.confidence[k]))
            for k in range(len(va))
        )


def _moments(label: np.ndarray, n_labels: int, pts: np.ndarray, w: np.ndarray | None = None):
    """Per label: count, centroid (K, 2), covariance entries (sxx, sxy, syy)."""
    w = np.ones(len(pts)) if w is None else w
    cnt = np.bincount(label, weights=w, minlength=n_labels)
    safe = np.maximum(cnt, 1e-9)
    mx = np.bincount(label, weights=w * pts[:, 0], minlength=n_labels) / safe
    my = np.bincount(label, weights=w * pts[:, 1], minlength=n_labels) / safe
    dx, dy = pts[:, 0] - mx[label], pts[:, 1] - my[label]
    sxx = np.bincount(label, weights=w * dx * dx, minlength=n_labels) / safe
    sxy = np.bincount(label, weights=w * dx * dy, minlength=n_labels) / safe
    syy = np.bincount(label, weights=w * dy * dy, minlength=n_labels) / safe
    return cnt, np.stack([mx, my], axis=1), sxx, sxy, syy


def _axes(sxx, sxy, syy):
    """Principal direction (K, 2) and the smaller eigenvalue (K,) of 2x2 covariances."""
    ang = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    tr, det = sxx + syy, sxx * syy - sxy * sxy
    lam_min = np.maximum(0.5 * tr - np.sqrt(np.maximum(0.25 * tr * tr - det, 0.0)), 0.0)
    return np.stack([np.cos(ang), np.sin(ang)], axis=1), lam_min


def _extent(label: np.ndarray, n_labels: int, t: np.ndarray):
    lo = np.full(n_labels, np.inf)
    hi = np.full(n_labels, -np.inf)
    np.minimum.at(lo, label, t)
    np.maximum.at(hi, label, t)
    return lo, hi


def _trimmed_fit(label: np.ndarray, n: int, pts: np.ndarray, trim_px: float):
    """Principal axis per label, fitted twice more without the points farther than
    ``trim_px`` from the previous fit (corners and junction spurs drop out). Returns inlier
    mask, counts, centres, directions, residual variance across."""
    cnt, c, sxx, sxy, syy = _moments(label, n, pts)
    inl = np.ones(len(pts), bool)
    for _ in range(2):
        u, _ = _axes(sxx, sxy, syy)
        d = pts - c[label]
        inl = np.abs(d[:, 0] * u[label, 1] - d[:, 1] * u[label, 0]) <= trim_px
        cnt, c, sxx, sxy, syy = _moments(label, n, pts, inl.astype(float))
    u, lam = _axes(sxx, sxy, syy)
    return inl, cnt, c, u, lam


def _grow(pts: np.ndarray, st: dict, p: MarkingParams):
    """Stage 5: segments as straight connected components of the centre-pixel graph.

    Returns a segment label per point (-1: none) and per segment: centre, direction,
    extent along it (lo, hi; px from the centre)."""
    m = len(pts)
    pairs = cKDTree(pts).query_pairs(p.link_radius_px, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    c2, s2 = st["c2"], st["s2"]
    same_o = c2[i] * c2[j] + s2[i] * s2[j] >= math.cos(2.0 * math.radians(p.link_angle_deg))
    th = 0.5 * np.arctan2(s2[i] + s2[j], c2[i] + c2[j])  # mean line direction
    v = pts[j] - pts[i]
    across = np.abs(-v[:, 0] * np.sin(th) + v[:, 1] * np.cos(th))
    S, L = st["S"], st["L"]
    ok = (
        same_o
        & (across <= p.link_offset_px)
        & (np.abs(S[i] - S[j]) <= p.link_width_ratio * np.maximum(S[i], S[j]))
        & (np.abs(L[i] - L[j]) <= p.link_intensity)
    )
    graph = coo_matrix((np.ones(int(ok.sum()), np.int8), (i[ok], j[ok])), shape=(m, m))
    n_lab, label = connected_components(graph, directed=False)
    inl, cnt, centre, u, lam = _trimmed_fit(label, n_lab, pts, p.trim_px)
    t = np.einsum("ij,ij->i", pts - centre[label], u[label])
    lo, hi = _extent(label[inl], n_lab, t[inl])
    good = (hi - lo >= p.min_segment_px) & (np.sqrt(lam) <= p.max_residual_px) & (cnt >= 3)
    new_id = np.cumsum(good) - 1
    seg = np.where(good[label] & inl, new_id[label], -1)
    return seg, centre[good], u[good], lo[good], hi[good]


def _cluster(st: dict, seg: np.ndarray, centre, u, lo, hi, p: MarkingParams, mpp: float):
    """Stage 6: single-link clustering of segments into lines.

    Returns the number of lines, the line of each segment, and all segment end points
    (2K, 2) with their line."""
    k = len(centre)
    sel = seg >= 0
    cnt = np.bincount(seg[sel], minlength=k)
    S = np.bincount(seg[sel], weights=st["S"][sel], minlength=k) / cnt
    L = np.bincount(seg[sel], weights=st["L"][sel], minlength=k) / cnt
    c, d = centre, u
    ea, eb = c + d * lo[:, None], c + d * hi[:, None]
    nrm = np.stack([-d[:, 1], d[:, 0]], axis=1)
    cn = np.einsum("ik,ik->i", c, nrm)[:, None]
    cd = np.einsum("ik,ik->i", c, d)[:, None]
    # [i, j]: segment j's end points across / along segment i's line
    off = np.maximum(np.abs(ea @ nrm.T - cn.T).T, np.abs(eb @ nrm.T - cn.T).T)
    off = np.maximum(off, off.T)
    ta, tb = (ea @ d.T).T - cd, (eb @ d.T).T - cd
    gap = np.maximum(
        0.0, np.maximum(np.minimum(ta, tb) - hi[:, None], lo[:, None] - np.maximum(ta, tb))
    )
    link = (
        (np.abs(d @ d.T) >= math.cos(math.radians(p.cluster_angle_deg)))
        & (off <= p.cluster_offset_m / mpp)
        & (np.minimum(gap, gap.T) <= p.cluster_gap_m / mpp)
        & (np.abs(S[:, None] - S[None, :]) <= p.cluster_width_m / mpp)
        & (np.abs(L[:, None] - L[None, :]) <= p.cluster_intensity)
    )
    n_lines, line_of = connected_components(coo_matrix(link), directed=False)
    return n_lines, line_of, np.concatenate([ea, eb]), np.concatenate([line_of, line_of])


def _bilinear(img: np.ndarray, invalid: np.ndarray, P: np.ndarray):
    """Image values at (..., 2) sub-pixel points and whether each is usable."""
    H, W = img.shape
    x, y = P[..., 0], P[..., 1]
    x0, y0 = np.floor(x).astype(np.intp), np.floor(y).astype(np.intp)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < W - 1) & (y0 < H - 1)
    x0, y0 = np.clip(x0, 0, W - 2), np.clip(y0, 0, H - 2)
    fx, fy = x - x0, y - y0
    v = (
        img[y0, x0] * (1 - fx) * (1 - fy)
        + img[y0, x0 + 1] * fx * (1 - fy)
        + img[y0 + 1, x0] * (1 - fx) * fy
        + img[y0 + 1, x0 + 1] * fx * fy
    )
    return v, ok & ~invalid[y0, x0]


def _extend_ends(free, st_free, cen, dirs, tlo, thi, p: MarkingParams):
    """Stage 6b: each line end runs on through centre points that no segment took (the
    short, ragged pieces where the paint ends, too short to be segments of their own):
    points on the line's axis (within ``trim_px``), of its orientation (within
    ``link_angle_deg``), following the end and each other with gaps of at most
    ``link_radius_px``, up to ``4 * link_radius_px + trim_px`` past the end. ``free``:
    (F, 2) those points; ``st_free``: their statistics."""
    k = len(cen)
    if len(free) == 0 or k == 0:
        return tlo, thi
    sign = np.concatenate([np.ones(k), -np.ones(k)])  # outward along the line: hi, then lo
    line = np.concatenate([np.arange(k), np.arange(k)])
    start = np.concatenate([thi, tlo])
    reach = 4.0 * p.link_radius_px + p.trim_px
    near = cKDTree(free).query_ball_point(cen[line] + dirs[line] * start[:, None], reach)
    end = np.repeat(np.arange(2 * k), [len(n) for n in near])
    if len(end) == 0:
        return tlo, thi
    pt = np.concatenate(near).astype(np.intp)
    li, u = line[end], dirs[line[end]]
    d = free[pt] - cen[li]
    along = sign[end] * (np.einsum("ij,ij->i", d, u) - start[end])  # > 0: past the end
    across = np.abs(d[:, 0] * u[:, 1] - d[:, 1] * u[:, 0])
    c2, s2 = u[:, 0] ** 2 - u[:, 1] ** 2, 2.0 * u[:, 0] * u[:, 1]
    same_o = st_free["c2"][pt] * c2 + st_free["s2"][pt] * s2 >= math.cos(
        2.0 * math.radians(p.link_angle_deg)
    )
    ok = (along > 0.0) & (across <= p.trim_px) & same_o
    end, along = end[ok], along[ok]
    if len(end) == 0:
        return tlo, thi
    order = np.lexsort((along, end))
    end, along = end[order], along[order]
    first = np.r_[True, end[1:] != end[:-1]]
    gap = np.where(first, along, np.diff(along, prepend=0.0))
    broken = np.cumsum(gap > p.link_radius_px)
    broken -= np.maximum.accumulate(np.where(first, broken - (gap > p.link_radius_px), 0))
    kept = broken == 0  # no gap too wide since this end
    reach_out = np.zeros(2 * k)
    np.maximum.at(reach_out, end[kept], along[kept])
    return tlo - reach_out[k:], thi + reach_out[:k]


# steps along the line from a fitted end, outward, in pixels of 1/60 m (the top views')
_END_STEPS = np.arange(-4.0, 10.25, 0.5)
_END_STEP_MPP = 1.0 / 60.0


def _refine_ends(img, invalid, cen, dirs, tlo, thi, floor_level, mpp):
    """Move each end to where the intensity along the centre line falls half way from
    the paint to the floor (the gradient stage stops a blur radius short of the end).
    Ends that meet no such drop within 0.17 m (10 px of a top view), or run into invalid
    pixels, stay. ``mpp``: metres per pixel of ``img``."""
    scale = _END_STEP_MPP / mpp
    s = _END_STEPS * scale
    out = []
    for sign, t in ((-1.0, tlo), (1.0, thi)):
        e = cen + dirs * t[:, None]
        P = e[:, None, :] + (sign * s)[None, :, None] * dirs[:, None, :]
        v, ok = _bilinear(img, invalid, P)
        inside = v[:, s <= -1.0 * scale].mean(axis=1)
        thr = 0.5 * (inside + floor_level)
        below = (v < thr[:, None]) & (s >= -2.0 * scale)[None, :]
        k = below.argmax(axis=1)
        r = np.arange(len(t))
        usable = below.any(axis=1) & (k > 0) & (np.cumsum(~ok, axis=1)[r, k] == 0)
        k = np.maximum(k, 1)
        v0, v1 = v[r, k - 1], v[r, k]
        frac = np.clip((v0 - thr) / np.maximum(v0 - v1, 1e-6), 0.0, 1.0)
        shift = s[k - 1] + frac * (s[k] - s[k - 1])
        out.append(np.where(usable, t + sign * shift, t))
    return out[0], out[1]


def lines_from_centres(
    img: np.ndarray,
    invalid: np.ndarray,
    pts: np.ndarray,
    st: dict,
    p: MarkingParams,
    mpp: float,
    centre_px: tuple[float, float],
) -> MarkingLines:
    """Stages 5-7 on the centre points (``img``: the equalised, smoothed image)."""
    if len(pts) < 3:
        return MarkingLines.empty(mpp, centre_px)
    seg, centre, u, lo, hi = _grow(pts, st, p)
    if len(centre) == 0:
        return MarkingLines.empty(mpp, centre_px)
    n_lines, line_of, ends, end_line = _cluster(st, seg, centre, u, lo, hi, p, mpp)
    sel = seg >= 0
    q, li = pts[sel], line_of[seg[sel]]
    inl, cnt, cen, dirs, lam = _trimmed_fit(li, n_lines, q, p.trim_px)
    t = np.einsum("ij,ij->i", ends - cen[end_line], dirs[end_line])
    tlo, thi = _extent(end_line, n_lines, t)
    if p.extend_ends:
        free = ~sel
        tlo, thi = _extend_ends(
            pts[free], {"c2": st["c2"][free], "s2": st["s2"][free]}, cen, dirs, tlo, thi, p
        )
    w_in = inl.astype(float)

    def mean(v: np.ndarray) -> np.ndarray:
        return np.bincount(li, weights=w_in * v[sel], minlength=n_lines) / np.maximum(cnt, 1)

    tlo, thi = _refine_ends(img, invalid, cen, dirs, tlo, thi, mean(st["F"]), mpp)
    a, b = cen + dirs * tlo[:, None], cen + dirs * thi[:, None]
    length_px = thi - tlo

    mid = 0.5 * (a + b) - np.asarray(centre_px)
    feats = np.stack(
        [
            mean(st["S"]) * mpp,
            mean(st["L"]),
            mean(np.sqrt(st["V"])),
            np.sqrt(lam),
            mean(st["G"]),
            mean(st["C"]),
            mean(st["A"]),
            mean(st["H"]),
            mean(st["R"]),
            mean(st["D"]),
            np.log(np.maximum(length_px * mpp, 0.01) / 0.3),
            cnt / np.maximum(length_px, 1.0),
            np.hypot(mid[:, 0], mid[:, 1]) * mpp,
        ],
        axis=1,
    )
    w = np.asarray(p.weights, float)
    z = w[0] + (feats / FEATURE_SCALES) @ w[1:]
    conf = 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))
    width_m = feats[:, 0]
    keep = (
        (length_px * mpp >= p.min_length_m)
        & (width_m >= p.min_width_m * 0.8)
        & (width_m <= p.max_width_m)
        & (conf >= p.min_confidence)
    )
    order = np.lexsort((a[keep, 1], a[keep, 0], -conf[keep]))
    idx = np.nonzero(keep)[0][order]
    return MarkingLines(a[idx], b[idx], feats[idx, 0] / mpp, conf[idx], feats[idx], mpp, centre_px)


__all__ = ["MarkingLines", "lines_from_centres"]
