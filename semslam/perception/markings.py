"""Painted line markings in top views: Houben's classical detector, vectorised.

The stages (Houben et al. 2016, ``../shared/DESIGN.md``, "Houben"):

1. presegmentation (optional): only pixels near the map's markings, given as segments
   in the vehicle frame around the predicted pose, are looked at;
2. contrast equalisation (CLAHE) of the marking channel ``(R + G) / 2`` (white and
   yellow paint are both bright there; green or grey floors are not);
3. gradients (Sobel on a Gaussian-smoothed image) and non-maximum suppression along
   the gradient;
4. symmetry: from every edge pixel, walk along its gradient (into the brighter side)
   up to the largest line width and pair it with the first pixel whose gradient is
   opposite (within ``pair_angle_deg`` of pi) and a local maximum; pairs whose floor
   samples beside the line are not darker by ``min_contrast``, differ from each other
   (``max_asymmetry``) or from the view's floor (``max_floor_dev``) are dropped; at the
   pair's centre pixel keep the means of the intensity between the pair ``L``, its
   variance ``V``, the gradient strength ``G``, the width ``S`` and the orientation
   ``O`` (plus contrast, asymmetry, colour and floor level);
5. region growing into short segments: neighbouring centre pixels (within
   ``link_radius_px``: the gap the penalty counter forgives) are joined when their
   ``O``, ``S`` and ``L`` agree and the step runs along the line; the connected
   components of that graph are the segments (all pixels at once instead of one seed
   at a time), fitted by their principal axis twice without outliers, straight ones kept;
6. single-link clustering of segments into lines (angle, offset across, gap along,
   width, intensity); a line is the principal axis of its centre points, its ends the
   extreme end points of its segments projected onto it, then moved to where the
   intensity along the line falls half way to the floor (the gradients stop short);
7. confidence: logistic regression over the line's features (:data:`FEATURES`).

Pixels are OpenCV's (u right, v down, centres at integers); results are in the
vehicle frame (x forward, y left, metres) through :class:`~semslam.rig.TopviewSpec`.
The parameters (:data:`TUNED`, the defaults) were tuned with CMA-ES on simulated top
views by ``tools/tune_markings.py``; the benchmark is ``benchmarks/bench_markings.py``.
Semantic masks of the line class (:meth:`MarkingDetector.detect_mask`) are resampled to
the top views' resolution and run through stages 3-7 with :data:`MASK_PARAMS`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from semslam.errors import SemslamError
from semslam.geometry import FloatArray
from semslam.rig import TopviewSpec
from semslam.types import MarkingObservation

# features of a line, in this order, each divided by its scale before the regression
FEATURES = (
    "width_m",  # S: mean painted width
    "intensity",  # L: mean equalised intensity between the pairs (0-255)
    "std",  # sqrt(V): mean spread of the intensity between the pairs
    "residual_px",  # O: RMS distance of the centre points from the fitted line
    "gradient",  # G: mean edge strength (intensity per pixel)
    "contrast",  # L minus the brighter of the two floor samples beside the line
    "asymmetry",  # difference between the two floor samples (cars, walls: large)
    "chroma",  # B - (R + G) / 2 between the pair (white paint: about 0, yellow: negative)
    "red_green",  # |R - G| between the pair (white and yellow paint: small)
    "floor_dev",  # the floor samples' distance from the view's median (car bodies: large)
    "log_length",  # log of the length on the ground over 0.3 m
    "fill",  # centre pixels per pixel of length (gaps lower it)
    "distance_m",  # distance of the line's middle from the vehicle centre
)
FEATURE_SCALES = np.array(
    [0.1, 255.0, 30.0, 1.0, 50.0, 50.0, 50.0, 50.0, 50.0, 50.0, 1.0, 1.0, 5.0]
)


class MarkingInputError(SemslamError, ValueError):
    """The marking detector was given an image, mask or prior it cannot use."""


@dataclass(frozen=True)
class MarkingParams:
    """Every tunable of the detector (pixel quantities at the working resolution).

    ``weights`` are the logistic regression's: bias first, then one per entry of
    :data:`FEATURES` (features divided by ``FEATURE_SCALES``).
    """

    preseg_margin_m: float = 0.5  # not tuned: around the map's markings
    clahe_clip: float = 1.8732  # CLAHE clip limit (0: no equalisation)
    clahe_tiles: int = 3
    blur_sigma_px: float = 1.9995
    grad_min: float = 3.8091  # edge strength, intensity per pixel
    pair_ratio: float = 0.7455  # the opposite edge must reach pair_ratio * grad_min
    pair_angle_deg: float = 49.6422  # alpha: opposite gradients within this of pi
    min_width_m: float = 0.0602
    max_width_m: float = 0.3301
    min_contrast: float = 18.1179
    max_asymmetry: float = 101.2923  # largest difference between the two floor samples
    max_floor_dev: float = 140.8841  # largest floor-sample distance from the view's median
    link_radius_px: float = 4.2813  # the gap region growing bridges (the penalty counter)
    link_angle_deg: float = 24.7524
    link_offset_px: float = 0.6013
    link_width_ratio: float = 0.2812
    link_intensity: float = 14.2738
    min_segment_px: float = 8.7896  # shortest segment, pixels
    max_residual_px: float = 1.3777
    trim_px: float = 2.2378  # points farther from the axis fit are dropped (twice)
    cluster_angle_deg: float = 4.7503
    cluster_offset_m: float = 0.0797
    cluster_gap_m: float = 0.9815
    cluster_width_m: float = 0.0569
    cluster_intensity: float = 145.6697
    min_length_m: float = 0.247
    # fmt: off
    weights: tuple[float, ...] = (-3.8125, -0.0570, -0.1719, 0.8542, -1.0911, 0.3340, 1.7181,
                                  -0.4438, -0.5096, -1.0851, -1.0614, 1.0927, 0.7477, 1.3431)
    # fmt: on
    min_confidence: float = 0.76  # operating point: precision >= 0.96 within 5 m (validation)

    def __post_init__(self) -> None:
        if len(self.weights) != len(FEATURES) + 1:
            raise MarkingInputError(
                f"MarkingParams.weights: expected {len(FEATURES) + 1} numbers, "
                f"got {len(self.weights)}"
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values."""
        d = asdict(self)
        d["weights"] = [float(w) for w in self.weights]
        return d

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> MarkingParams:
        """From :meth:`to_dict` output; unknown keys are refused."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise MarkingInputError(f"MarkingParams: unknown field(s) {', '.join(unknown)}")
        v = dict(values)
        if "weights" in v:
            v["weights"] = tuple(float(w) for w in v["weights"])
        if "clahe_tiles" in v:
            v["clahe_tiles"] = int(round(v["clahe_tiles"]))
        return cls(**v)


TUNED = MarkingParams()  # the defaults: tools/tune_markings.py, CMA-ES (see BENCHMARKS.md)
# the mask path (hand-set, not tuned): no equalisation, a fixed edge threshold for 0/255
# masks; on a clean mask L, V, G and colour are constant, so the confidence weighs only
# length, fill, straightness and distance
MASK_PARAMS = replace(
    TUNED,
    clahe_clip=0.0,
    blur_sigma_px=1.0,
    grad_min=40.0,
    min_contrast=60.0,
    link_intensity=255.0,
    cluster_intensity=255.0,
    weights=(-3.0, 0.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 3.0, -0.3),
    min_confidence=0.5,
)
MASK_WORK_MPP = 1.0 / 60.0  # masks are resampled to the top views' resolution


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


# ----------------------------------------------------------------------- input checks


def _as_uint8_image(image: object, what: str) -> NDArray[np.uint8]:
    if not isinstance(image, np.ndarray):
        raise MarkingInputError(f"{what}: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise MarkingInputError(f"{what}: expected dtype uint8, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))):
        raise MarkingInputError(
            f"{what}: expected shape (H, W) or (H, W, 3), got {tuple(image.shape)}"
        )
    if min(image.shape[:2]) < 16:
        raise MarkingInputError(
            f"{what}: image of {image.shape[1]} x {image.shape[0]} px is too small"
        )
    return image


def marking_channel(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The channel markings are bright in: ``(R + G) / 2`` of a BGR image, or the gray image."""
    if image.ndim == 2:
        return image
    if image.shape[2] == 1:
        return np.ascontiguousarray(image[:, :, 0])
    _, g, r = cv2.split(image)
    return np.asarray(cv2.addWeighted(g, 0.5, r, 0.5, 0.0), np.uint8)


