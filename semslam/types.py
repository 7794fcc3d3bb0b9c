"""Core value types: observations in the vehicle frame and the semantic map.

All are frozen dataclasses holding numpy arrays (compare them through
their dict form in ``semslam.io``). Frames follow DESIGN.md: the map frame is
the garage's ground plane, the vehicle frame has x forward, y left, origin at
the vehicle centre on the ground (ISO 8855). Lengths in metres, angles in
radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from semslam.geometry import FloatArray, rotation_variance

MAX_ORIENTATION_VARIANCE = math.pi**2 / 3
"""rad^2: the variance of a heading spread evenly over a whole turn. A larger orientation
variance (a map's ``heading_variance`` of 1e12, or corner covariances of 1e12 m^2 on a small
slot) says no more than this, and the localizer's floor of the heading on it would leave its
innovation covariances singular."""


class SlotKind(StrEnum):
    """How a slot's entrance meets the aisle."""

    PERPENDICULAR = "perpendicular"
    PARALLEL = "parallel"
    SLANTED = "slanted"


class TagFamily(StrEnum):
    """AprilTag families that pupil-apriltags decodes."""

    TAG36H11 = "tag36h11"
    TAG25H9 = "tag25h9"
    TAG16H5 = "tag16h5"
    TAG_STANDARD41H12 = "tagStandard41h12"


class JunctionShape(StrEnum):
    """Shape of a painted junction at a slot's entrance corner (a marking point)."""

    T = "T"
    L = "L"


# --------------------------------------------------------------------------- observations


@dataclass(frozen=True, eq=False)
class SlotObservation:
    """A parking slot seen in one frame.

    Attributes:
        vCorners: (4, 2) corners in the vehicle frame, metres, in the order
            entrance-left, entrance-right, rear-right, rear-left as seen from the aisle.
        kind: perpendicular, parallel or slanted.
        label: painted slot ID as read ("B17"), or None when unreadable.
        label_confidence: probability in [0, 1] that ``label`` is right (0 without a label).
        confidence: probability in [0, 1] that the slot is real.
        corner_sigma: 1-sigma isotropic noise of each corner, metres, for a consumer that
            takes each frame's detections as independent (what the mapper and the filter
            weight it with).
        label_reads: frames that read ``label`` (1 for a single frame; more for the
            slot of several recent frames merged into one, :mod:`semslam.localization.recent`).
        corner_sigma_own: per corner (in the order of ``vCorners``), the 1-sigma per axis
            (m) of the part of its error that is this detection's own, independent of other
            frames' (None: all of ``corner_sigma``).
        corner_sigma_shared: per corner, the 1-sigma per axis (m) of the part that every
            detection of this slot shares, in the map frame: a detector's bias for that
            slot's paint, which more frames do not average away (None: none). A detector
            with such an error declares a ``corner_sigma`` larger than its own part, so
            that frames taken as independent do not make a map too sure; the mapper then
            exports corner covariances from these two (:mod:`semslam.mapping.shared_error`).
    """

    vCorners: FloatArray
    kind: SlotKind
    label: str | None
    label_confidence: float
    confidence: float
    corner_sigma: float
    label_reads: int = 1
    corner_sigma_own: tuple[float, float, float, float] | None = None
    corner_sigma_shared: tuple[float, float, float, float] | None = None


@dataclass(frozen=True, eq=False)
class TagObservation:
    """A fiducial tag seen in one frame.

    Attributes:
        family: tag family.
        tag_id: decoded ID.
        size: edge length of the tag's black square, metres.
        vTt: pose ``(x, y, yaw)`` of the tag centre in the vehicle frame; yaw
            is the direction of the tag's outward normal (from the face toward a viewer).
        height: height of the tag centre above the ground, metres.
        covariance: (3, 3) covariance of ``vTt`` (m^2, m*rad, rad^2).
    """

    family: TagFamily
    tag_id: int
    size: float
    vTt: FloatArray
    height: float
    covariance: FloatArray


@dataclass(frozen=True, eq=False)
class MarkingObservation:
    """A painted line segment seen in one frame.

    Attributes:
        vA, vB: (2,) end points in the vehicle frame, metres (the visible part only).
        width: painted line width, metres.
        confidence: probability in [0, 1] that the segment is a real marking.
        sigma: 1-sigma of each end point across the line, metres, as the detector
            declares it; None: the consumer's configured default (``marking_sigma``).
    """

    vA: FloatArray
    vB: FloatArray
    width: float
    confidence: float
    sigma: float | None = None


