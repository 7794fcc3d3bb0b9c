"""AprilTag detection (pupil-apriltags) in OpenCV pixel coordinates.

Pixels: OpenCV's convention, the one ``Camera.K`` uses: pixel centres at integer
coordinates. The AprilTag library puts them at +0.5; :func:`detect_tags` subtracts
that half pixel, so corners feed ``cv2.solvePnP`` with ``K`` directly.

Corner order is the AprilTag library's: bottom-left, bottom-right, top-right,
top-left of the upright tag (counter-clockwise as seen on the tag). The detector
comes from :func:`~semslam.perception.apriltag_detector.shared_detector` (one per
family and process, never a second one); its settings are applied on every call,
so one process must not detect from two threads at once.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import PerceptionError
from semslam.geometry import FloatArray
from semslam.perception.tag_refinement import border_contrast, refine_corners_and_count
from semslam.types import TagFamily

log = logging.getLogger(__name__)

APRILTAG_PIXEL_OFFSET = 0.5  # AprilTag pixel coordinate minus OpenCV pixel coordinate
CELLS = {TagFamily.TAG36H11: 8, TagFamily.TAG25H9: 7, TagFamily.TAG16H5: 6,
         TagFamily.TAG_STANDARD41H12: 5}  # cells across the square the corners outline
RING_FAMILIES = frozenset({TagFamily.TAG36H11, TagFamily.TAG25H9, TagFamily.TAG16H5})
"""Families whose black square's outer cells are a black ring around the data cells."""


@dataclass(frozen=True)
class DetectorSettings:
    """AprilTag detector settings (the C library's names).

    Attributes:
        quad_decimate: quads are found on an image this many times smaller (2: 2x faster
            per step, tags need about 14 px of side; 1: full resolution).
        quad_sigma: Gaussian blur (px) before the quad search; 0 = none.
        refine_edges: snap quad edges to strong gradients (the corners stay sub-pixel
            with decimation).
        decode_sharpening: sharpening of the decoded samples.
        min_white_black_diff: smallest grey-level range of a 4 x 4 px tile (of the
            decimated image) for it to take part in the quad search. The C default (5)
            lets sensor noise on textured floors through as thousands of candidates,
            and the quad search's time falls steeply as this rises (1280 x 800 garage
            frames: 30 -> 16.6 ms, 40 -> 8.5 ms, 50 -> 5.7 ms on one run; the machine's
            speed varies by 60 % between runs). 50 keeps every tag whose black and white
            differ by about 50 grey levels or more: no tag is lost at 50 on the simulated
            drive, the 1500-view sweep (4 light levels, up to 25 m) or the real photos
            (whose dimmest tag border differs by 60), while 60 loses 3 sweep views at
            20-25 m. Detections on the drive are bit-identical to those at 30.
        max_hamming: largest number of corrected bits accepted (tag36h11: 0-2).
        min_decision_margin: weakest decoding accepted (the library's decision margin).
        ring_refinement: rebuild the corners from the middle of the black border ring
            (:mod:`~semslam.perception.tag_refinement`), where an overexposed tag's
            clipped white cannot move them (not a C library setting).
    """

    quad_decimate: float = 2.0
    quad_sigma: float = 0.0
    refine_edges: bool = True
    decode_sharpening: float = 0.25
    min_white_black_diff: int = 50
    max_hamming: int = 1
    min_decision_margin: float = 0.0
    ring_refinement: bool = True


REFERENCE_SETTINGS = DetectorSettings(
    quad_decimate=1.0, refine_edges=False, min_white_black_diff=5, max_hamming=2,
    ring_refinement=False,
)
"""The settings of the AprilTag regression images' reference detections."""


