"""Line markings of the map: many marking observations in the map frame merged into lines.

Input: every marking observation of a drive, already placed in the map frame
by the optimised keyframe poses, as end points ``(N, 2, 2)`` with widths and
detector confidences. An observation is the part of a painted line inside one
top view, so a clipped end is not an end of the paint: only the extremes of
many observations of the same line are.

Algorithm:

1. Drop observations below ``min_confidence`` (and degenerate, zero-length ones).
2. Cluster single-link: two segments join when their undirected directions
   differ by less than ``angle_tolerance``, the midpoint of each lies within
   ``offset_tolerance`` of the other's line, and their projections on the
   common (bisector) direction overlap or leave a gap below ``gap``.
   Neighbours come from a grid, never from all pairs: each segment is
   registered in two overlapping direction bins (of width >= the angle
   tolerance) and, in each bin's rotated frame, in the along x lateral cells
   that its line covers over its extent lengthened by about half the gap, widened
   by the offset tolerance; two segments that may join always share a cell.
   Inside each cell the segments, sorted by lateral position, are tested
   against their next few neighbours; then, once the components of those
   links are known, every pair sharing a cell but lying in different
   components is tested. So the components are exactly those of the rule over
   all pairs, while same-line observations (the bulk: a line is seen by tens
   of frames) cost a few tests each instead of all their pairs.
3. A cluster with at least ``min_support`` observations gives its lines. The
   direction is the principal axis of all its end points weighted by
   confidence. Along it, the lines are the stretches covered by at least two
   of the cluster's observations, joined across holes up to ``gap``: a single
   false segment that happened to chain two collinear lines (stubs 1.5 m
   apart, say) covers the hole between them once only, so they come out
   apart again (each refitted on its own end points). Outward, a line keeps
   the tail seen once only (the last view before the paint left the top view)
   but not a segment beyond a hole in the coverage. A line's extent runs
   between the end point projections at both extremes, taken robustly: start
   at the smallest (largest) projection, or at the 2nd (98th) percentile for
   clusters with many end points (a stray false segment cannot stretch the
   line), and twice move to the median of the end points within
   ``offset_tolerance`` of it. The real ends pile up there (every unclipped
   view ends at the paint's end), and the median of that pile is not biased
   outward by the noise as a plain minimum would be. The width is the median
   width of the observations overlapping the line.
4. Lines shorter than ``min_length`` are dropped; the rest come sorted by
   their ``a`` end point, ``a`` being the end with the smaller x (y on ties).

Everything is in the map frame, metres; numpy and scipy only.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from semslam.geometry import FloatArray
from semslam.types import Marking

IntArray = np.ndarray

_ALONG_CELL = 1.0  # m, cell side along a direction bin's axis
_LATERAL_CELL = 0.25  # m, cell side across it
_WINDOW = 3  # first pass: each segment tested against its next few in a cell
_TRIM = 0.02  # share of end points skipped at each extreme of a big cluster
_TRIM_FROM = 50  # end points from which a cluster's extremes are trimmed
_SEEN = 2  # a line is where at least this many of its cluster's observations overlap
_CHUNK = 2_000_000  # pairs tested at once (bounds the memory)
_MIN_SEGMENT = 1e-9  # m, shorter observations have no direction
_EPS = 1e-9  # m, slack of zone bounds that sit on an end point


def merge_marking_observations(
    segments: FloatArray,
    widths: FloatArray,
    confidences: FloatArray,
    *,
    angle_tolerance_deg: float = 5.0,
    offset_tolerance: float = 0.10,
    gap: float = 0.5,
    min_support: int = 3,
    min_length: float = 0.5,
    min_confidence: float = 0.3,
) -> tuple[Marking, ...]:
    """Merge map-frame marking observations into line markings (see the module docstring).

    Args:
        segments: (N, 2, 2) end points ``a``, ``b`` of each observation, map frame, m.
        widths: (N,) painted line widths, m.
        confidences: (N,) detector confidences in [0, 1].
        angle_tolerance_deg: largest direction difference (undirected) of joined segments.
        offset_tolerance: largest distance of a segment's midpoint from a joined one's line, m.
        gap: largest gap between joined segments along their common direction, m.
        min_support: fewest observations that make a line.
        min_length: shortest line kept, m.
        min_confidence: observations below it are ignored.

    Returns:
        The merged lines, sorted by their ``a`` end point.
    """
    seg = np.asarray(segments, dtype=float)
    width = np.asarray(widths, dtype=float)
    conf = np.asarray(confidences, dtype=float)
    if seg.size == 0 and width.size == 0 and conf.size == 0:
        return ()
    if seg.ndim != 3 or seg.shape[1:] != (2, 2):
        raise ValueError(f"segments must have shape (N, 2, 2), got {seg.shape}")
    n = seg.shape[0]
    if width.shape != (n,):
        raise ValueError(f"widths must have shape ({n},), got {width.shape}")
    if conf.shape != (n,):
        raise ValueError(f"confidences must have shape ({n},), got {conf.shape}")
    if not (np.all(np.isfinite(seg)) and np.all(np.isfinite(width)) and np.all(np.isfinite(conf))):
        raise ValueError("segments, widths and confidences must be finite")
    if not 0.0 < angle_tolerance_deg <= 30.0:
        raise ValueError(f"angle_tolerance_deg must be in (0, 30], got {angle_tolerance_deg}")
    if offset_tolerance <= 0.0 or gap < 0.0 or min_length < 0.0 or min_support < 1:
        raise ValueError("offset_tolerance must be > 0, gap and min_length >= 0, min_support >= 1")

    d = seg[:, 1] - seg[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    keep = (conf >= min_confidence) & (length > _MIN_SEGMENT)
    if not np.any(keep):
        return ()
    seg, width, conf = seg[keep], width[keep], conf[keep]
    rule = _Rule(seg, math.radians(angle_tolerance_deg), offset_tolerance, gap)
    labels = rule.components()
    return _fit_lines(seg, width, conf, labels, min_support, min_length, offset_tolerance, gap)


class _Rule:
    """The join rule on one set of segments, and its single-link components."""

    def __init__(self, seg: FloatArray, angle_tol: float, offset: float, gap: float) -> None:
        self.seg = seg
        self.n = seg.shape[0]
        d = seg[:, 1] - seg[:, 0]
        self.u = d / np.hypot(d[:, 0], d[:, 1])[:, None]
        self.mid = seg.mean(axis=1)
        # contiguous copies: the pair tests gather from these
        self.ux, self.uy = self.u[:, 0].copy(), self.u[:, 1].copy()
        self.mx, self.my = self.mid[:, 0].copy(), self.mid[:, 1].copy()
        self.ax, self.ay = seg[:, 0, 0].copy(), seg[:, 0, 1].copy()
        self.bx, self.by = seg[:, 1, 0].copy(), seg[:, 1, 1].copy()
        self.angle_tol, self.cos_tol = angle_tol, math.cos(angle_tol)
        self.offset, self.gap = offset, gap

    # -- the rule
    def compatible(self, i: IntArray, j: IntArray) -> np.ndarray:
        """Boolean mask: which pairs (i[k], j[k]) join."""
        out = np.empty(i.size, dtype=bool)
        for s in range(0, i.size, _CHUNK):
            out[s : s + _CHUNK] = self._compatible(i[s : s + _CHUNK], j[s : s + _CHUNK])
        return out

    def _compatible(self, i: IntArray, j: IntArray) -> np.ndarray:
        uxi, uyi, uxj, uyj = self.ux[i], self.uy[i], self.ux[j], self.uy[j]
        dot = uxi * uxj + uyi * uyj
        dx, dy = self.mx[j] - self.mx[i], self.my[j] - self.my[i]
        ok = np.abs(dot) > self.cos_tol
        ok &= np.abs(uxi * dy - uyi * dx) < self.offset
        ok &= np.abs(uxj * dy - uyj * dx) < self.offset
        sign = np.where(dot < 0.0, -1.0, 1.0)
        cx, cy = uxi + sign * uxj, uyi + sign * uyj  # common direction, not normalised
        norm = np.hypot(cx, cy)
        pa_i = self.ax[i] * cx + self.ay[i] * cy
        pb_i = self.bx[i] * cx + self.by[i] * cy
        pa_j = self.ax[j] * cx + self.ay[j] * cy
        pb_j = self.bx[j] * cx + self.by[j] * cy
        lo = np.maximum(np.minimum(pa_i, pb_i), np.minimum(pa_j, pb_j))
        hi = np.minimum(np.maximum(pa_i, pb_i), np.maximum(pa_j, pb_j))
        ok &= lo - hi < self.gap * norm
        return ok

    # -- neighbours
    def cells(self) -> tuple[IntArray, IntArray, FloatArray]:
        """Grid registrations sorted by cell: (cell key, segment, lateral position), each (R,).

        Two segments that may join share at least one cell (see the module docstring).
        """
        n_bins = int(math.floor(math.pi / self.angle_tol))
        bin_width = math.pi / n_bins  # >= the tolerance: joinable segments sit in adjacent bins
        tilt = 1.5 * bin_width  # largest angle between a segment and a bin axis it registers in
        # half the longest along-axis gap between joinable segments, and the lateral margin
        o_far = self.offset / math.cos(self.angle_tol)
        reach = self.gap + o_far + self.gap * math.tan(self.angle_tol / 2.0)
        extend = 0.5 * reach * 1.01 + 1e-6
        margin = 0.5 * self.offset / math.cos(tilt) * 1.01 + 1e-6
        theta = np.mod(np.arctan2(self.u[:, 1], self.u[:, 0]), math.pi)
        k = np.minimum(np.floor(theta / bin_width).astype(np.int64), n_bins - 1)
        seg_r = np.concatenate([np.arange(self.n), np.arange(self.n)])
        bin_r = np.concatenate([k, (k + 1) % n_bins])
        phi = (bin_r + 0.5) * bin_width
        ax = np.stack([np.cos(phi), np.sin(phi)], axis=1)
        nx = np.stack([-ax[:, 1], ax[:, 0]], axis=1)
        ends = self.seg[seg_r]  # (R, 2, 2)
        s_e = np.einsum("rkc,rc->rk", ends, ax)
        y_e = np.einsum("rkc,rc->rk", ends, nx)
        slope = (y_e[:, 1] - y_e[:, 0]) / (s_e[:, 1] - s_e[:, 0])  # |tilt| <= 45 deg
        s0, y0 = s_e[:, 0], y_e[:, 0]
        lo = s_e.min(axis=1) - extend
        hi = s_e.max(axis=1) + extend
        # along cells
        ia0 = np.floor(lo / _ALONG_CELL).astype(np.int64)
        ia1 = np.floor(hi / _ALONG_CELL).astype(np.int64)
        r, ia = _expand(ia0, ia1 - ia0 + 1)
        sa = np.maximum(lo[r], ia * _ALONG_CELL)
        sb = np.minimum(hi[r], (ia + 1) * _ALONG_CELL)
        ya = y0[r] + slope[r] * (sa - s0[r])
        yb = y0[r] + slope[r] * (sb - s0[r])
        yc = 0.5 * (ya + yb)
        il0 = np.floor((np.minimum(ya, yb) - margin) / _LATERAL_CELL).astype(np.int64)
        il1 = np.floor((np.maximum(ya, yb) + margin) / _LATERAL_CELL).astype(np.int64)
        q, il = _expand(il0, il1 - il0 + 1)
        ia, rr = ia[q], r[q]
        span_a = int(ia.max() - ia.min()) + 1
        span_l = int(il.max() - il.min()) + 1
        key = (bin_r[rr] * span_a + (ia - ia.min())) * span_l + (il - il.min())
        y = yc[q]
        order = np.lexsort((y, key))
        return key[order], seg_r[rr][order], y[order]

    def components(self) -> IntArray:
        """(N,) label of each segment's single-link cluster."""
        key, seg, _ = self.cells()
        # pass 1: a few neighbours in lateral order inside each cell
        pi, pj = [], []
        for w in range(1, _WINDOW + 1):
            same = np.flatnonzero(key[:-w] == key[w:])
            pi.append(seg[same])
            pj.append(seg[same + w])
        i, j = _unique_pairs(np.concatenate(pi), np.concatenate(pj), self.n)
        ok = self.compatible(i, j)
        links_i, links_j = [i[ok]], [j[ok]]
        labels = _label(self.n, links_i[0], links_j[0])
        # pass 2: every pair sharing a cell across the components of pass 1
        lab = labels[seg]
        order = np.lexsort((lab, key))
        key, seg, lab = key[order], seg[order], lab[order]
        new_group = np.r_[True, key[1:] != key[:-1]]
        new_run = new_group | np.r_[True, lab[1:] != lab[:-1]]
        group_end = _run_ends(new_group)
        run_end = _run_ends(new_run)
        p, partner = _expand(run_end, group_end - run_end)
        if p.size:
            i, j = _unique_pairs(seg[p], seg[partner], self.n)
            ok = self.compatible(i, j)
            links_i.append(i[ok])
            links_j.append(j[ok])
            labels = _label(self.n, np.concatenate(links_i), np.concatenate(links_j))
        return labels