@dataclass(frozen=True, eq=False)
class FrameObservations:
    """Everything perceived at one frame time ``t`` (seconds)."""

    t: float
    slots: tuple[SlotObservation, ...] = ()
    tags: tuple[TagObservation, ...] = ()
    markings: tuple[MarkingObservation, ...] = ()


# --------------------------------------------------------------------------- map


@dataclass(frozen=True, eq=False)
class Slot:
    """A parking slot in the map frame.

    Attributes:
        id: integer ID unique within the map.
        label: painted slot ID ("B17") or None when never read.
        label_confidence: probability in [0, 1] that ``label`` is right.
        corners: (4, 2) corners in the map frame, metres (entrance-left,
            entrance-right, rear-right, rear-left as seen from the aisle).
        corner_covariances: (4, 2, 2) covariance of each corner, m^2.
        kind: perpendicular, parallel or slanted.
        observations: how many frames saw this slot.
        heading_variance: variance of the slot's orientation in the map, rad^2, from the
            joint covariance of its corners (their errors are correlated: they were
            measured together); None when the map does not say (see
            :attr:`orientation_variance`).
    """

    id: int
    label: str | None
    label_confidence: float
    corners: FloatArray
    corner_covariances: FloatArray
    kind: SlotKind
    observations: int = 0
    heading_variance: float | None = None

    @property
    def orientation_variance(self) -> float:
        """``heading_variance``, or, when the map gives none, the rotation variance of the
        corners taken as independent (larger: correlated corner errors partly cancel); at most
        :data:`MAX_ORIENTATION_VARIANCE` (a heading not known at all)."""
        if self.heading_variance is not None:
            return min(float(self.heading_variance), MAX_ORIENTATION_VARIANCE)
        corners = np.asarray(self.corners, dtype=float)
        if not np.ptp(corners, axis=0).any():  # a degenerate slot: no orientation to doubt
            return 0.0
        return min(rotation_variance(corners, self.corner_covariances), MAX_ORIENTATION_VARIANCE)


@dataclass(frozen=True, eq=False)
class Tag:
    """A fiducial tag in the map frame.

    Attributes:
        family, tag_id, size: as in :class:`TagObservation`.
        mTt: pose ``(x, y, yaw)`` of the tag centre in the map frame; yaw is
            the direction of the outward normal.
        height: height of the tag centre above the ground, metres.
        covariance: (3, 3) covariance of ``mTt``.
    """

    family: TagFamily
    tag_id: int
    size: float
    mTt: FloatArray
    height: float
    covariance: FloatArray


@dataclass(frozen=True, eq=False)
class Marking:
    """A painted line marking in the map frame: end points ``a``, ``b`` (2,), width, metres.

    ``sigma``: 1-sigma of the line's position across itself, metres, RMS along the segment
    (the mapper's marginal of the line; it holds the map's own drift, as a slot corner's
    covariance does); None: not known. The localizer takes it where it exceeds its
    configured ``marking_map_sigma`` (BENCHMARKS.md, Localizer, "Map lines' own uncertainty").

    ``across_covariance``: (2, 2) covariance, m^2, of the line's offsets across itself at
    ``a`` and at ``b``. A line's error is a shift and a turn, so its offset at the point a
    share ``lam`` of the way from ``a`` to ``b`` is ``(1 - lam) e_a + lam e_b``, and its
    variance there follows from this matrix alone
    (:func:`semslam.line_uncertainty.across_variance`); a long line
    is surer in its middle or at one end than at the other. ``sigma`` squared is that
    variance's mean along the segment. None: only ``sigma`` is known (the same everywhere)."""

    a: FloatArray
    b: FloatArray
    width: float
    sigma: float | None = None
    across_covariance: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class SemanticMap:
    """The map of a garage: slots, tags, markings and free-form metadata."""

    slots: tuple[Slot, ...] = ()
    tags: tuple[Tag, ...] = ()
    markings: tuple[Marking, ...] = ()
    metadata: dict[str, Any] = field(default_factory=dict)


def default_covariance(sigma: float, n: int = 2) -> FloatArray:
    """An isotropic n x n covariance with standard deviation ``sigma``."""
    return np.eye(n) * sigma * sigma
