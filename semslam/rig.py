"""The sensor rig: cameras with intrinsics and extrinsics, the top-view grid, the vehicle.

Camera frame (OpenCV): x right, y down, z along the optical axis.
``T_vehicle_camera`` (4x4) maps camera-frame points to the vehicle frame.
The top view follows the ps2.0 convention: 600 x 600 px over 10 m x 10 m,
vehicle centre at the image centre, image up = vehicle forward, image left
= vehicle left, so ``x_v = (cy - v) * s`` and ``y_v = (cx - u) * s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike

from semslam.geometry import FloatArray


class CameraModel(StrEnum):
    """Projection model of a camera."""

    PINHOLE = "pinhole"
    FISHEYE = "fisheye"  # OpenCV's equidistant (Kannala-Brandt) model, 4 coefficients


@dataclass(frozen=True, eq=False)
class Camera:
    """One camera: name, model, 3x3 intrinsics ``K``, distortion ``D``, ``size`` (w, h) px,
    and ``T_vehicle_camera`` (4x4, metres)."""

    name: str
    model: CameraModel
    K: FloatArray
    D: FloatArray
    size: tuple[int, int]
    T_vehicle_camera: FloatArray

    def project_vehicle_points(self, vP: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Project (N, 3) vehicle-frame points (pinhole model, no distortion).

        Returns:
            (N, 2) pixel coordinates and (N,) depths along the optical axis (metres).
        """
        pts = np.atleast_2d(np.asarray(vP, dtype=float))
        T_cv = np.linalg.inv(self.T_vehicle_camera)
        cP = pts @ T_cv[:3, :3].T + T_cv[:3, 3]
        z = cP[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (cP[:, :2] / z[:, None]) * np.array([self.K[0, 0], self.K[1, 1]]) + np.array(
                [self.K[0, 2], self.K[1, 2]]
            )
        return uv, z


@dataclass(frozen=True)
class TopviewSpec:
    """The bird's-eye image grid (ps2.0 convention).

    Attributes:
        size_px: image is ``size_px`` x ``size_px`` pixels.
        metres_per_px: ground resolution (1/60 m for ps2.0).
        ego_length_m, ego_width_m: the black box drawn over the ego car,
            centred on the vehicle centre (ps2.0: 225 x 103 px).
    """

    size_px: int = 600
    metres_per_px: float = 1.0 / 60.0
    ego_length_m: float = 3.75
    ego_width_m: float = 1.72

    @property
    def centre_px(self) -> float:
        """Pixel coordinate of the vehicle centre on both axes."""
        return (self.size_px - 1) / 2.0

    @property
    def half_extent_m(self) -> float:
        """Half the side of the covered square, metres."""
        return self.size_px * self.metres_per_px / 2.0

    def vehicle_to_pixel(self, vP: ArrayLike) -> FloatArray:
        """(N, 2) vehicle-frame points (m) to (N, 2) pixels (u right, v down)."""
        p = np.atleast_2d(np.asarray(vP, dtype=float))
        c, s = self.centre_px, self.metres_per_px
        return np.stack([c - p[:, 1] / s, c - p[:, 0] / s], axis=1)

    def pixel_to_vehicle(self, uv: ArrayLike) -> FloatArray:
        """(N, 2) pixels to (N, 2) vehicle-frame points (m)."""
        q = np.atleast_2d(np.asarray(uv, dtype=float))
        c, s = self.centre_px, self.metres_per_px
        return np.stack([(c - q[:, 1]) * s, (c - q[:, 0]) * s], axis=1)


@dataclass(frozen=True)
class VehicleSpec:
    """Ego vehicle footprint, metres (a small city car like ps2.0's)."""

    length: float = 3.6
    width: float = 1.6
    wheelbase: float = 2.3


@dataclass(frozen=True, eq=False)
class Rig:
    """All cameras by name, the top-view grid and the vehicle."""

    cameras: dict[str, Camera] = field(default_factory=dict)
    topview: TopviewSpec = field(default_factory=TopviewSpec)
    vehicle: VehicleSpec = field(default_factory=VehicleSpec)


def camera_pose_matrix(
    position: ArrayLike, yaw: float = 0.0, pitch_down: float = 0.0
) -> FloatArray:
    """``T_vehicle_camera`` for a camera at ``position`` (vehicle frame, m) looking
    along heading ``yaw`` (rad, CCW from vehicle x) tilted down by ``pitch_down`` (rad)."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch_down), math.sin(pitch_down)
    z_c = np.array([cp * cy, cp * sy, -sp])  # optical axis
    x_c = np.array([sy, -cy, 0.0])  # image right
    y_c = np.cross(z_c, x_c)  # image down
    T = np.eye(4)
    T[:3, :3] = np.stack([x_c, y_c, z_c], axis=1)
    T[:3, 3] = np.asarray(position, dtype=float)
    return T


def default_front_camera() -> Camera:
    """The simulator's front camera: 1280 x 800 pinhole, 90 deg horizontal field of view,
    behind the windscreen 1.35 m up, tilted 3 deg down."""
    w, h = 1280, 800
    f = 640.0
    K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    return Camera(
        name="front",
        model=CameraModel.PINHOLE,
        K=K,
        D=np.zeros(5),
        size=(w, h),
        T_vehicle_camera=camera_pose_matrix([1.2, 0.0, 1.35], 0.0, math.radians(3.0)),
    )


def default_rig() -> Rig:
    """The simulator's rig: the front camera and the ps2.0 top view."""
    return Rig(cameras={"front": default_front_camera()})