def _expand(start: IntArray, count: IntArray) -> tuple[IntArray, IntArray]:
    """For each k, the values start[k] .. start[k] + count[k] - 1: (owner k, value) arrays."""
    count = np.maximum(count, 0)
    owner = np.repeat(np.arange(count.size), count)
    offsets = np.cumsum(count) - count
    return owner, start[owner] + (np.arange(owner.size) - offsets[owner])


def _run_ends(starts: np.ndarray) -> IntArray:
    """For a boolean 'a run starts here' array: the index one past the end of each element's run."""
    idx = np.flatnonzero(starts)
    ends = np.r_[idx[1:], starts.size]
    return ends[np.cumsum(starts) - 1]


def _unique_pairs(i: IntArray, j: IntArray, n: int) -> tuple[IntArray, IntArray]:
    """Distinct unordered pairs of different segments."""
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    code = np.sort(lo[lo != hi] * n + hi[lo != hi])
    code = code[np.r_[True, code[1:] != code[:-1]]] if code.size else code
    return code // n, code % n


def _label(n: int, i: IntArray, j: IntArray) -> IntArray:
    graph = coo_matrix((np.ones(i.size, dtype=np.int8), (i, j)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _robust_extreme(t_sorted: FloatArray, band: float, from_top: bool) -> float:
    """The end of a line from its sorted end point projections (module docstring, step 3)."""
    n = t_sorted.size
    k = int(_TRIM * n) if n >= _TRIM_FROM else 0
    centre = float(t_sorted[n - 1 - k] if from_top else t_sorted[k])
    for _ in range(2):
        lo = int(np.searchsorted(t_sorted, centre - band, side="left"))
        hi = int(np.searchsorted(t_sorted, centre + band, side="right"))
        if hi > lo:
            near = t_sorted[lo:hi]
            centre = 0.5 * float(near[(near.size - 1) // 2] + near[near.size // 2])
    return centre


def robust_extent(t: FloatArray, band: float = 0.10) -> tuple[float, float]:
    """Where a line starts and ends along its direction, from the projections ``t`` (m) of
    its observations' end points: at each extreme the median of the end points piled
    within ``band`` m of it, after skipping the outermost 2 % of big sets (step 3 of the
    module docstring). Every unclipped view ends at the paint's end, so the real ends pile
    up; a plain minimum / maximum would follow the noisiest or a stray observation."""
    ts = np.sort(np.asarray(t, dtype=float).ravel())
    return _robust_extreme(ts, band, from_top=False), _robust_extreme(ts, band, from_top=True)


def _principal_axis(pts: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weighted centre and unit principal direction (x >= 0) of points (M, 2)."""
    total = w.sum()
    w = w / total if total > 0 else np.full(w.size, 1.0 / w.size)
    centre = w @ pts
    q = pts - centre
    cxx, cxy, cyy = w @ (q[:, 0] ** 2), w @ (q[:, 0] * q[:, 1]), w @ (q[:, 1] ** 2)
    angle = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)
    return centre, np.array([math.cos(angle), math.sin(angle)])


def _zones(lo: FloatArray, hi: FloatArray, seen: int, gap: float, band: float):
    """Where along a cluster's line its lines lie, from the observations' intervals [lo, hi].

    Stretches covered by at least ``seen`` observations, joined across holes up to
    ``gap``, are the lines; each gets the zone from which its end points are taken:
    up to ``band`` past an inner stretch end and, at the cluster's two ends, out to
    where the coverage first stops (a view's clipped tail is seen once only and
    still counts; a segment beyond a hole does not).
    """
    x = np.concatenate([lo, hi])
    step = np.concatenate([np.ones(lo.size), -np.ones(hi.size)])
    order = np.argsort(x, kind="stable")  # starts before ends at ties: touching is no hole
    x, cover = x[order], np.cumsum(step[order])[:-1]
    strong = np.flatnonzero((cover >= seen) & (x[1:] > x[:-1]))
    if strong.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(strong) > 1)
    first = strong[np.r_[0, breaks + 1]]
    last = strong[np.r_[breaks, strong.size - 1]]
    runs = [[float(x[f]), float(x[g + 1])] for f, g in zip(first, last, strict=True)]
    stretches = [runs[0]]
    for a, b in runs[1:]:
        if a - stretches[-1][1] <= gap:
            stretches[-1][1] = b
        else:
            stretches.append([a, b])
    zones = [[a - band, b + band] for a, b in stretches]
    holes = np.flatnonzero(cover < 1)
    before, after = holes[holes < first[0]], holes[holes > last[-1]]
    zones[0][0] = float(x[before[-1] + 1]) - _EPS if before.size else -math.inf
    zones[-1][1] = float(x[after[0]]) + _EPS if after.size else math.inf
    return zones


def _fit_lines(
    seg: FloatArray,
    width: FloatArray,
    conf: FloatArray,
    labels: IntArray,
    min_support: int,
    min_length: float,
    band: float,
    gap: float,
) -> tuple[Marking, ...]:
    support = np.bincount(labels)
    keep = support[labels] >= min_support
    if not np.any(keep):
        return ()
    seg, width, conf, labels = seg[keep], width[keep], conf[keep], labels[keep]
    order = np.argsort(labels, kind="stable")
    seg, width, conf, labels = seg[order], width[order], conf[order], labels[order]
    starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
    ends = np.r_[starts[1:], labels.size]
    seen = min(_SEEN, min_support)
    out = []
    for s, e in zip(starts, ends, strict=True):
        pts = seg[s:e].reshape(-1, 2)
        w = np.repeat(conf[s:e], 2)
        centre, direction = _principal_axis(pts, w)
        t = (pts - centre) @ direction
        lo, hi = np.minimum(t[0::2], t[1::2]), np.maximum(t[0::2], t[1::2])
        zones = _zones(lo, hi, seen, gap, band)
        for z0, z1 in zones:
            members = (hi >= z0) & (lo <= z1)
            if np.count_nonzero(members) < min_support:
                continue
            inside = (t >= z0) & (t <= z1)
            c, u = (centre, direction)
            if len(zones) > 1:
                c, u = _principal_axis(pts[inside], w[inside])
            tz = np.sort((pts[inside] - c) @ u)
            t0 = _robust_extreme(tz, band, from_top=False)
            t1 = _robust_extreme(tz, band, from_top=True)
            if t1 - t0 < min_length:
                continue
            a, b = c + t0 * u, c + t1 * u
            if (b[0], b[1]) < (a[0], a[1]):
                a, b = b, a
            out.append(Marking(a, b, float(np.median(width[s:e][members]))))
    out.sort(key=lambda m: (m.a[0], m.a[1], m.b[0], m.b[1]))
    return tuple(out)


__all__ = ["merge_marking_observations", "robust_extent"]