def _prior_roi(
    prior: ArrayLike, spec: TopviewSpec, shape: tuple[int, int], margin_m: float
) -> NDArray[np.bool_]:
    seg = np.asarray(prior, dtype=float)
    if seg.size == 0:
        return np.zeros(shape, bool)
    if seg.ndim != 3 or seg.shape[1:] != (2, 2) or not np.isfinite(seg).all():
        raise MarkingInputError(
            f"prior_segments: expected finite (K, 2, 2) vehicle-frame end points, "
            f"got shape {seg.shape}"
        )
    px = spec.vehicle_to_pixel(seg.reshape(-1, 2)).reshape(-1, 2, 2)
    roi = np.zeros(shape, np.uint8)
    thick = max(1, int(round(2.0 * margin_m / spec.metres_per_px)))
    for (u0, v0), (u1, v1) in np.clip(px, -1e4, 1e4):
        cv2.line(roi, (int(round(u0)), int(round(v0))), (int(round(u1)), int(round(v1))), 1, thick)
    return roi.astype(bool)


# ----------------------------------------------------------------------- stages 2-4


def _walk_range(p: MarkingParams, mpp: float) -> tuple[int, int]:
    """Shortest and longest walk to the opposite edge, pixels."""
    kmin = max(2, int(math.floor(p.min_width_m / mpp)))
    return kmin, max(kmin + 1, int(math.ceil(p.max_width_m / mpp)) + 1)


