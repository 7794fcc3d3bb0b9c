"""Fiducial tags from camera images: detection, pose by PnP, covariance, observations.

The steps, each in its own module:

1. :mod:`~semslam.perception.tag_detection`: AprilTag corners (pupil-apriltags), OpenCV
   pixel convention;
2. :mod:`~semslam.perception.undistort`: corners of a distorted (pinhole or fisheye)
   image moved to the ideal pinhole image with the same ``K``;
3. :mod:`~semslam.perception.tag_pose`: both IPPE poses, the ambiguity ratio, the
   position by PnP or TiEV's bearing-plus-range;
4. :mod:`~semslam.perception.tag_covariance`: the calibrated covariance;
5. here: :class:`TagEstimate` per tag (camera frame) and :class:`TagObservation` per
   usable tag (vehicle frame: through ``Camera.T_vehicle_camera``), dropping ambiguous
   tags, tags beyond the range limit (TiEV: 20 m), tags too small in the image and tags
   cut by the image border.

Tags hang upright: the tag's outward normal gives the observation's yaw. A tag's
metric size is an input (PnP's range scales with it): :func:`size_mismatches` reports
observations whose size differs from the map's instead of using them silently.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from semslam.geometry import FloatArray
from semslam.perception.tag_covariance import (
    TagNoiseModel,
    camera_covariance,
    flip_probability,
    min_side_px,
    side_px,
    vehicle_covariance,
    vehicle_pose_2d,
)
from semslam.perception.tag_detection import (
    DetectorSettings,
    PerceptionError,
    TagDetection,
    detect_tags,
)
from semslam.perception.tag_pose import PositionVariant, TagPose, estimate_pose
from semslam.perception.undistort import undistort_pixels
from semslam.rig import Camera
from semslam.types import Tag, TagFamily, TagObservation

if TYPE_CHECKING:
    from semslam.config import SemslamConfig


@dataclass(frozen=True)
class TagSettings:
    """What to detect and which tags to keep.

    Attributes:
        family: tag family.
        size: edge of the black square of every tag, metres, unless ``sizes`` names it.
        sizes: per-ID sizes (m), e.g. from the map (:func:`sizes_from_map`).
        variant: how the position is obtained (PnP measured the more accurate).
        max_ambiguity: tags whose IPPE ratio (best / other reprojection error) exceeds
            this are not turned into observations.
        max_flip_probability: nor are tags whose other IPPE solution is right with a
            larger probability (:func:`~semslam.perception.tag_covariance.flip_probability`):
            a flipped pose is off by about twice the viewing angle in yaw, which no
            Gaussian covariance can say without overstating every other tag's. 0.005 is
            the largest cut that keeps none of the calibration sweep's flips (seed 11,
            refitted flip model: 0 of 12; 0.01 kept 3, and a flip's NEES is in the
            hundreds, so one of them moves the mean of a drive's 60 observations by 5).
        range_limit: tags farther from the camera (m) are not turned into observations.
        min_side_px: smaller tags (square root of the image area, px) are not turned into
            observations: below about 18 px the corners move inwards by up to 1 px (the
            range comes out long) and range errors have heavy tails (simulator).
        min_border_cells: tags closer to the image border than this many code cells
            (their white quiet zone cut off) are not turned into observations.
        full_ring: also drop refined tags whose border ring could not be read on all
            four sides (a code with no white cell along a side: 24 of the 587 tag36h11
            codes). Off by default: their covariance is widened instead
            (``TagNoiseModel.unread_side_factor``); dropping them made the NEES of the
            simulated drives' tags consistent but lost a landmark, and the demo's map
            with it went from 0.046 to 0.053 m (BENCHMARKS.md).
        detector: AprilTag detector settings.
        noise: the covariance model.
    """

    family: TagFamily = TagFamily.TAG36H11
    size: float = 0.5
    sizes: Mapping[int, float] = field(default_factory=dict)
    variant: PositionVariant = PositionVariant.PNP
    max_ambiguity: float = 0.5
    max_flip_probability: float = 0.005
    range_limit: float = 20.0
    min_side_px: float = 18.0
    min_border_cells: float = 1.0
    full_ring: bool = False
    detector: DetectorSettings = field(default_factory=DetectorSettings)
    noise: TagNoiseModel = field(default_factory=TagNoiseModel)

    def size_of(self, tag_id: int) -> float:
        """The size (m) assumed for tag ``tag_id``."""
        return float(self.sizes.get(int(tag_id), self.size))


@dataclass(frozen=True, eq=False)
class TagEstimate:
    """One detected tag with its pose in the camera frame.

    Attributes:
        detection: the detector's output (corner pixels of the raw image).
        size: the size used for PnP, metres.
        corners: (4, 2) undistorted corner pixels (ideal pinhole with the camera's ``K``).
        pose: both IPPE solutions, the ambiguity and the chosen position.
        side_px: the tag's size in the (undistorted) image, px.
        flip_probability: probability that the other IPPE solution is the right one.
        covariance: (6, 6) of (position (m), rotation (rad)) in the camera frame.
    """

    detection: TagDetection
    size: float
    corners: FloatArray
    pose: TagPose
    side_px: float
    flip_probability: float
    covariance: FloatArray

    @property
    def range(self) -> float:
        """Distance from the camera centre to the tag centre, metres."""
        return float(np.linalg.norm(self.pose.position))


def _check_camera(camera: Camera) -> None:
    K = np.asarray(camera.K, dtype=float)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise PerceptionError(f"camera {camera.name}: K must be a 3x3 matrix, positive focals")


def estimate_tag(
    detection: TagDetection, camera: Camera, settings: TagSettings = TagSettings()
) -> TagEstimate | None:
    """The camera-frame pose and covariance of one detection (None if PnP fails)."""
    corners = undistort_pixels(detection.corners, camera.K, camera.D, camera.model)
    s = side_px(corners)
    if s < 1.0:
        return None
    size = settings.size_of(detection.tag_id)
    pose = estimate_pose(corners, size, camera.K, settings.variant)
    if pose is None:
        return None
    f = math.sqrt(float(camera.K[0, 0]) * float(camera.K[1, 1]))
    return TagEstimate(detection, size, corners, pose, s,
                       flip_probability(pose, s, settings.noise),
                       camera_covariance(pose, s, f, settings.noise, detection.clipped,
                                         min_side_px(corners), detection.contrast,
                                         detection.ring_sides))


def estimate_tags(
    image: object, camera: Camera, settings: TagSettings = TagSettings()
) -> tuple[TagEstimate, ...]:
    """Every tag of ``settings.family`` in one image of ``camera``, sorted by ID.

    Args:
        image: (H, W) grey or (H, W, 3) BGR uint8 image from ``camera``.
        camera: intrinsics and model (pinhole or fisheye); its extrinsics are not used.
        settings: family, sizes, variant, detector and noise model.

    Raises:
        PerceptionError: bad image, camera or family.
    """
    _check_camera(camera)
    estimates = (estimate_tag(d, camera, settings)
                 for d in detect_tags(image, settings.family, settings.detector))
    return tuple(e for e in estimates if e is not None)


def to_observations(
    estimates: Iterable[TagEstimate], camera: Camera, settings: TagSettings = TagSettings()
) -> tuple[TagObservation, ...]:
    """The usable estimates as vehicle-frame observations (see :func:`usable`)."""
    out = []
    for est in estimates:
        if not usable(est, settings):
            continue
        vTt, height = vehicle_pose_2d(est.pose.position, est.pose.rotation,
                                      camera.T_vehicle_camera)
        cov = vehicle_covariance(est.pose.rotation, est.covariance, camera.T_vehicle_camera)
        out.append(TagObservation(est.detection.family, est.detection.tag_id, est.size, vTt,
                                  height, cov))
    return tuple(out)


def usable(est: TagEstimate, settings: TagSettings = TagSettings()) -> bool:
    """Does ``est`` make an observation: unambiguous (``max_ambiguity``,
    ``max_flip_probability``), near enough (``range_limit``), large enough
    (``min_side_px``), clear of the image border (``min_border_cells``) and, with
    ``full_ring``, read on all four sides of its ring?"""
    det = est.detection
    return ((not settings.full_ring or det.ring_sides in (-1, 4))
            and est.pose.ambiguity <= settings.max_ambiguity
            and est.flip_probability <= settings.max_flip_probability
            and est.range <= settings.range_limit
            and est.side_px >= settings.min_side_px
            and det.border_distance >= settings.min_border_cells * det.cell_px)


def observe_tags(
    image: object, camera: Camera, settings: TagSettings = TagSettings()
) -> tuple[TagObservation, ...]:
    """The tag observations (vehicle frame) of one image of ``camera``."""
    return to_observations(estimate_tags(image, camera, settings), camera, settings)


def settings_from_config(config: SemslamConfig, **fields: Any) -> TagSettings:
    """:class:`TagSettings` with the range limit of ``config.mapping.tag_range_limit``
    (other fields from ``fields`` or the defaults)."""
    return replace(TagSettings(range_limit=float(config.mapping.tag_range_limit)), **fields)


def sizes_from_map(tags: Iterable[Tag]) -> dict[int, float]:
    """Per-ID tag sizes (m) of a map's tags, for :attr:`TagSettings.sizes`."""
    return {int(t.tag_id): float(t.size) for t in tags}


@dataclass(frozen=True)
class SizeMismatch:
    """A tag observed with another size than the map's (m): its pose is wrong by their ratio."""

    family: TagFamily
    tag_id: int
    observed: float
    mapped: float


def size_mismatches(
    observations: Iterable[TagObservation], tags: Iterable[Tag], rel_tol: float = 0.01
) -> tuple[SizeMismatch, ...]:
    """Observations of mapped tags (same family and ID) whose size differs from the map's
    by more than ``rel_tol``; tags absent from the map are not mismatches."""
    mapped = {(t.family, int(t.tag_id)): float(t.size) for t in tags}
    out = []
    for obs in observations:
        size = mapped.get((obs.family, int(obs.tag_id)))
        if size is not None and abs(obs.size - size) > rel_tol * size:
            out.append(SizeMismatch(obs.family, int(obs.tag_id), float(obs.size), size))
    return tuple(out)


__all__ = [
    "DetectorSettings",
    "PositionVariant",
    "SizeMismatch",
    "TagEstimate",
    "TagNoiseModel",
    "TagSettings",
    "estimate_tag",
    "estimate_tags",
    "observe_tags",
    "settings_from_config",
    "size_mismatches",
    "sizes_from_map",
    "to_observations",
    "usable",
]
