"""Pixel undistortion for the rig's camera models (AprilTag itself has none).

Both directions map between a camera's raw image and the ideal pinhole image with
the same ``K`` (OpenCV pixel convention, pixel centres at integers):

- pinhole: OpenCV's radial-tangential model, ``D`` with 4, 5, 8, 12 or 14 coefficients
  (all zero: nothing to do);
- fisheye: OpenCV's equidistant (Kannala-Brandt) model, ``D`` with 4 coefficients.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike

from semslam.errors import PerceptionError
from semslam.geometry import FloatArray
from semslam.rig import CameraModel

_PINHOLE_D = (4, 5, 8, 12, 14)
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)


def _checked(K: ArrayLike, D: ArrayLike, model: CameraModel) -> tuple[FloatArray, FloatArray]:
    K_ = np.asarray(K, dtype=float)
    D_ = np.asarray(D, dtype=float).ravel()
    if K_.shape != (3, 3) or not np.isfinite(K_).all() or K_[0, 0] <= 0 or K_[1, 1] <= 0:
        raise PerceptionError("K must be a finite 3x3 matrix with positive focal lengths")
    if not np.isfinite(D_).all():
        raise PerceptionError("distortion coefficients must be finite")
    if model is CameraModel.FISHEYE and len(D_) != 4:
        raise PerceptionError(f"a fisheye camera takes 4 distortion coefficients, got {len(D_)}")
    if model is CameraModel.PINHOLE and len(D_) not in (0, *_PINHOLE_D):
        raise PerceptionError(
            f"a pinhole camera takes 4, 5, 8, 12 or 14 distortion coefficients, got {len(D_)}"
        )
    return K_, D_


def undistort_pixels(
    uv: ArrayLike, K: ArrayLike, D: ArrayLike, model: CameraModel = CameraModel.PINHOLE
) -> FloatArray:
    """(N, 2) raw pixels to the (N, 2) pixels an ideal pinhole camera with ``K`` sees."""
    K_, D_ = _checked(K, D, model)
    pts = np.asarray(uv, dtype=float).reshape(-1, 1, 2)
    if not len(pts) or _identity(model, D_):
        return pts.reshape(-1, 2).copy()
    if model is CameraModel.FISHEYE:
        out = cv2.fisheye.undistortPoints(pts, K_, D_, P=K_, criteria=_CRITERIA)
    else:
        out = cv2.undistortPoints(pts, K_, D_, R=None, P=K_, criteria=_CRITERIA)
    return np.asarray(out, dtype=float).reshape(-1, 2)


def distort_pixels(
    uv: ArrayLike, K: ArrayLike, D: ArrayLike, model: CameraModel = CameraModel.PINHOLE
) -> FloatArray:
    """(N, 2) ideal pinhole pixels (same ``K``) to the (N, 2) raw pixels of the camera."""
    K_, D_ = _checked(K, D, model)
    pts = np.asarray(uv, dtype=float).reshape(-1, 2)
    if not len(pts) or _identity(model, D_):
        return pts.copy()
    xy = (pts - K_[:2, 2]) / np.array([K_[0, 0], K_[1, 1]])  # normalised, skew ignored
    if model is CameraModel.FISHEYE:
        out = cv2.fisheye.distortPoints(xy.reshape(-1, 1, 2), K_, D_)
        return np.asarray(out, dtype=float).reshape(-1, 2)
    obj = np.column_stack([xy, np.ones(len(xy))])
    out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K_, D_)
    return np.asarray(out, dtype=float).reshape(-1, 2)


def _identity(model: CameraModel, D: FloatArray) -> bool:
    """A pinhole without distortion; a fisheye is never one (r = f theta even at D = 0)."""
    return model is CameraModel.PINHOLE and not D.any()


__all__ = ["distort_pixels", "undistort_pixels"]