def _edges(eq: NDArray[np.uint8], invalid: NDArray[np.bool_], p: MarkingParams):
    """Stage 3 on the equalised image: smoothed image, gradients, edge pixels after NMS
    (the image is padded: its border pixels are invalid)."""
    img = eq.astype(np.float32)
    if p.blur_sigma_px > 0.05:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), float(p.blur_sigma_px)), np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    mag = cv2.magnitude(gx, gy)
    cand = (mag >= p.grad_min) & ~invalid
    # walk only from edges whose gradient (into the bright side) points into one half
    # plane (with a 20 deg overlap): each line is found from one of its two edges, or
    # from both when its normal is near the half plane's border
    cand &= gx >= -0.35 * mag
    ys, xs = np.nonzero(cand)
    m0 = mag[ys, xs]
    dx, dy = gx[ys, xs] / m0, gy[ys, xs] / m0
    ix1, iy1 = np.rint(xs + dx).astype(np.intp), np.rint(ys + dy).astype(np.intp)
    ix0, iy0 = np.rint(xs - dx).astype(np.intp), np.rint(ys - dy).astype(np.intp)
    mp, mm = mag[iy1, ix1], mag[iy0, ix0]
    keep = (m0 >= mp) & (m0 > mm)
    xs, ys, dx, dy, m0, mp, mm = (a[keep] for a in (xs, ys, dx, dy, m0, mp, mm))
    den = mm - 2.0 * m0 + mp
    off = np.where(den < -1e-6, 0.5 * (mm - mp) / np.where(den < -1e-6, den, -1.0), 0.0)
    return img, gx, gy, xs, ys, dx, dy, m0, np.clip(off, -0.5, 0.5)


_DIRS = 256  # walk directions


@functools.lru_cache(maxsize=8)
def _walk_offsets(row_stride: int, kmax: int) -> NDArray[np.intp]:
    """(_DIRS, kmax + 5) flat-index offsets of the walk steps -2..kmax+2 per direction."""
    a = np.arange(_DIRS) * (2 * math.pi / _DIRS)
    k = np.arange(-2, kmax + 3)
    ox = np.rint(np.cos(a)[:, None] * k[None, :]).astype(np.intp)
    oy = np.rint(np.sin(a)[:, None] * k[None, :]).astype(np.intp)
    return oy * row_stride + ox