@dataclass(frozen=True, eq=False)
class TagDetection:
    """One decoded tag in one image.

    Attributes:
        family: tag family.
        tag_id: decoded ID.
        corners: (4, 2) corner pixels (OpenCV convention), bottom-left, bottom-right,
            top-right, top-left of the upright tag's black square.
        centre: (2,) pixel of the tag centre (intersection of the diagonals).
        hamming: bits the decoder corrected.
        decision_margin: the decoder's margin (higher = clearer).
        image_size: (width, height) of the image, px ((0, 0): unknown).
        clipped: share of the pixels in the tag's bounding box at the top of the grey
            scale (>= 250): an overexposed tag's white bleeds into its black square,
            which then looks smaller (PnP ranges up to 1.5 % long).
        contrast: grey levels between the white quiet zone and the black border
            (:func:`~semslam.perception.tag_refinement.border_contrast`; NaN: unknown).
        ring_cells: per side, the white data cells at which the corner refinement read
            the border ring (:func:`~semslam.perception.tag_refinement.refine_corners_and_count`);
            empty when the corners were not refined (refinement off, or a family without
            the ring).
    """

    family: TagFamily
    tag_id: int
    corners: FloatArray
    centre: FloatArray
    hamming: int
    decision_margin: float
    image_size: tuple[int, int] = (0, 0)
    clipped: float = 0.0
    contrast: float = float("nan")
    ring_cells: tuple[int, ...] = ()

    @property
    def ring_sides(self) -> int:
        """Sides read on the border ring (0-4); -1 when the corners were not refined."""
        return sum(n > 0 for n in self.ring_cells) if self.ring_cells else -1

    @property
    def border_distance(self) -> float:
        """Pixels between the nearest corner and the image border (inf if unknown): a tag
        whose white quiet zone is cut by the border has biased corners."""
        w, h = self.image_size
        if w <= 0 or h <= 0:
            return math.inf
        c = np.asarray(self.corners, dtype=float)
        return float(min(c[:, 0].min(), c[:, 1].min(), w - 1 - c[:, 0].max(),
                         h - 1 - c[:, 1].max()))

    @property
    def cell_px(self) -> float:
        """Mean edge of one code cell in the image, px (the black square is
        ``CELLS[family]`` cells wide)."""
        c = np.asarray(self.corners, dtype=float)
        edges = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)
        return float(edges.mean()) / CELLS[self.family]


class _QuadThresholdParams(ctypes.Structure):
    _fields_ = [
        ("min_cluster_pixels", ctypes.c_int),
        ("max_nmaxima", ctypes.c_int),
        ("critical_rad", ctypes.c_float),
        ("cos_critical_rad", ctypes.c_float),
        ("max_line_fit_mse", ctypes.c_float),
        ("min_white_black_diff", ctypes.c_int),
        ("deglitch", ctypes.c_int),
    ]


class _DetectorStruct(ctypes.Structure):
    """The head of the C ``apriltag_detector`` (pupil-apriltags wraps only its first six
    fields; ``qtp`` follows them in AprilTag 3)."""

    _fields_ = [
        ("nthreads", ctypes.c_int),
        ("quad_decimate", ctypes.c_float),
        ("quad_sigma", ctypes.c_float),
        ("refine_edges", ctypes.c_int),
        ("decode_sharpening", ctypes.c_double),
        ("debug", ctypes.c_int),
        ("qtp", _QuadThresholdParams),
    ]


def parse_family(family: str | TagFamily) -> TagFamily:
    """``family`` as a :class:`TagFamily`, or a one-line :class:`PerceptionError`."""
    try:
        return TagFamily(str(family))
    except ValueError:
        known = ", ".join(f.value for f in TagFamily)
        raise PerceptionError(f"unknown tag family {family!r} (known: {known})") from None


@functools.cache
def _detector(family: TagFamily):
    from semslam.perception.apriltag_detector import shared_detector

    try:
        detector = shared_detector(family.value)
    except ImportError:
        raise PerceptionError("tag detection needs pupil-apriltags (pip install "
                              "pupil-apriltags)") from None
    return detector  # (shared_detector leaks it at exit rather than destroying it)


@functools.cache
def _thresholds(family: TagFamily) -> _QuadThresholdParams | None:
    """The detector's quad-threshold parameters, if the C struct has the expected layout
    (checked once against the library defaults that semslam never changes)."""
    head = ctypes.cast(_detector(family).tag_detector_ptr, ctypes.POINTER(_DetectorStruct))
    qtp = head.contents.qtp
    if qtp.max_nmaxima == 10 and abs(qtp.cos_critical_rad - np.cos(np.radians(10.0))) < 1e-5:
        return qtp
    log.warning("unexpected apriltag_detector layout: min_white_black_diff left at default")
    return None


def configured_detector(family: str | TagFamily, settings: DetectorSettings = DetectorSettings()):
    """The process-wide ``pupil_apriltags.Detector`` of ``family`` with ``settings`` applied
    (for callers that need the library's own outputs, e.g. its pose estimate)."""
    family = parse_family(family)
    detector = _detector(family)
    c = detector.tag_detector_ptr.contents
    c.nthreads = 1  # a second thread does not help on 1280 x 800 (measured)
    c.quad_decimate = float(settings.quad_decimate)
    c.quad_sigma = float(settings.quad_sigma)
    c.refine_edges = int(bool(settings.refine_edges))
    c.decode_sharpening = float(settings.decode_sharpening)
    qtp = _thresholds(family)
    if qtp is not None:
        qtp.min_white_black_diff = int(settings.min_white_black_diff)
    return detector


