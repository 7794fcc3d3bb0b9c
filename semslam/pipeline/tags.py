"""`semslam tags`: AprilTag poses in image files (a standalone tool, like apriltag_ros
without ROS).

Reads each image (any format OpenCV reads, converted to 8-bit grey), runs
:func:`semslam.perception.tags.estimate_tags` with a camera built from the command's
intrinsics (quads searched at full resolution by default: photos come one at a time,
unlike the 15 ms budget of a front-camera frame), and returns the JSON document the
command prints::

    {"images": [{"image": PATH, "width": W, "height": H, "detections": [...]}]}

Per detection: ``family``, ``id``, ``size`` (m), ``corners`` (4 x 2 px as in the file,
OpenCV pixel centres, AprilTag order bottom-left, bottom-right, top-right, top-left),
``centre`` (px), ``position`` (x, y, z of the tag centre in the camera frame: x right,
y down, z forward, metres), ``rotation`` (3 x 3, camera from tag; tag x right, y down,
z into the tag), ``range`` (m), ``ambiguity`` (best / other IPPE reprojection error),
``reprojection_error_px``, ``alternative`` (the other IPPE solution), ``flip_probability``,
``covariance`` (6 x 6 over x, y, z (m) and the rotation error about the camera's x, y, z
(rad)), ``hamming``, ``decision_margin``, ``contrast`` (grey levels between the quiet zone
and the black border; null when unknown) and ``ring_sides_read`` (sides of the border
ring the corner refinement read, 0-4; -1 when not refined).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np

from semslam.io.images import image_files, read_image
from semslam.perception.tag_detection import DetectorSettings, PerceptionError, parse_family
from semslam.perception.tag_pose import PositionVariant
from semslam.perception.tags import TagEstimate, TagSettings, estimate_tags
from semslam.rig import Camera, CameraModel

MAX_PIXELS = 1e6
"""Largest focal length or principal-point coordinate accepted, px (beyond: a typo)."""

MIN_TAG_SIZE = 1e-3
"""Smallest tag edge accepted, metres (a millimetre; below it PnP loses all precision and
every detection fails silently)."""

MAX_TAG_SIZE = 100.0
"""Largest tag edge accepted, metres."""


def parse_numbers(text: str, name: str, counts: Sequence[int]) -> list[float]:
    """Comma-separated finite numbers, as many as one of ``counts``, or a one-line error."""
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise PerceptionError(f"{name}: expected comma-separated numbers, got {text!r}") from None
    if len(values) not in counts or not all(math.isfinite(v) for v in values):
        want = " or ".join(str(c) for c in counts)
        raise PerceptionError(f"{name}: expected {want} finite numbers, got {text!r}")
    return values


def make_camera(
    intrinsics: Sequence[float],
    distortion: Sequence[float] | None,
    fisheye: bool,
    size: tuple[int, int],
) -> Camera:
    """A camera at the origin from fx, fy, cx, cy and optional distortion coefficients."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    if not (fx >= 1 and fy >= 1):
        raise PerceptionError(
            f"--intrinsics: focal lengths must be at least 1 px, got {fx:g}, {fy:g}"
        )
    if max(fx, fy, abs(cx), abs(cy)) > MAX_PIXELS:
        raise PerceptionError(
            f"--intrinsics: {fx:g}, {fy:g}, {cx:g}, {cy:g} out of range (at most {MAX_PIXELS:g} px)"
        )
    if distortion is not None and max((abs(float(v)) for v in distortion), default=0) > MAX_PIXELS:
        raise PerceptionError(f"--distortion: a coefficient beyond {MAX_PIXELS:g} in magnitude")
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    D = np.asarray(distortion if distortion is not None else [], dtype=float)
    if fisheye and len(D) != 4:
        raise PerceptionError("--fisheye needs --distortion with 4 coefficients (k1..k4)")
    model = CameraModel.FISHEYE if fisheye else CameraModel.PINHOLE
    return Camera("cli", model, K, D, size, np.eye(4))


def _matrix(a: np.ndarray, digits: int) -> list:
    return np.round(np.asarray(a, dtype=float), digits).tolist()


def detection_json(est: TagEstimate) -> dict:
    """One estimate as the JSON object described in the module docstring."""
    pose, det = est.pose, est.detection
    alt = pose.other
    return {
        "family": det.family.value,
        "id": det.tag_id,
        "size": est.size,
        "corners": _matrix(det.corners, 3),
        "centre": _matrix(det.centre, 3),
        "position": _matrix(pose.position, 6),
        "rotation": _matrix(pose.rotation, 6),
        "range": round(est.range, 6),
        "ambiguity": round(pose.ambiguity, 4),
        "reprojection_error_px": round(pose.best.error, 4),
        "alternative": None
        if alt is None
        else {
            "position": _matrix(alt.t, 6),
            "rotation": _matrix(alt.R, 6),
            "reprojection_error_px": round(alt.error, 4),
        },
        "flip_probability": round(est.flip_probability, 4),
        "covariance": [[float(f"{v:.6g}") for v in row] for row in est.covariance],
        "hamming": det.hamming,
        "decision_margin": round(det.decision_margin, 2),
        "contrast": round(det.contrast, 1) if math.isfinite(det.contrast) else None,
        "ring_sides_read": det.ring_sides,
    }


def tags_in_images(
    images: Sequence[str | os.PathLike[str]],
    intrinsics: Sequence[float],
    tag_size: float,
    distortion: Sequence[float] | None = None,
    fisheye: bool = False,
    family: str = "tag36h11",
    variant: str = "pnp",
    decimate: float = 1.0,
) -> dict:
    """Detect tags and their poses in every image (a folder: its image files, by name); the
    JSON-ready result.

    Raises:
        FormatError: an image file is missing or unreadable, or a folder holds none.
        PerceptionError: bad intrinsics, distortion, tag size, family or variant.
    """
    if not (math.isfinite(tag_size) and MIN_TAG_SIZE <= tag_size <= MAX_TAG_SIZE):
        raise PerceptionError(
            f"--tag-size must be a number of metres from {MIN_TAG_SIZE:g} to {MAX_TAG_SIZE:g}, "
            f"got {tag_size:g}"
        )
    try:
        position_variant = PositionVariant(variant)
    except ValueError:
        raise PerceptionError(f"--variant must be pnp or tiev, got {variant!r}") from None
    if not (math.isfinite(decimate) and decimate >= 1.0):
        raise PerceptionError(f"--decimate must be a number >= 1, got {decimate}")
    settings = TagSettings(
        family=parse_family(family),
        size=float(tag_size),
        variant=position_variant,
        detector=DetectorSettings(quad_decimate=float(decimate)),
    )
    out = []
    files = [file for given in images for file in image_files(given)]
    for path in files:
        gray = read_image(path, grey=True)
        camera = make_camera(intrinsics, distortion, fisheye, (gray.shape[1], gray.shape[0]))
        try:
            estimates = estimate_tags(gray, camera, settings)
        except PerceptionError as e:
            raise PerceptionError(f"{path}: {e}") from None
        out.append(
            {
                "image": str(path),
                "width": int(gray.shape[1]),
                "height": int(gray.shape[0]),
                "detections": [detection_json(e) for e in estimates],
            }
        )
    return {"images": out}


__all__ = ["detection_json", "make_camera", "parse_numbers", "tags_in_images"]
