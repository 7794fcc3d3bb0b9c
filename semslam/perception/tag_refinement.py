"""Tag corners from the centre line of the black border ring, which overexposure cannot move.

AprilTag fits each quad edge to the gradient between the tag's black border and the
white quiet zone around it. When the white is clipped (an overexposed tag: a lamp
behind the camera, a short exposure set for the dark floor), the blurred edge loses its
white half, the gradient's centre moves onto the black side, every edge moves inwards
and the square looks smaller: PnP then ranges 0.5-1.2 % long (simulator, 5-15 m). The
same bleed moves the *inner* edge of the border ring (black ring against a white data
cell) outwards by as much, so the middle of the ring does not move. This module finds
that middle and rebuilds the square from it:

1. the homography ``H`` from the tag's own cell grid to the image, from AprilTag's
   corners (tag coordinates in cells, the black square from ``-c/2`` to ``c/2``, ``c``
   = :data:`~semslam.perception.tag_detection.CELLS`; the ring's centre line at
   ``c/2 - 1/2``);
2. along each side, every data cell next to the ring that is white (its centre brighter
   than halfway between the ring and the quiet zone): three intensity profiles across
   the ring (tag coordinates, bilinear samples of the image);
3. per profile, the ring's two edges where the intensity crosses halfway between its
   darkest sample and the brightest sample on that side, and their midpoint: a clipped,
   blurred ring keeps the midpoint where it is (a centroid of darkness would not: a
   narrow white data cell never reaches full white and drags it inwards, 0.1 px at 4 px
   per cell);
4. per side a line through its midpoints: their mean offset, and their slope too where
   they span two cells and a cell is 8 px or more (smaller tags keep AprilTag's edge
   directions, which the few midpoints there would only make noisier); a side without
   a white data cell takes the mean offset of the others;
5. the four lines' corners (the ring's middle square), and the outer square from them
   by the homography between the two squares.

Measured on the simulator (``benchmarks/bench_tags.py``) and on the real duckietown
photos; see BENCHMARKS.md. Families whose border is not the outermost dark ring
(tagStandard41h12) are returned unchanged, as are tags the method cannot read (no
white data cell next to the ring, a profile without its ring, or a side that would
move by more than a quarter of a cell: a distorted fisheye image, a tag cut by an
object).

Pixels: OpenCV's convention (pixel centres at integer coordinates), as
:func:`~semslam.perception.tag_detection.detect_tags` returns them.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.geometry import FloatArray

# the four sides of the tag in its own cell grid (x right, y up): outward normals in
# AprilTag's corner order bottom-left -> bottom-right -> top-right -> top-left
_NORMALS = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
_TANGENTS = np.stack([-_NORMALS[:, 1], _NORMALS[:, 0]], axis=1)  # along each side
_TANGENT_OFFSETS = (-0.3, 0.0, 0.3)  # profiles per white data cell, cells from its centre
_SPAN = 1.1  # the profile covers the ring's middle +- this many cells
_SAMPLE_PX = 0.2  # spacing of the profile samples in the image, px (at least 45 a profile)
_MIN_CONTRAST = 20.0  # grey levels between ring and quiet zone for a cell to be read
_MAX_SHIFT = 0.25  # cells: a side that would move further is not trusted
_MIN_SLOPE_SPAN = 2.0  # cells along a side that its midpoints must span to turn it
_MIN_SLOPE_CELL_PX = 8.0  # and px per cell (smaller tags keep AprilTag's edge directions)


def _sample(gray: NDArray[np.uint8], H: FloatArray, pts: FloatArray) -> FloatArray:
    """Bilinear grey values at tag-grid points ``pts`` (..., 2)."""
    flat = pts.reshape(-1, 1, 2)
    uv = cv2.perspectiveTransform(flat, H).reshape(-1, 2).astype(np.float32)
    out = cv2.remap(gray, uv[:, :1], uv[:, 1:], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(pts.shape[:-1]).astype(float)


def _grid_homography(corners: FloatArray, cells: int) -> tuple[FloatArray, FloatArray]:
    """The black square's corners in the tag's own cell grid (4, 2) and the homography
    from that grid to the image, from the (4, 2) image ``corners``."""
    half = cells / 2.0
    grid = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    H = cv2.getPerspectiveTransform(grid.astype(np.float32), corners.astype(np.float32))
    return grid, H.astype(np.float64)


def ring_midpoints(profiles: FloatArray, positions: FloatArray) -> FloatArray:
    """Midpoint between the two half-level crossings around the darkest sample of each
    profile (NaN where the trough lies at an end or a side never comes back up).

    Args:
        profiles: (m, n) intensities.
        positions: (n,) increasing positions of the samples.

    Returns:
        (m,) midpoints, in the units of ``positions``.
    """
    P = np.asarray(profiles, dtype=float)
    m, n = P.shape
    idx = np.arange(n)
    j = P.argmin(axis=1)
    trough = P[np.arange(m), j]
    right = idx[None, :] >= j[:, None]
    left = idx[None, :] <= j[:, None]
    level_r = 0.5 * (np.where(right, P, -np.inf).max(axis=1) + trough)
    level_l = 0.5 * (np.where(left, P, -np.inf).max(axis=1) + trough)
    above_r = right & (idx[None, :] > j[:, None]) & (level_r[:, None] <= P)
    above_l = left & (idx[None, :] < j[:, None]) & (level_l[:, None] <= P)
    ok = above_r.any(axis=1) & above_l.any(axis=1) & (j > 0) & (j < n - 1)
    kr = np.where(ok, above_r.argmax(axis=1), 1)  # first sample at or above, right of j
    kl = np.where(ok, n - 1 - above_l[:, ::-1].argmax(axis=1), 0)  # last one left of j
    kr = np.clip(kr, 1, n - 1)
    kl = np.clip(kl, 0, n - 2)
    rows = np.arange(m)

    def cross(a: NDArray[np.intp], b: NDArray[np.intp], level: FloatArray) -> FloatArray:
        pa, pb = P[rows, a], P[rows, b]
        den = np.where(pb != pa, pb - pa, 1.0)
        f = np.clip(np.where(pb != pa, (level - pa) / den, 0.5), 0.0, 1.0)
        return positions[a] + f * (positions[b] - positions[a])

    mid = 0.5 * (cross(kr - 1, kr, level_r) + cross(kl + 1, kl, level_l))
    return np.where(ok, mid, np.nan)


def refine_corners(gray: NDArray[np.uint8], corners: FloatArray, cells: int) -> FloatArray:
    """The tag's (4, 2) corners rebuilt from its border ring's middle (see the module
    docstring), or ``corners`` unchanged when the ring cannot be read.

    Args:
        gray: (H, W) uint8 image the corners were detected in.
        corners: (4, 2) AprilTag corners, bottom-left, bottom-right, top-right, top-left
            of the upright tag's black square, px (OpenCV convention).
        cells: code cells across the black square (tag36h11: 8), the border ring one of
            them on each side.
    """
    return refine_corners_and_count(gray, corners, cells)[0]


def refine_corners_and_count(
    gray: NDArray[np.uint8], corners: FloatArray, cells: int
) -> tuple[FloatArray, tuple[int, int, int, int]]:
    """:func:`refine_corners` and, per side (AprilTag's order: bottom, right, top, left of
    the upright tag), the white data cells read on the ring (all 0 when the corners came
    back unchanged). A side with none keeps AprilTag's edge, moved by the others' mean
    offset: the bleed that the ring cancels is still in it; a side read at one cell is
    placed by that cell's three profiles alone."""
    c = np.asarray(corners, dtype=float)
    half = cells / 2.0
    if cells < 4 or c.shape != (4, 2) or not np.isfinite(c).all():
        return c, (0, 0, 0, 0)
    grid, H = _grid_homography(c, cells)
    middle = half - 0.5
    along = np.arange(-half + 1.5, half - 1.0, 1.0)  # centres of the data cells by a side
    tangents = _TANGENTS
    base = along[None, :, None] * tangents[:, None, :]  # (4, cells - 2, 2)
    nrm = _NORMALS[:, None, :]
    probes = np.stack([base + (half - 1.5) * nrm, base + middle * nrm,
                       base + (half + 0.5) * nrm], axis=2)  # data, ring, quiet zone
    data, ring, quiet = np.moveaxis(_sample(gray, H, probes), 2, 0)
    white = (data > 0.5 * (ring + quiet)) & (quiet - ring >= _MIN_CONTRAST)
    if not white.any():
        return c, (0, 0, 0, 0)
    cell_px = float(np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1).max()) / cells
    n = max(45, int(math.ceil(2.0 * _SPAN * cell_px / _SAMPLE_PX)) + 1)
    positions = np.linspace(middle - _SPAN, middle + _SPAN, n)
    side, cell = np.nonzero(white)
    offsets = np.array(_TANGENT_OFFSETS)
    starts = (along[cell][:, None, None] + offsets[None, :, None]) * tangents[side][:, None, :]
    pts = starts[:, :, None, :] + positions[None, None, :, None] * _NORMALS[side][:, None, None, :]
    profiles = _sample(gray, H, pts).reshape(-1, n)
    mids = ring_midpoints(profiles, positions).reshape(len(side), len(offsets)) - middle
    where = along[cell][:, None] + offsets[None, :]  # tangent position of each midpoint
    lines = []  # per side (offset at the side's centre, slope), cells
    for k in range(4):
        m, t = mids[side == k].ravel(), where[side == k].ravel()
        ok = np.isfinite(m)
        m, t = m[ok], t[ok]
        if m.size and np.ptp(t) >= _MIN_SLOPE_SPAN and cell_px >= _MIN_SLOPE_CELL_PX:
            slope, offset = np.polyfit(t, m, 1)
            lines.append((float(offset), float(slope)))
        elif m.size:
            lines.append((float(m.mean()), 0.0))
        else:
            lines.append(None)
    known = [ln for ln in lines if ln is not None]
    if not known:
        return c, (0, 0, 0, 0)
    mean_offset = float(np.mean([ln[0] for ln in known]))
    lines = [ln if ln is not None else (mean_offset, 0.0) for ln in lines]
    if max(abs(o) + abs(b) * half for o, b in lines) > _MAX_SHIFT:
        return c, (0, 0, 0, 0)
    # side k's middle line in the tag grid: (n_k - b_k t_k) . X = middle + o_k; corner i
    # (grid order) where sides i - 1 and i meet
    middle_square = np.empty((4, 2))
    for i in range(4):
        rows, rhs = [], []
        for k in ((i - 1) % 4, i):
            o, b = lines[k]
            rows.append(_NORMALS[k] - b * tangents[k])
            rhs.append(middle + o)
        middle_square[i] = np.linalg.solve(np.array(rows), np.array(rhs))
    ring_img = cv2.perspectiveTransform(middle_square.reshape(-1, 1, 2), H).reshape(4, 2)
    # the outer square from the ring's middle square by the homography between them
    H_ring = cv2.getPerspectiveTransform((grid * (middle / half)).astype(np.float32),
                                         ring_img.astype(np.float32)).astype(np.float64)
    read = tuple(int(np.count_nonzero(side == k)) for k in range(4))
    return cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H_ring).reshape(4, 2), read


