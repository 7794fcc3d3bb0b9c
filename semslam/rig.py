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


TOPVIEW_BLACK = 8
"""Grey at or below which a top-view pixel is the view's black, where nothing is seen: the
ego box, ground no camera covers, padding outside the image (0, with room for compression
and for interpolation at its edge)."""


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


# --------------------------------------------------------------------------- fisheye rig


def fisheye_project(camera: Camera, cP: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Project (N, 3) camera-frame points through ``camera``'s equidistant fisheye model.

    OpenCV's ``cv2.fisheye.projectPoints`` formula (``theta_d = theta (1 + k1 theta^2 +
    k2 theta^4 + k3 theta^6 + k4 theta^8)``), but with ``theta = atan2(r, z)`` so that
    points beside and behind the camera (``z <= 0``, a lens wider than 180 deg) project
    too, where OpenCV's ``atan(r / z)`` folds them back.

    Returns:
        (N, 2) pixels (OpenCV convention) and (N,) angles from the optical axis (rad).
    """
    p = np.atleast_2d(np.asarray(cP, dtype=float))
    k = np.asarray(camera.D, dtype=float).ravel()
    r = np.hypot(p[:, 0], p[:, 1])
    theta = np.arctan2(r, p[:, 2])
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
    scale = np.divide(theta_d, r, out=np.zeros_like(r), where=r > 1e-12)
    xd, yd = p[:, 0] * scale, p[:, 1] * scale
    K = camera.K
    uv = np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)
    return uv, theta


def fisheye_unproject(camera: Camera, uv: ArrayLike, iterations: int = 20) -> FloatArray:
    """(N, 2) pixels to (N, 3) unit rays in the camera frame (the inverse of
    :func:`fisheye_project`, valid beyond 90 deg from the axis while ``theta_d`` grows
    with ``theta``; Newton on ``theta``, at most ``iterations`` steps)."""
    q = np.atleast_2d(np.asarray(uv, dtype=float))
    k = np.asarray(camera.D, dtype=float).ravel()
    K = camera.K
    yd = (q[:, 1] - K[1, 2]) / K[1, 1]
    xd = (q[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    theta_d = np.hypot(xd, yd)
    theta = theta_d.copy()
    for _ in range(iterations):
        t2 = theta * theta
        f = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) - theta_d
        df = 1.0 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
        step = f / df
        theta = theta - step
        if not np.any(np.abs(step) > 1e-12):
            break
    s = np.divide(np.sin(theta), theta_d, out=np.zeros_like(theta), where=theta_d > 1e-12)
    return np.stack([xd * s, yd * s, np.cos(theta)], axis=1)


def default_fisheye_cameras(size: tuple[int, int] = (960, 640)) -> dict[str, Camera]:
    """The simulator's surround-view fisheyes ``fisheye_front``, ``fisheye_rear``,
    ``fisheye_left``, ``fisheye_right`` (the names of frames.csv's columns).

    Equidistant lenses of about 190 deg horizontal field of view at ``size`` (w, h) with
    a mild Kannala-Brandt distortion; front camera in the bumper 0.7 m up tilted 28 deg
    down, rear camera above the number plate 0.9 m up tilted 32 deg down, side cameras
    under the mirrors 1.0 m up looking sideways 65 deg down.
    """
    w, h = size
    f = 0.925 * w / math.pi  # about 95 deg from the axis at the left and right borders
    K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    D = np.array([0.02, -0.006, 0.001, -0.0001])
    mounts = {
        "fisheye_front": ([1.8, 0.0, 0.7], 0.0, 28.0),
        "fisheye_rear": ([-1.8, 0.0, 0.9], math.pi, 32.0),
        "fisheye_left": ([0.5, 0.95, 1.0], math.pi / 2, 65.0),
        "fisheye_right": ([0.5, -0.95, 1.0], -math.pi / 2, 65.0),
    }
    return {
        name: Camera(
            name=name,
            model=CameraModel.FISHEYE,
            K=K.copy(),
            D=D.copy(),
            size=(w, h),
            T_vehicle_camera=camera_pose_matrix(pos, yaw, math.radians(pitch)),
        )
        for name, (pos, yaw, pitch) in mounts.items()
    }


def surround_rig() -> Rig:
    """:func:`default_rig` plus the four surround-view fisheyes of
    :func:`default_fisheye_cameras`."""
    rig = default_rig()
    return Rig(
        cameras={**rig.cameras, **default_fisheye_cameras()},
        topview=rig.topview,
        vehicle=rig.vehicle,
    )
