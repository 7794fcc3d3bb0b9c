"""Top views of any size and ground resolution in the detectors' frame.

The detectors read the ps2.0 convention (:class:`~semslam.rig.TopviewSpec`: 600 x 600 px,
60 px per metre, the car at the centre): the CNNs were trained on its scale and the slot
rules, ID crops and line detector measure in its pixels. An image of another size (a ps2.0
view resized to 512 px, as DMPR-PS pipelines store them; a 600 x 480 AVM view) is brought
into that frame first: resampled to 60 px per metre and padded with black around its
centre, where the car is. Detections then map back to the image's own pixels.

Pixel convention (OpenCV): pixel ``u`` covers ``[u - 0.5, u + 0.5]``; resampling by ``f``
maps ``u`` to ``f (u + 0.5) - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from semslam.errors import PerceptionError
from semslam.geometry import FloatArray
from semslam.rig import TopviewSpec

MIN_PX_PER_M = 10.0
"""Coarsest ground resolution read: a painted line (0.10-0.20 m) is 1-2 px there."""

MIN_SIDE_PX = 16
"""Smallest image side read."""

MIN_GROUND_M = 1.0
"""Least ground an image must cover (its longer side, metres): a junction's paint and the
floor around it; less is a wrong ``--px-per-m``."""


@dataclass(frozen=True)
class ViewFrame:
    """Where an image lies in the detectors' frame.

    Attributes:
        image_shape: (height, width) of the image, pixels.
        scale: (fx, fy) detector pixels per image pixel along u and v.
        offset: (left, top) black padding added around the resampled image, detector px.
    """

    image_shape: tuple[int, int]
    scale: tuple[float, float]
    offset: tuple[int, int]

    @property
    def is_identity(self) -> bool:
        """The image already is a view of the detectors' frame."""
        return self.scale == (1.0, 1.0) and self.offset == (0, 0)

    def to_detector(self, uv: FloatArray) -> FloatArray:
        """(N, 2) image pixels to detector pixels."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        return (uv + 0.5) * self.scale - 0.5 + self.offset

    def to_image(self, uv: FloatArray) -> FloatArray:
        """(N, 2) detector pixels to image pixels."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        return (uv - self.offset + 0.5) / self.scale - 0.5

    def direction_to_image(self, radians):
        """Directions in detector pixels (``atan2(dv, du)``, radians) in image pixels: the
        same unless the two axes were resampled by different factors (rounded sizes)."""
        fx, fy = self.scale
        return np.arctan2(np.sin(radians) / fy, np.cos(radians) / fx)

    def direction_to_detector(self, radians):
        """Directions in image pixels in detector pixels (:meth:`direction_to_image`)."""
        fx, fy = self.scale
        return np.arctan2(np.sin(radians) * fy, np.cos(radians) * fx)


def view_frame(
    image_shape: tuple[int, ...], px_per_m: float | None = None, spec: TopviewSpec | None = None
) -> ViewFrame:
    """The frame of an image of ``image_shape`` (height, width, ...) whose ground resolution
    is ``px_per_m``; None: its longer side spans the detectors' view (ps2.0: 10 m).

    Raises:
        PerceptionError: ``px_per_m`` is not a positive number, the image is smaller than
            :data:`MIN_SIDE_PX` or coarser than :data:`MIN_PX_PER_M`, or it covers less
            ground than :data:`MIN_GROUND_M` or more than the detectors' view (they read
            one 10 m view; crop it).
    """
    spec = spec or TopviewSpec()
    height, width = (int(n) for n in image_shape[:2])
    side = spec.size_px
    if min(height, width) < MIN_SIDE_PX:
        raise PerceptionError(f"top view of {width} x {height} px: too small to read "
                              f"(at least {MIN_SIDE_PX} px a side)")
    if px_per_m is None:
        factor = side / max(height, width)
    else:
        if not (np.isfinite(px_per_m) and px_per_m > 0):
            raise PerceptionError(f"--px-per-m {px_per_m}: expected a number > 0")
        factor = 1.0 / (px_per_m * spec.metres_per_px)
    resolution = 1.0 / (factor * spec.metres_per_px)
    if resolution < MIN_PX_PER_M:
        raise PerceptionError(
            f"top view of {width} x {height} px at {resolution:g} px per metre: too coarse to "
            f"read (at least {MIN_PX_PER_M:g} px per metre; give its --px-per-m)"
        )
    new_w, new_h = max(1, round(width * factor)), max(1, round(height * factor))
    extent = max(height, width) * factor * spec.metres_per_px
    if extent < MIN_GROUND_M:
        raise PerceptionError(
            f"top view of {width} x {height} px at {resolution:g} px per metre covers "
            f"{extent:.3g} m: too little ground to read (at least {MIN_GROUND_M:g} m; check "
            "its --px-per-m)"
        )
    if new_w > side or new_h > side:
        raise PerceptionError(
            f"top view of {width} x {height} px at {resolution:g} px per metre covers "
            f"{extent:.1f} m; the detectors read views of at most "
            f"{side * spec.metres_per_px:g} m (crop it, or give its --px-per-m)"
        )
    return ViewFrame((height, width), (new_w / width, new_h / height),
                     ((side - new_w) // 2, (side - new_h) // 2))


def into_detector_frame(image: np.ndarray, frame: ViewFrame,
                        spec: TopviewSpec | None = None) -> np.ndarray:
    """``image`` resampled and padded into the detectors' frame (itself when it is one)."""
    side = (spec or TopviewSpec()).size_px
    if frame.is_identity and image.shape[:2] == (side, side):
        return image
    height, width = image.shape[:2]
    new_w, new_h = round(width * frame.scale[0]), round(height * frame.scale[1])
    if (new_w, new_h) != (width, height):
        shrinking = new_w < width
        image = cv2.resize(image, (new_w, new_h),
                           interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    left, top = frame.offset
    return cv2.copyMakeBorder(image, top, side - new_h - top, left, side - new_w - left,
                              cv2.BORDER_CONSTANT, value=0)


__all__ = [
    "MIN_GROUND_M", "MIN_PX_PER_M", "MIN_SIDE_PX", "ViewFrame", "into_detector_frame", "view_frame",
]