def border_contrast(gray: NDArray[np.uint8], corners: FloatArray, cells: int) -> float:
    """Grey levels between the tag's white quiet zone and its black border ring: the
    medians of samples at the middle of the ring and of the quiet zone, one per border
    cell along each side (tag coordinates through the corners' homography). Noise moves
    an edge by (noise / contrast) px, so a tag that stands out less has noisier corners.

    Args:
        gray: (H, W) uint8 image.
        corners: (4, 2) corners of the black square (as :func:`refine_corners`).
        cells: code cells across the black square (tag36h11: 8).
    """
    c = np.asarray(corners, dtype=float)
    if cells < 4 or c.shape != (4, 2) or not np.isfinite(c).all():
        return float("nan")
    half = cells / 2.0
    _, H = _grid_homography(c, cells)
    along = np.arange(-half + 0.5, half, 1.0)  # every cell along a side
    base = along[None, :, None] * _TANGENTS[:, None, :]
    nrm = _NORMALS[:, None, :]
    ring = _sample(gray, H, base + (half - 0.5) * nrm)
    quiet = _sample(gray, H, base + (half + 0.5) * nrm)
    return float(np.median(quiet) - np.median(ring))


__all__ = ["border_contrast", "refine_corners", "refine_corners_and_count", "ring_midpoints"]
