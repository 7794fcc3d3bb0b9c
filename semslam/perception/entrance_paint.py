"""Is there an entrance line at a marking point? A classical check of the CNNs' points.

A marking point is where a slot's separator meets its entrance line, so paint leaves the
point across the separator, at the slot's angle (90 deg, or a slanted slot's), on one side
(an L junction) or both (a T). The end of a bare line has none: a gap in a long painted
line, or a separator that stops in the aisle. Both look like a junction in a patch a few
lines wide, and the CNNs, trained on simulated garages, take them for one (on the real
ps2.0 samples six of the nine false points are such line ends; BENCHMARKS.md).

The check, per point: the paint level is halfway between the ground (the median grey of a
90 px square around the point, every third pixel) and the separator (the median grey along
it, 8-34 px out); along each ray at 40-140 deg either side of the separator, 10-34 px out,
every 2 px, the share of samples (each the mean of a 3 x 3 px neighbourhood) at or above
that level is measured; the point's entrance score is the largest share. A point is
undecided (score NaN, kept) when its separator is no brighter than the ground by
:data:`MIN_CONTRAST` grey levels, or when more than half of a ray or of the separator is
not seen (outside the image, or on its black: the ego box, padding): the entrance may lie
there.

Pixels are the top view's (u right, v down), at ps2.0's scale (600 px for 10 m; other
sizes scale the distances); directions in radians, ``atan2(dv, du)`` of the separator.
About 1.2 ms for the five or six points of a simulated view (one core, this machine).
"""

from __future__ import annotations

import numpy as np

from semslam.geometry import FloatArray
from semslam.rig import TOPVIEW_BLACK

MIN_ENTRANCE_SHARE = 0.25
"""A point whose best entrance ray holds less paint than this share is a bare line end."""

MIN_CONTRAST = 12.0
"""Grey levels the separator must stand above the ground for the check to decide."""

_SEPARATOR_PX = np.arange(8.0, 36.0, 2.0)
_ENTRANCE_PX = np.arange(10.0, 36.0, 2.0)
_ANGLES = np.radians(np.concatenate([np.arange(40, 141, 5), -np.arange(40, 141, 5)]))
_GROUND_HALF_PX = 45
_GREY_WEIGHTS = np.array([0.114, 0.587, 0.299], np.float32)  # of B, G, R


def _median(values: np.ndarray) -> float:
    """The median (the upper one of an even count): a partition, without np.median's overhead."""
    m = len(values) // 2
    return float(np.partition(values, m)[m])


def _ray_offsets(scale: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Sample offsets (along, across) the separator, pixels: the separator's ray, then every
    entrance ray; and how many belong to the separator."""
    along = np.concatenate([_SEPARATOR_PX, np.outer(np.cos(_ANGLES), _ENTRANCE_PX).ravel()])
    across = np.concatenate([np.zeros(len(_SEPARATOR_PX)),
                             np.outer(np.sin(_ANGLES), _ENTRANCE_PX).ravel()])
    return along * scale, across * scale, len(_SEPARATOR_PX)


def entrance_scores(topview_bgr: np.ndarray, uv: FloatArray, direction: FloatArray) -> FloatArray:
    """(N,) entrance score in [0, 1] of each point, NaN where the check cannot decide.

    Args:
        topview_bgr: uint8 (H, W, 3) top view.
        uv: (N, 2) points, pixels.
        direction: (N,) separator directions, radians.
    """
    import cv2

    uv = np.asarray(uv, float).reshape(-1, 2)
    direction = np.asarray(direction, float).reshape(-1)
    n = len(uv)
    if n == 0:
        return np.zeros(0)
    h, w = topview_bgr.shape[:2]
    scale = max(h, w) / 600.0
    along, across, k = _ray_offsets(scale)
    c, s = np.cos(direction)[:, None], np.sin(direction)[:, None]
    su = uv[:, :1] + c * along - s * across  # (N, samples)
    sv = uv[:, 1:] + s * along + c * across
    # grey of a 3 x 3 px neighbourhood at each sample, bilinear at its four corners (a light
    # blur against paving joints and noise)
    nu = np.concatenate([su + du for du in (-1.0, 1.0, -1.0, 1.0)], axis=1).astype(np.float32)
    nv = np.concatenate([sv + dv for dv in (-1.0, -1.0, 1.0, 1.0)], axis=1).astype(np.float32)
    bgr = cv2.remap(topview_bgr, nu, nv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    grey = (bgr.astype(np.float32) @ _GREY_WEIGHTS).reshape(n, 4, -1).mean(axis=1)
    seen = (su >= 0) & (su <= w - 1) & (sv >= 0) & (sv <= h - 1) & (grey > TOPVIEW_BLACK)
    shape = (n, len(_ANGLES), len(_ENTRANCE_PX))
    sep_grey, ent_grey = grey[:, :k], grey[:, k:].reshape(shape)
    sep_in, ent_in = seen[:, :k], seen[:, k:].reshape(shape)
    # the separator and every entrance side at least half in view
    decided = (sep_in.mean(axis=1) >= 0.5) & (ent_in.mean(axis=2).min(axis=1) >= 0.5)
    level = np.full(n, np.nan)
    half = int(round(_GROUND_HALF_PX * scale))
    for i in np.flatnonzero(decided):
        col, row = int(uv[i, 0]), int(uv[i, 1])
        window = topview_bgr[max(0, row - half) : row + half + 1 : 3,
                             max(0, col - half) : col + half + 1 : 3]
        floor = window.reshape(-1, 3).astype(np.float32) @ _GREY_WEIGHTS
        floor = floor[floor > TOPVIEW_BLACK]
        if floor.size:
            ground, paint = _median(floor), _median(sep_grey[i][sep_in[i]])
            if paint - ground >= MIN_CONTRAST:
                level[i] = ground + 0.5 * (paint - ground)
    painted = (ent_grey >= level[:, None, None]) & ent_in
    share = painted.sum(axis=2) / np.maximum(ent_in.sum(axis=2), 1)
    return np.where(np.isnan(level), np.nan, share.max(axis=1))


def bare_line_ends(topview_bgr: np.ndarray, uv: FloatArray, direction: FloatArray) -> np.ndarray:
    """(N,) bool: the points the check decides have no entrance line (see the module)."""
    scores = entrance_scores(topview_bgr, uv, direction)
    return np.nan_to_num(scores, nan=1.0) < MIN_ENTRANCE_SHARE


__all__ = ["MIN_CONTRAST", "MIN_ENTRANCE_SHARE", "bare_line_ends", "entrance_scores"]