def _symmetry(img, gx, gy, aux: dict, invalid, edges, p: MarkingParams, mpp: float):
    """Stage 4: pairs of opposite edges and the per-pixel statistics at their centres.

    Returns (M, 2) centre points (px) and a dict of (M,) arrays: S, L, V, G, C (contrast),
    A (asymmetry), H (chroma), R (red-green), D (floor deviation), F (floor level),
    c2, s2 (doubled line angle), n (pairs). ``aux``: the raw marking channel ``raw``, its
    median over the view ``median``, and (BGR input) the ``chroma`` and ``rg`` images.
    """
    xs, ys, dx, dy, m0, off0 = edges
    kmin, kmax = _walk_range(p, mpp)
    steps = np.arange(-2, kmax + 3)  # floor sample, walk, floor sample
    # the images are padded by more than a walk (padding is invalid): walks need no bounds
    # checks, and each walk is its start index plus the offsets of its direction,
    # quantised to 1/256 of a turn (at most 0.35 px off the exact ray at 28 px)
    W = img.shape[1]
    gxp, gyp, imgp, invp = gx.ravel(), gy.ravel(), img.ravel(), invalid.ravel()
    start = ys.astype(np.int64) * W + xs.astype(np.int64)
    dbin = np.rint(np.arctan2(dy, dx) * (_DIRS / (2 * math.pi))).astype(np.intp) % _DIRS
    flat = start[:, None] + _walk_offsets(W, kmax)[dbin]
    gxs, gys = gxp[flat], gyp[flat]
    ok = ~invp[flat]
    proj = -(gxs * dx[:, None] + gys * dy[:, None])  # > 0 on the far edge
    j0 = 2  # column of step 0
    cos_a = math.cos(math.radians(p.pair_angle_deg))
    c0, c1 = j0 + kmin, j0 + kmax + 1  # walk columns where the far edge may be
    core = proj[:, c0:c1]
    hit = (
        (core >= p.pair_ratio * p.grad_min)
        & (core * core >= (gxs[:, c0:c1] ** 2 + gys[:, c0:c1] ** 2) * (cos_a * abs(cos_a)))
        & (core >= proj[:, c0 - 1 : c1 - 1])
        & (core > proj[:, c0 + 1 : c1 + 1])
    )
    blocked = np.cumsum(~ok[:, j0:c1], axis=1) > 0  # entered the ego box or left the image
    hit &= ~blocked[:, kmin:]
    found = hit.any(axis=1)
    k_idx = hit.argmax(axis=1)[found] + c0  # column in the walk arrays
    rows = np.nonzero(found)[0]
    if len(rows) == 0:
        return np.zeros((0, 2)), {}
    pm, pc, pp = proj[rows, k_idx - 1], proj[rows, k_idx], proj[rows, k_idx + 1]
    den = pm - 2.0 * pc + pp
    offk = np.where(den < -1e-6, 0.5 * (pm - pp) / np.where(den < -1e-6, den, -1.0), 0.0)
    kk = steps[k_idx] + np.clip(offk, -0.5, 0.5)
    o0 = off0[rows]
    width = kk - o0
    # intensities: interior steps 1..k-1, floor samples at -2 and k+2
    fr = flat[rows]
    Is = imgp[fr]
    cs = np.cumsum(Is, axis=1)
    cs2 = np.cumsum(Is * Is, axis=1)
    r = np.arange(len(rows))
    n_in = (k_idx - 1 - j0).astype(np.float32)
    s1 = cs[r, k_idx - 1] - cs[r, j0]
    s2 = cs2[r, k_idx - 1] - cs2[r, j0]
    L = s1 / n_in
    V = np.maximum(s2 / n_in - L * L, 0.0)
    far = k_idx + 2
    out_far = Is[r, far]
    contrast = L - np.maximum(Is[:, 0], out_far)
    asym = np.abs(Is[:, 0] - out_far)
    floor = 0.5 * (Is[:, 0] + out_far)
    G = 0.5 * (m0[rows] + pc)
    keep = (contrast >= p.min_contrast) & ok[rows, far] & ok[rows, 0]
    rows, kk, o0, width, L, V, contrast, asym, floor, G, k_idx, far, fr = (
        a[keep] for a in (rows, kk, o0, width, L, V, contrast, asym, floor, G, k_idx, far, fr)
    )
    r = np.arange(len(rows))
    raw = aux["raw"].ravel()
    dev = 0.5 * (np.abs(raw[fr[:, 0]] - aux["median"]) + np.abs(raw[fr[r, far]] - aux["median"]))
    gate = (asym <= p.max_asymmetry) & (dev <= p.max_floor_dev)
    rows, kk, o0, width, L, V, contrast, asym, floor, G, k_idx, far, fr, dev = (
        a[gate] for a in (rows, kk, o0, width, L, V, contrast, asym, floor, G, k_idx, far, fr, dev)
    )
    r = np.arange(len(rows))
    if aux.get("chroma") is None:
        hue = rg = np.zeros(len(rows))
    else:
        centre = fr[r, (j0 + k_idx) // 2]
        hue = aux["chroma"].ravel()[centre]
        rg = aux["rg"].ravel()[centre]
    gxs, gys = gxs[rows], gys[rows]
    ddx, ddy = dx[rows], dy[rows]
    t = 0.5 * (o0 + kk)
    cx, cy = xs[rows] + t * ddx, ys[rows] + t * ddy
    # orientation of the line: normal from both edges' gradients, as a doubled angle
    gqx, gqy = gxs[r, k_idx], gys[r, k_idx]
    mq = np.maximum(np.hypot(gqx, gqy), 1e-6)
    nx, ny = ddx - gqx / mq, ddy - gqy / mq
    theta = np.arctan2(ny, nx) + 0.5 * math.pi  # line direction
    c2, s2 = np.cos(2 * theta), np.sin(2 * theta)
    # per-pixel running means at the centre pixel
    pix = np.rint(cy).astype(np.int64) * W + np.rint(cx).astype(np.int64)
    uniq, inv = np.unique(pix, return_inverse=True)
    n = np.bincount(inv).astype(float)

    def mean(v: np.ndarray) -> np.ndarray:
        return np.bincount(inv, weights=v) / n

    pts = np.stack([mean(cx), mean(cy)], axis=1)
    cc, ss = mean(c2), mean(s2)
    norm = np.maximum(np.hypot(cc, ss), 1e-9)
    stats = {
        "S": mean(width),
        "L": mean(L),
        "V": mean(V),
        "G": mean(G),
        "C": mean(contrast),
        "A": mean(asym),
        "H": mean(hue),
        "R": mean(rg),
        "D": mean(dev),
        "F": mean(floor),
        "c2": cc / norm,
        "s2": ss / norm,
        "n": n,
    }
    return pts, stats


# ----------------------------------------------------------------------- stages 5-7


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


_END_STEPS = np.arange(-4.0, 10.25, 0.5)  # px along the line from a fitted end, outward


def _refine_ends(img, invalid, cen, dirs, tlo, thi, floor_level):
    """Move each end to where the intensity along the centre line falls half way from
    the paint to the floor (the gradient stage stops a blur radius short of the end).
    Ends that meet no such drop within 10 px, or run into invalid pixels, stay."""
    s = _END_STEPS
    out = []
    for sign, t in ((-1.0, tlo), (1.0, thi)):
        e = cen + dirs * t[:, None]
        P = e[:, None, :] + (sign * s)[None, :, None] * dirs[:, None, :]
        v, ok = _bilinear(img, invalid, P)
        inside = v[:, s <= -1.0].mean(axis=1)
        thr = 0.5 * (inside + floor_level)
        below = (v < thr[:, None]) & (s >= -2.0)[None, :]
        k = below.argmax(axis=1)
        r = np.arange(len(t))
        usable = below.any(axis=1) & (k > 0) & (np.cumsum(~ok, axis=1)[r, k] == 0)
        k = np.maximum(k, 1)
        v0, v1 = v[r, k - 1], v[r, k]
        frac = np.clip((v0 - thr) / np.maximum(v0 - v1, 1e-6), 0.0, 1.0)
        shift = s[k - 1] + frac * (s[k] - s[k - 1])
        out.append(np.where(usable, t + sign * shift, t))
    return out[0], out[1]


def _lines(
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
    w_in = inl.astype(float)

    def mean(v: np.ndarray) -> np.ndarray:
        return np.bincount(li, weights=w_in * v[sel], minlength=n_lines) / np.maximum(cnt, 1)

    tlo, thi = _refine_ends(img, invalid, cen, dirs, tlo, thi, mean(st["F"]))
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


def _run(
    gray: NDArray[np.uint8],
    bgr: NDArray[np.uint8] | None,
    invalid: NDArray[np.bool_],
    p: MarkingParams,
    mpp: float,
    centre_px: tuple[float, float],
) -> MarkingLines:
    sub = gray[::4, ::4][~invalid[::4, ::4]]
    median = float(np.median(sub)) if sub.size else 0.0
    eq = gray
    if p.clahe_clip > 0:  # stage 2 (before padding: the tiles see only the view)
        tiles = max(1, int(p.clahe_tiles))
        clahe = cv2.createCLAHE(clipLimit=float(p.clahe_clip), tileGridSize=(tiles, tiles))
        eq = np.asarray(clahe.apply(gray), np.uint8)
    # pad by more than the longest walk (replicated values, marked invalid)
    pad = _walk_range(p, mpp)[1] + 4

    def padded(a: np.ndarray, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
        return np.asarray(cv2.copyMakeBorder(a, pad, pad, pad, pad, border, value=1))

    invp = padded(invalid.astype(np.uint8), cv2.BORDER_CONSTANT).astype(bool)
    aux: dict = {"raw": padded(gray), "median": median}
    if bgr is not None:
        b, g, r = (c.astype(np.float32) for c in cv2.split(padded(bgr)))
        aux["chroma"] = b - 0.5 * (g + r)
        aux["rg"] = cv2.absdiff(r, g)
    img, gx, gy, xs, ys, dx, dy, m0, off0 = _edges(padded(eq), invp, p)
    pts, st = _symmetry(img, gx, gy, aux, invp, (xs, ys, dx, dy, m0, off0), p, mpp)
    lines = _lines(img, invp, pts, st, p, mpp, (centre_px[0] + pad, centre_px[1] + pad))
    return replace(lines, a=lines.a - pad, b=lines.b - pad, centre_px=centre_px)


# ----------------------------------------------------------------------- public API


class MarkingDetector:
    """Houben's painted-line detector for top views and for semantic line masks.

    Args:
        params: detector settings for top views (default: the CMA-ES-tuned :data:`TUNED`).
        mask_params: settings for :meth:`detect_mask` (default :data:`MASK_PARAMS`).
    """

    def __init__(
        self, params: MarkingParams | None = None, mask_params: MarkingParams | None = None
    ) -> None:
        self.params = params or TUNED
        self.mask_params = mask_params or MASK_PARAMS

    def detect(
        self,
        topview: NDArray[np.uint8],
        spec: TopviewSpec,
        prior_segments: ArrayLike | None = None,
    ) -> tuple[MarkingObservation, ...]:
        """Line markings in one top view.

        Args:
            topview: (size, size, 3) BGR or (size, size) gray uint8 image on the grid of
                ``spec`` (vehicle at the centre, x forward = up); black pixels (ego box,
                outside the stitched view) are ignored.
            spec: the top-view grid.
            prior_segments: (K, 2, 2) end points (vehicle frame, m) of the map's markings
                seen from the predicted pose: only pixels within ``preseg_margin_m`` of
                them are searched (an empty array searches nothing). None: the whole view.

        Returns:
            Observations in the vehicle frame, most confident first.
        """
        return self.detect_lines(topview, spec, prior_segments).observations()

    def detect_lines(
        self,
        topview: NDArray[np.uint8],
        spec: TopviewSpec,
        prior_segments: ArrayLike | None = None,
        params: MarkingParams | None = None,
    ) -> MarkingLines:
        """:meth:`detect` in pixels, with every line's features (tuning, overlays)."""
        p = params or self.params
        img = _as_uint8_image(topview, "topview")
        n = spec.size_px
        if img.shape[:2] != (n, n):
            raise MarkingInputError(
                f"topview: expected {n} x {n} px for this TopviewSpec, "
                f"got {img.shape[1]} x {img.shape[0]}"
            )
        gray = marking_channel(img)
        bgr = img if img.ndim == 3 and img.shape[2] == 3 else None
        invalid = cv2.dilate((gray <= 6).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        c, s = spec.centre_px, spec.metres_per_px
        if spec.ego_length_m > 0 and spec.ego_width_m > 0:
            hu, hv = spec.ego_width_m / (2 * s) + 2, spec.ego_length_m / (2 * s) + 2
            invalid[
                max(0, int(c - hv)) : int(math.ceil(c + hv)) + 1,
                max(0, int(c - hu)) : int(math.ceil(c + hu)) + 1,
            ] = True
        if prior_segments is not None:
            invalid |= ~_prior_roi(prior_segments, spec, gray.shape, p.preseg_margin_m)
        return _run(gray, bgr, invalid, p, s, (c, c))

    def detect_mask(
        self,
        mask: NDArray[Any],
        metres_per_pixel: float,
        centre_px: tuple[float, float],
    ) -> tuple[MarkingObservation, ...]:
        """Line markings in a bird's-eye binary mask of one class (non-zero = paint).

        The mask is resampled to the top views' resolution (``MASK_WORK_MPP``) and runs
        through the same stages with :data:`MASK_PARAMS` (no equalisation; on a clean
        mask the symmetry stage only measures widths).

        Args:
            mask: (H, W) bool or integer mask, rows down, x forward = up.
            metres_per_pixel: its ground resolution (the real garage drive: 0.01).
            centre_px: (u, v) pixel of the vehicle centre (the garage drive: (W/2, H/2)).

        Returns:
            Observations in the vehicle frame (x forward, y left, m), most confident first.
        """
        return self.detect_mask_lines(mask, metres_per_pixel, centre_px).observations()

    def detect_mask_lines(
        self,
        mask: NDArray[Any],
        metres_per_pixel: float,
        centre_px: tuple[float, float],
    ) -> MarkingLines:
        """:meth:`detect_mask` in pixels of the resampled mask."""
        if not isinstance(mask, np.ndarray) or mask.ndim != 2:
            shape = getattr(mask, "shape", None)
            raise MarkingInputError(f"mask: expected a 2-D numpy array, got shape {shape}")
        if not (mask.dtype == np.bool_ or np.issubdtype(mask.dtype, np.integer)):
            raise MarkingInputError(f"mask: expected a bool or integer array, got {mask.dtype}")
        mpp = float(metres_per_pixel)
        if not (mpp > 0 and math.isfinite(mpp)):
            raise MarkingInputError(f"metres_per_pixel: expected > 0, got {metres_per_pixel}")
        if min(mask.shape) < 16:
            raise MarkingInputError(f"mask: {mask.shape[1]} x {mask.shape[0]} px is too small")
        f = mpp / MASK_WORK_MPP
        m8 = (mask != 0).astype(np.uint8) * 255
        size = (max(16, int(round(mask.shape[1] * f))), max(16, int(round(mask.shape[0] * f))))
        work = cv2.resize(m8, size, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
        fx, fy = size[0] / mask.shape[1], size[1] / mask.shape[0]
        centre = ((centre_px[0] + 0.5) * fx - 0.5, (centre_px[1] + 0.5) * fy - 0.5)
        invalid = np.zeros(work.shape, bool)
        return _run(work, None, invalid, self.mask_params, MASK_WORK_MPP, centre)


__all__ = [
    "FEATURES",
    "FEATURE_SCALES",
    "MASK_PARAMS",
    "MASK_WORK_MPP",
    "MarkingLines",
    "TUNED",
    "MarkingDetector",
    "MarkingInputError",
    "MarkingParams",
    "marking_channel",
]
