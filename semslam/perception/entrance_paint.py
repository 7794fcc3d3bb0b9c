"""Is there an entrance line at a marking point? A classical check of the CNNs' points.

A marking point is where a slot's separator meets its entrance line, so paint leaves the
point across the separator, at the slot's angle (90 deg, or a slanted slot's), on one side
(an L junction) or both (a T). The end of a bare line has none: a gap in a long painted
line, or a separator that stops in the aisle. Both look like a junction in a patch a few
lines wide, and the CNNs, trained on simulated garages, take them for one (on the real
ps2.0 samples six of the nine false points are such line ends; BENCHMARKS.md).

The check, per point: the paint level is halfway between the ground (the median grey of a
90 px square around the point) and the separator (the median grey along it, 8-34 px out);
along each ray at 40-140 deg either side of the separator, 10-34 px out, the share of
samples at or above that level is measured; the point's entrance score is the largest
share. A point is undecided (score NaN, kept) when its separator is no brighter than the
ground by :data:`MIN_CONTRAST` grey levels, or when more than half of a ray or of the
separator is not seen (outside the image, or on its black: the ego box, padding): the
entrance may lie there.

Pixels are the top view's (u right, v down), at ps2.0's scale (600 px for 10 m; other
sizes scale the distances); directions in radians, ``atan2(dv, du)`` of the separator.
"""

from __future__ import annotations

import numpy as np

from semslam.geometry import FloatArray

MIN_ENTRANCE_SHARE = 0.25
"""A point whose best entrance ray holds less paint than this share is a bare line end."""

MIN_CONTRAST = 12.0
"""Grey levels the separator must stand above the ground for the check to decide."""

BLACK = 8.0
"""Grey at or below which a pixel is the view's black (the ego box, padding): not seen."""

_SEPARATOR_PX = np.arange(8.0, 36.0, 2.0)
_ENTRANCE_PX = np.arange(10.0, 36.0, 2.0)
_ANGLES = np.radians(np.concatenate([np.arange(40, 141, 5), -np.arange(40, 141, 5)]))
_GROUND_HALF_PX = 45


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
    h, w = topview_bgr.shape[:2]
    scale = max(h, w) / 600.0
    half = int(round(_GROUND_HALF_PX * scale))
    sep_r, ent_r = _SEPARATOR_PX * scale, _ENTRANCE_PX * scale
    scores = np.full(len(uv), np.nan)
    for i, ((u, v), d) in enumerate(zip(uv, direction, strict=True)):
        # samples (u, v) of the separator's ray, then of every entrance ray
        angles = np.concatenate([[d], d + _ANGLES])
        radii = [sep_r] + [ent_r] * len(_ANGLES)
        su = np.concatenate([u + r * np.cos(a) for a, r in zip(angles, radii, strict=True)])
        sv = np.concatenate([v + r * np.sin(a) for a, r in zip(angles, radii, strict=True)])
        c0, r0 = max(0, int(u) - half), max(0, int(v) - half)
        window = topview_bgr[r0 : int(v) + half + 1, c0 : int(u) + half + 1]
        grey = cv2.GaussianBlur(cv2.cvtColor(window, cv2.COLOR_BGR2GRAY), (0, 0), 1.0)
        samples = cv2.remap(grey.astype(np.float32), (su - c0).astype(np.float32)[None],
                            (sv - r0).astype(np.float32)[None], cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)[0]
        # outside the view, or on its black (the ego box, the padding): not seen
        seen = (su >= 0) & (su <= w - 1) & (sv >= 0) & (sv <= h - 1) & (samples > BLACK)
        sep_in = seen[: len(sep_r)]
        ent_in = seen[len(sep_r) :].reshape(len(_ANGLES), len(ent_r))
        if sep_in.mean() < 0.5 or (ent_in.mean(axis=1) < 0.5).any():
            continue  # the separator or an entrance side is not in view
        floor = grey[grey > BLACK]
        if not floor.size:
            continue
        ground = float(np.median(floor))
        paint = float(np.median(samples[: len(sep_r)][sep_in]))
        if paint - ground < MIN_CONTRAST:
            continue
        level = ground + 0.5 * (paint - ground)
        painted = (samples[len(sep_r) :].reshape(ent_in.shape) >= level) & ent_in
        scores[i] = float((painted.sum(axis=1) / ent_in.sum(axis=1)).max())
    return scores


def bare_line_ends(topview_bgr: np.ndarray, uv: FloatArray, direction: FloatArray) -> np.ndarray:
    """(N,) bool: the points the check decides have no entrance line (see the module)."""
    scores = entrance_scores(topview_bgr, uv, direction)
    return np.nan_to_num(scores, nan=1.0) < MIN_ENTRANCE_SHARE


__all__ = ["BLACK", "MIN_CONTRAST", "MIN_ENTRANCE_SHARE", "bare_line_ends", "entrance_scores"]