def as_gray(image: object) -> NDArray[np.uint8]:
    """A contiguous uint8 grey image from an (H, W) grey, (H, W, 3) BGR or (H, W, 4)
    BGRA uint8 array; anything else is a one-line :class:`PerceptionError`."""
    if not isinstance(image, np.ndarray):
        raise PerceptionError(f"image must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise PerceptionError(f"image must be uint8, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    if image.ndim != 2:
        raise PerceptionError(f"image must be (H, W) or (H, W, 3), got shape {image.shape}")
    if min(image.shape) < 8:
        raise PerceptionError(f"image is too small: {image.shape[1]} x {image.shape[0]} px")
    return np.ascontiguousarray(image)


MIN_DECIMATED_PX = 8
"""Smallest side (px) of the decimated image the AprilTag library is given."""


def detect_tags(
    image: object,
    family: str | TagFamily = TagFamily.TAG36H11,
    settings: DetectorSettings = DetectorSettings(),
) -> tuple[TagDetection, ...]:
    """Every tag of ``family`` in ``image``, sorted by ID.

    Args:
        image: (H, W) grey or (H, W, 3) BGR uint8 array.
        family: tag family name or :class:`TagFamily`.
        settings: detector settings.

    Returns:
        The detections (empty for a blank image).

    Raises:
        PerceptionError: a bad image, an unknown family, or a decimation that leaves
            fewer than :data:`MIN_DECIMATED_PX` pixels a side.
    """
    fam = parse_family(family)
    gray = as_gray(image)
    height, width = gray.shape
    k = settings.quad_decimate
    if k > 1 and min(width, height) / k < MIN_DECIMATED_PX:
        # the AprilTag library kills the process (no error) on such images
        raise PerceptionError(
            f"decimate {k:g} leaves a {int(width / k)} x {int(height / k)} px image "
            f"(needs at least {MIN_DECIMATED_PX} px a side)"
        )
    detector = configured_detector(fam, settings)
    out = []
    for d in detector.detect(gray):
        if d.hamming > settings.max_hamming or d.decision_margin < settings.min_decision_margin:
            continue
        corners = np.asarray(d.corners, dtype=float) - APRILTAG_PIXEL_OFFSET
        ring_cells: tuple[int, ...] = ()
        if settings.ring_refinement and fam in RING_FAMILIES:
            corners, ring_cells = refine_corners_and_count(gray, corners, CELLS[fam])
        contrast = (border_contrast(gray, corners, CELLS[fam]) if fam in RING_FAMILIES
                    else float("nan"))
        out.append(
            TagDetection(fam, int(d.tag_id), corners, quad_centre(corners), int(d.hamming),
                         float(d.decision_margin), (gray.shape[1], gray.shape[0]),
                         clipped_share(gray, corners), contrast, ring_cells)
        )
    return tuple(sorted(out, key=lambda t: t.tag_id))


def clipped_share(gray: NDArray[np.uint8], corners: FloatArray, level: int = 250) -> float:
    """Share of the pixels of ``gray`` in the bounding box of ``corners`` at ``level`` or
    above."""
    h, w = gray.shape
    x0, y0 = np.clip(np.floor(corners.min(axis=0)).astype(int), 0, [w - 1, h - 1])
    x1, y1 = np.clip(np.ceil(corners.max(axis=0)).astype(int) + 1, 1, [w, h])
    patch = gray[y0:y1, x0:x1]
    return float(np.count_nonzero(patch >= level)) / patch.size if patch.size else 0.0


def quad_centre(corners: FloatArray) -> FloatArray:
    """(2,) intersection of the diagonals of a (4, 2) quad: the image of the centre of a
    planar square under any homography."""
    p0, p1, p2, p3 = np.asarray(corners, dtype=float)
    d1, d2 = p2 - p0, p3 - p1
    den = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(den) < 1e-12:
        return np.asarray(corners, dtype=float).mean(axis=0)
    s = ((p1[0] - p0[0]) * d2[1] - (p1[1] - p0[1]) * d2[0]) / den
    return p0 + s * d1


__all__ = [
    "APRILTAG_PIXEL_OFFSET",
    "CELLS",
    "REFERENCE_SETTINGS",
    "RING_FAMILIES",
    "DetectorSettings",
    "PerceptionError",
    "TagDetection",
    "as_gray",
    "clipped_share",
    "configured_detector",
    "detect_tags",
    "parse_family",
    "quad_centre",
]
