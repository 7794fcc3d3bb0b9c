"""A square tag's pose from its four corner pixels: IPPE, both solutions kept.

Frames: the tag frame is AprilTag's (origin at the centre of the black square, x to
the right and y down on the upright tag, z into the tag, away from a viewer); the
camera frame is OpenCV's. ``R`` and ``t`` map tag-frame points into the camera frame
(metres). Pixels follow ``K``'s convention and must be undistorted already
(:mod:`semslam.perception.undistort`).

A planar square seen small or head-on has two poses that explain its corners almost
equally well (the tag tilted towards or away from the viewer). ``cv2.solvePnPGeneric``
with ``SOLVEPNP_IPPE_SQUARE`` returns both; each is polished by Levenberg-Marquardt
and the ambiguity is the ratio of their reprojection errors (best / other, in [0, 1];
near 1 the rotation cannot be trusted, the position still can).

Position variants:
- ``pnp``: the tag centre from PnP's translation (the default: measured the more
  accurate, on the simulator and on the real rotation set; BENCHMARKS.md);
- ``tiev`` (TiEV): the bearing from the ray through the tag-centre pixel (the
  diagonals' intersection), the range ``|t|`` from PnP.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import cv2
import numpy as np
from numpy.typing import ArrayLike

from semslam.geometry import FloatArray
from semslam.perception.tag_detection import PerceptionError, quad_centre

_LM_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-10)
_SAME_MINIMUM = np.radians(0.5)  # two polished solutions this close are one minimum


class PositionVariant(StrEnum):
    """Where the tag centre comes from (see the module docstring)."""

    PNP = "pnp"
    TIEV = "tiev"


@dataclass(frozen=True, eq=False)
class PnPSolution:
    """One pose of the tag: ``R`` (3, 3) and ``t`` (3,) camera from tag, metres; ``error``
    the RMS reprojection error of the four corners, px."""

    R: FloatArray
    t: FloatArray
    error: float


@dataclass(frozen=True, eq=False)
class TagPose:
    """A tag's pose in the camera frame.

    Attributes:
        position: (3,) tag centre in the camera frame, metres (by ``variant``).
        rotation: (3, 3) camera from tag (the best solution's).
        best, other: the two IPPE solutions, best first (``other`` None if IPPE gave one).
        ambiguity: ``best.error / other.error`` in [0, 1] (0: unambiguous; 1 when the
            corners are fitted exactly by both, which only happens without noise).
        variant: how ``position`` was obtained.
    """

    position: FloatArray
    rotation: FloatArray
    best: PnPSolution
    other: PnPSolution | None
    ambiguity: float
    variant: PositionVariant


def square_object_points(size: float) -> FloatArray:
    """(4, 3) black-square corners in the tag frame, in AprilTag's (and IPPE_SQUARE's)
    order: bottom-left, bottom-right, top-right, top-left."""
    h = size / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def _rms(obj: FloatArray, uv: FloatArray, rvec: FloatArray, tvec: FloatArray,
         K: FloatArray) -> float:
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv) ** 2, axis=1))))


def solve_ippe(corners: ArrayLike, size: float, K: ArrayLike) -> list[PnPSolution]:
    """Both IPPE poses of a square of edge ``size`` (m) from its (4, 2) undistorted corner
    pixels, best (lowest reprojection error) first; each is polished by Levenberg-Marquardt
    unless that would slide it into the other's minimum (then it stays as IPPE gave it).
    Solutions with the tag behind the camera are dropped."""
    uv = np.asarray(corners, dtype=float).reshape(4, 2)
    K_ = np.asarray(K, dtype=float)
    if not np.isfinite(uv).all():
        raise PerceptionError("tag corners must be finite")
    if not (np.isfinite(size) and size > 0):
        raise PerceptionError(f"tag size must be positive, got {size}")
    obj = square_object_points(size)
    ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, uv, K_, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    raw = [(r.reshape(3, 1), t.reshape(3, 1)) for r, t in zip(rvecs, tvecs, strict=True)]
    polished = [cv2.solvePnPRefineLM(obj, uv, K_, None, r.copy(), t.copy(), criteria=_LM_CRITERIA)
                for r, t in (raw if ok else [])]
    out: list[PnPSolution] = []
    for (r1, t1), (r0, t0) in zip(polished, raw[: len(polished)], strict=True):
        rvec, tvec = np.asarray(r1, dtype=float), np.asarray(t1, dtype=float)
        R = np.asarray(cv2.Rodrigues(rvec)[0], dtype=float)
        if any(_angle(R, s.R) < _SAME_MINIMUM for s in out):
            rvec, tvec = np.asarray(r0, dtype=float), np.asarray(t0, dtype=float)
            R = np.asarray(cv2.Rodrigues(rvec)[0], dtype=float)
        if tvec[2, 0] <= 0:
            continue
        out.append(PnPSolution(R, tvec.ravel(), _rms(obj, uv, rvec, tvec, K_)))
    return sorted(out, key=lambda s: s.error)


def _angle(Ra: FloatArray, Rb: FloatArray) -> float:
    """Angle (rad) of the rotation between two rotation matrices."""
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0)))


def centre_ray(centre_px: ArrayLike, K: ArrayLike) -> FloatArray:
    """(3,) unit ray in the camera frame through an undistorted pixel."""
    ray = np.linalg.solve(np.asarray(K, dtype=float), np.array([*np.asarray(centre_px), 1.0]))
    return ray / np.linalg.norm(ray)


def estimate_pose(
    corners: ArrayLike,
    size: float,
    K: ArrayLike,
    variant: PositionVariant = PositionVariant.PNP,
) -> TagPose | None:
    """The pose of a tag from its (4, 2) undistorted corner pixels (None if PnP fails).

    Args:
        corners: corner pixels in AprilTag's order (see :func:`square_object_points`).
        size: edge of the black square, metres.
        K: (3, 3) intrinsics of the undistorted pixels.
        variant: how the position is obtained.
    """
    solutions = solve_ippe(corners, size, K)
    if not solutions:
        return None
    best = solutions[0]
    other = solutions[1] if len(solutions) > 1 else None
    if other is None:
        ambiguity = 0.0
    elif other.error <= 1e-12:
        ambiguity = 1.0
    else:
        ambiguity = min(1.0, best.error / other.error)
    position = best.t
    if variant is PositionVariant.TIEV:
        position = centre_ray(quad_centre(np.asarray(corners, dtype=float)), K) * float(
            np.linalg.norm(best.t)
        )
    return TagPose(position, best.R, best, other, ambiguity, PositionVariant(variant))


__all__ = [
    "PnPSolution",
    "PositionVariant",
    "TagPose",
    "centre_ray",
    "estimate_pose",
    "solve_ippe",
    "square_object_points",
]
