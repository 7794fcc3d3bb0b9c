"""The ps2.0 top view built from a surround rig's fisheye images by one remap.

As Houben builds it: not undistort-then-homography per camera, but one table, computed
once from the rig calibration, that sends every top-view pixel straight to the fisheye
pixel that sees its ground point. For each top-view pixel the table holds its ground
point in the vehicle frame (``z = 0``), the camera that sees it best (smallest angle from
the optical axis among the cameras that have it inside their image and inside the lens's
field of view: the best-resolved view, and seams fall half-way between the axes), and
that camera's pixel by the fisheye projection (:func:`semslam.rig.fisheye_project`,
OpenCV's equidistant model extended past 90 deg). The cameras' images are laid side by
side in one atlas, so a top view is one copy into the atlas and one ``cv2.remap`` with a
fixed-point (``CV_16SC2``) table; the ego box and ground no camera sees stay black.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import cv2
import numpy as np

from semslam.errors import PerceptionError
from semslam.geometry import FloatArray
from semslam.rig import Camera, CameraModel, Rig, TopviewSpec, fisheye_project

DEFAULT_CAMERAS = ("fisheye_front", "fisheye_rear", "fisheye_left", "fisheye_right")
_PINHOLE_MAX_ANGLE = math.radians(80.0)


def _fisheye_limit(D: FloatArray) -> float:
    """The angle from the axis up to which ``theta_d(theta)`` grows (at most pi): beyond
    it the model folds back and a pixel would stand for two directions."""
    k = np.asarray(D, dtype=float).ravel()
    t = np.linspace(0.0, math.pi, 3142)
    t2 = t * t
    slope = 1.0 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
    bad = np.nonzero(slope <= 0.0)[0]
    return float(t[bad[0]]) if len(bad) else math.pi


def _project(camera: Camera, vP: FloatArray) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """(N, 3) vehicle-frame points to (N, 2) pixels of ``camera``, (N,) angles from its
    optical axis and (N,) whether the model is valid there (inside the lens's field of
    view for a fisheye, well in front for a pinhole)."""
    T = np.asarray(camera.T_vehicle_camera, dtype=float)
    R, o = T[:3, :3], T[:3, 3]
    q = vP - o
    # R^T q, broadcast (no BLAS call)
    cP = q[:, :1] * R[0] + q[:, 1:2] * R[1] + q[:, 2:] * R[2]
    if camera.model is CameraModel.FISHEYE:
        uv, theta = fisheye_project(camera, cP)
        return uv, theta, theta < _fisheye_limit(camera.D)
    theta = np.arctan2(np.hypot(cP[:, 0], cP[:, 1]), cP[:, 2])
    ok = theta < _PINHOLE_MAX_ANGLE
    uv = np.full((len(cP), 2), -1.0)
    if ok.any():
        D = np.asarray(camera.D, dtype=float).ravel()
        pts, _ = cv2.projectPoints(
            cP[ok].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.asarray(camera.K, float), D
        )
        uv[ok] = pts.reshape(-1, 2)
    return uv, theta, ok


_MAX_ATLAS_PX = 32767
"""``cv2.remap`` with a 16-bit fixed-point table reads a source narrower than this."""


class TopviewBuilder:
    """Builds top views from a rig's camera images with one precomputed remap table.

    Args:
        rig: the calibration (cameras by name).
        spec: the top-view grid; the rig's own (``rig.topview``) by default.
        cameras: names of the rig's cameras to stitch, in atlas order.

    Attributes:
        spec: the top-view grid.
        cameras: the stitched cameras' names.
        ground: (n, n, 2) ground point of each top-view pixel, vehicle frame (m).
        camera_index: (n, n) int8 index into ``cameras`` of the camera each pixel is
            taken from, -1 for the ego box and ground no camera sees.
        camera_pixels: (n, n, 2) float32 pixel (OpenCV convention) in that camera,
            NaN where ``camera_index`` is -1.

    Raises:
        PerceptionError: a camera is missing from the rig, or names repeat.
    """

    def __init__(
        self,
        rig: Rig,
        spec: TopviewSpec | None = None,
        cameras: tuple[str, ...] | list[str] = DEFAULT_CAMERAS,
    ) -> None:
        self.spec = spec = spec or rig.topview
        self.cameras = tuple(cameras)
        if not self.cameras:
            raise PerceptionError("top view: no cameras given")
        if len(set(self.cameras)) != len(self.cameras):
            raise PerceptionError(f"top view: repeated camera names in {list(self.cameras)}")
        for name in self.cameras:
            if name not in rig.cameras:
                raise PerceptionError(
                    f"top view: camera '{name}' is not in the rig (has {sorted(rig.cameras)})"
                )
        cams = [rig.cameras[name] for name in self.cameras]
        self._sizes = [(int(c.size[0]), int(c.size[1])) for c in cams]
        self._offsets = np.concatenate([[0], np.cumsum([w for w, _ in self._sizes])]).astype(int)
        self._atlas_shape = (max(h for _, h in self._sizes), int(self._offsets[-1]))
        if max(self._atlas_shape) >= _MAX_ATLAS_PX:  # OpenCV's fixed-point remap table
            raise PerceptionError(
                f"top view: the cameras' images side by side are {self._atlas_shape[1]} x "
                f"{self._atlas_shape[0]} px; the remap takes less than {_MAX_ATLAS_PX} px a side"
            )

        n = spec.size_px
        vv, uu = np.mgrid[0:n, 0:n].astype(np.float64)
        ground = spec.pixel_to_vehicle(np.stack([uu.ravel(), vv.ravel()], axis=1))
        vP = np.column_stack([ground, np.zeros(len(ground))])
        best = np.full(len(vP), np.inf)
        index = np.full(len(vP), -1, np.int8)
        pix = np.full((len(vP), 2), np.nan)
        for i, (cam, (w, h)) in enumerate(zip(cams, self._sizes, strict=True)):
            uv, theta, ok = _project(cam, vP)
            # strictly inside, so that bilinear sampling never reads the next camera
            ok &= (uv[:, 0] >= 0.0) & (uv[:, 0] < w - 1) & (uv[:, 1] >= 0.0) & (uv[:, 1] < h - 1)
            take = ok & (theta < best)
            best[take] = theta[take]
            index[take] = i
            pix[take] = uv[take]
        x, y = ground[:, 0], ground[:, 1]
        ego = (np.abs(x) <= spec.ego_length_m / 2.0) & (np.abs(y) <= spec.ego_width_m / 2.0)
        index[ego] = -1
        pix[ego] = np.nan
        self.ground = ground.reshape(n, n, 2)
        self.camera_index = index.reshape(n, n)
        self.camera_pixels = pix.astype(np.float32).reshape(n, n, 2)
        seen = index >= 0
        mx = np.full(len(vP), -1.0, np.float32)
        my = np.full(len(vP), -1.0, np.float32)
        mx[seen] = pix[seen, 0] + self._offsets[index[seen]]
        my[seen] = pix[seen, 1]
        self._maps = cv2.convertMaps(mx.reshape(n, n), my.reshape(n, n), cv2.CV_16SC2)

    def build(self, images: Mapping[str, np.ndarray]) -> np.ndarray:
        """The (n, n, 3) uint8 BGR top view from the cameras' images (by camera name).

        Raises:
            PerceptionError: a camera's image is missing or not a (h, w, 3) uint8 array of
                that camera's size.
        """
        if not isinstance(images, Mapping):
            raise PerceptionError(
                f"top view: expected images by camera name, got {type(images).__name__}"
            )
        atlas = np.zeros((*self._atlas_shape, 3), np.uint8)
        for i, (name, (w, h)) in enumerate(zip(self.cameras, self._sizes, strict=True)):
            img = images.get(name)
            if img is None:
                raise PerceptionError(f"top view: no image for camera '{name}'")
            shape = getattr(img, "shape", None)
            dtype = getattr(img, "dtype", None)
            if not isinstance(img, np.ndarray) or shape != (h, w, 3) or dtype != np.uint8:
                got = f"{shape} {dtype}" if isinstance(img, np.ndarray) else type(img).__name__
                raise PerceptionError(
                    f"top view: camera '{name}' image must be ({h}, {w}, 3) uint8, got {got}"
                )
            x0 = int(self._offsets[i])
            atlas[:h, x0 : x0 + w] = img
        return cv2.remap(
            atlas,
            self._maps[0],
            self._maps[1],
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=(0, 0, 0),
        )


__all__ = ["DEFAULT_CAMERAS", "TopviewBuilder"]
