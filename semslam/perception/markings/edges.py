"""Stages 3-4 of the detector: gradients with non-maximum suppression, then symmetry:
pairs of opposite edges across a painted line and the per-pixel statistics (L, V, G, S,
O and the floor samples) at the pair's centre. Pixels: the padded working image."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.perception.markings.params import MarkingParams


def walk_range(p: MarkingParams, mpp: float) -> tuple[int, int]:
    """Shortest and longest walk to the opposite edge, pixels."""
    kmin = max(2, int(math.floor(p.min_width_m / mpp)))
    return kmin, max(kmin + 1, int(math.ceil(p.max_width_m / mpp)) + 1)


def edge_pixels(eq: NDArray[np.uint8], invalid: NDArray[np.bool_], p: MarkingParams):
    """Stage 3 on the equalised image: smoothed image, gradients, edge pixels after NMS
    (the image is padded: its border pixels are invalid)."""
    img = eq.astype(np.float32)
    if p.blur_sigma_px > 0.05:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), float(p.blur_sigma_px)), np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    # numpy, not cv2.magnitude: OpenCV's (IPP's) result changed in its last bits from call
    # to call on the same gradients, moving the lines by up to 1e-7 px between runs
    mag = np.sqrt(gx * gx + gy * gy)
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


def symmetry_centres(img, gx, gy, aux: dict, invalid, edges, p: MarkingParams, mpp: float):
    """Stage 4: pairs of opposite edges and the per-pixel statistics at their centres.

    Returns (M, 2) centre points (px) and a dict of (M,) arrays: S, L, V, G, C (contrast),
    A (asymmetry), H (chroma), R (red-green), D (floor deviation), F (floor level),
    c2, s2 (doubled line angle), n (pairs). ``aux``: the raw marking channel ``raw``, its
    median over the view ``median``, and (BGR input) the padded colour image ``bgr``.
    """
    xs, ys, dx, dy, m0, off0 = edges
    kmin, kmax = walk_range(p, mpp)
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
    if aux.get("bgr") is None:
        hue = rg = np.zeros(len(rows))
    else:  # colour at the walk's middle pixel
        b, g, r_ = aux["bgr"].reshape(-1, 3)[fr[r, (j0 + k_idx) // 2]].astype(np.float32).T
        hue, rg = b - 0.5 * (g + r_), np.abs(r_ - g)
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


__all__ = ["edge_pixels", "symmetry_centres", "walk_range"]
