"""The detector's entry points: input checks, the marking channel, the map prior's
region, and :class:`MarkingDetector` running stages 2-7 on a top view or on a semantic
line mask."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from semslam.geometry import clip_segment
from semslam.perception.markings.edges import edge_pixels, symmetry_centres, walk_range
from semslam.perception.markings.params import (
    MASK_PARAMS,
    TUNED,
    MarkingInputError,
    MarkingParams,
)
from semslam.perception.markings.segments import MarkingLines, lines_from_centres
from semslam.rig import TopviewSpec
from semslam.types import MarkingObservation


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
    reach = max(shape) + thick  # cut to the view and its margin; cutting keeps the direction
    for a, b in px:
        cut = clip_segment(a, b, -float(reach), float(reach))
        if cut is None:
            continue
        (u0, v0), (u1, v1) = cut
        cv2.line(roi, (int(round(u0)), int(round(v0))), (int(round(u1)), int(round(v1))), 1, thick)
    return roi.astype(bool)


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
    pad = walk_range(p, mpp)[1] + 4

    def padded(a: np.ndarray, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
        return np.asarray(cv2.copyMakeBorder(a, pad, pad, pad, pad, border, value=1))

    invp = padded(invalid.astype(np.uint8), cv2.BORDER_CONSTANT).astype(bool)
    aux: dict = {"raw": padded(gray), "median": median}
    if bgr is not None:
        aux["bgr"] = padded(bgr)
    img, gx, gy, xs, ys, dx, dy, m0, off0 = edge_pixels(padded(eq), invp, p)
    pts, st = symmetry_centres(img, gx, gy, aux, invp, (xs, ys, dx, dy, m0, off0), p, mpp)
    centre = (centre_px[0] + pad, centre_px[1] + pad)
    lines = lines_from_centres(img, invp, pts, st, p, mpp, centre)
    return replace(lines, a=lines.a - pad, b=lines.b - pad, centre_px=centre_px)


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
                f"topview: expected {n} x {n} px (the rig's top-view size), "
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
        f = p.shrink_factor(s)
        if f == 1:
            return _run(gray, bgr, invalid, p, s, (c, c))
        # stages 2-7 on the view shrunk f times (pixel means; a working pixel is invalid
        # when any of its pixels is), then the lines back in the view's pixels
        size = (max(16, n // f), max(16, n // f))
        fx = size[0] / n
        small = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
        small_bgr = None if bgr is None else cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
        small_invalid = (
            cv2.resize(invalid.astype(np.uint8) * 255, size, interpolation=cv2.INTER_AREA) > 0
        )
        cw = (c + 0.5) * fx - 0.5
        lines = _run(small, small_bgr, small_invalid, p, s / fx, (cw, cw))
        return replace(
            lines,
            a=(lines.a + 0.5) / fx - 0.5,
            b=(lines.b + 0.5) / fx - 0.5,
            width_px=lines.width_px / fx,
            metres_per_px=s,
            centre_px=(c, c),
        )

    def detect_mask(
        self,
        mask: NDArray[Any],
        metres_per_pixel: float,
        centre_px: tuple[float, float],
    ) -> tuple[MarkingObservation, ...]:
        """Line markings in a bird's-eye binary mask of one class (non-zero = paint).

        The mask is resampled to the mask settings' ``work_px_per_m`` (:data:`MASK_PARAMS`:
        the top views' 60 px per metre) and runs through the same stages with them (no
        equalisation; on a clean mask the symmetry stage only measures widths).

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
        work_mpp = 1.0 / self.mask_params.work_px_per_m
        f = mpp / work_mpp
        m8 = (mask != 0).astype(np.uint8) * 255
        size = (max(16, int(round(mask.shape[1] * f))), max(16, int(round(mask.shape[0] * f))))
        work = cv2.resize(m8, size, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
        fx, fy = size[0] / mask.shape[1], size[1] / mask.shape[0]
        centre = ((centre_px[0] + 0.5) * fx - 0.5, (centre_px[1] + 0.5) * fy - 0.5)
        invalid = np.zeros(work.shape, bool)
        return _run(work, None, invalid, self.mask_params, work_mpp, centre)


__all__ = ["MarkingDetector", "marking_channel"]
