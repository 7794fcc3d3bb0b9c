"""How uncertain a tag pose from PnP is: a covariance from range, viewing angle and the
tag's size in pixels, calibrated on the simulator.

Every term is an effective pixel error ``g(s) = sqrt(floor^2 + (knee / s)^2)`` (px;
``s`` the square root of the tag's area in the image, px) turned into metres or
radians by the geometry of a square seen at range ``rho`` (m) by a camera of focal
length ``f`` (px):

- range along the line of sight: ``sigma_rho^2 = (rho / s * g_range(s))^2 + (e_rho rho)^2``
  (``e_rho``: a relative floor, what a tag printed 0.3 % too small or a focal length
  0.3 % off would cause);
- across it (each of the two directions):
  ``sigma_perp^2 = (rho / f * g_bearing(s))^2 + (e_bearing rho)^2`` (``e_bearing``: an
  angular floor, rad, what a principal point off by a fraction of a pixel causes);
- the tag's normal tilting about its own x / y axis:
  ``g_tilt(s) / (s * sqrt((c * s / f)^2 + sin(theta)^2))`` with ``theta`` the viewing
  angle about that axis (foreshortening informs a turned tag, only perspective a
  head-on one, so head-on and small tags get uncertain normals);
- turning in its own plane: ``g_roll(s) / s``.

A tag that stands out less from its quiet zone has every pixel error multiplied by
``(contrast_ref / contrast) ^ contrast_power`` (:func:`contrast_factor`; ``contrast`` the
grey levels between quiet zone and black border,
:func:`~semslam.perception.tag_refinement.border_contrast`): image noise moves an edge by
noise / contrast. The calibration sweep spans the light levels of a garage (contrast
60-220) since the tags along a drive are lit less than one under a lamp.

A code with no white data cell along one side of its border ring (24 of the 587
tag36h11 codes) keeps AprilTag's edge there, with the overexposure bleed the ring
refinement removes elsewhere: its pixel errors are multiplied by ``unread_side_factor``
(1.52: on one sweep of 16 such codes and one of 16 codes read on every side, same
views, the mean NEES was 12.7 against 5.5, a ratio of 2.3 in variance).

An overexposed tag (clipped white around it) has every pixel error multiplied by
``sqrt(1 + c_clip^2 + (k_clip / s_min)^2)``, ``s_min`` its shortest side in the image
(px): the corners come from the middle of the border ring
(:mod:`~semslam.perception.tag_refinement`), which the clipped white cannot move, but
where the ring or the white data cells beside it are only a pixel or two wide (a small
or steeply turned tag) the clipped side of the ring is not the mirror of the other.

The covariance is that of the chosen IPPE solution (:mod:`semslam.perception.tag_pose`)
*given that it is the right one*. The other solution is right with probability
``w = 1 / (1 + exp(-(a + b ln(ambiguity) + c ln(s))))`` (:func:`flip_probability`;
measured: about 0.1 % of the views with an ambiguity ratio below 0.1 are flipped, 5-10 %
of those between 0.4 and 0.5, more of the small ones). A flip turns the yaw by about
twice the viewing angle, which no Gaussian can hold without overstating every other
tag's yaw: moment-matching it in (``+ w d d^T``, as before) gave a mean NEES of 2.33
with the yaw alone at 0.30 on the evaluation sweep. So tags with ``w`` above
``TagSettings.max_flip_probability`` are not turned into observations.

The constants below were fitted by maximum likelihood on 3,000 simulated views of a
0.5 m tag (1.5-25 m, +-70 deg, 4 light levels;
``benchmarks/bench_tags.py --calibrate-only``), keeping
the views that become observations (:func:`semslam.perception.tags.usable`): each term
on its own error first, then the terms of the 2D observation together on its
vehicle-frame (x, y, yaw) errors. The simulator's image is cleaner than a real camera's
(corner errors of 0.03-0.13 px after the ring refinement) and its intrinsics are exact:
for a real camera, scale every pixel error by ``scale`` and set the floors
(``range_rel_floor``, ``bearing_floor_rad``) from its calibration and the tags' print
tolerance.

Covariances are over ``(x, y, z, rx, ry, rz)`` of the tag in the camera frame: the
position error (m) and the rotation error ``R_true = exp([r]x) R`` (rad, camera axes).
:func:`vehicle_covariance` maps them to the ``(x, y, yaw)`` of a ``TagObservation``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from semslam.geometry import FloatArray
from semslam.perception.tag_pose import PositionVariant, TagPose


@dataclass(frozen=True)
class TagNoiseModel:
    """The covariance model's constants (pixel errors in px; see the module docstring)."""

    range_floor_px: float = 0.02006
    range_knee_px2: float = 0.5775
    range_rel_floor: float = 3.143e-06
    clipped_knee_px: float = 16.14
    clipped_floor: float = 1.228
    clipped_share: float = 0.1
    bearing_floor_px: float = 0.008039
    bearing_knee_px2: float = 0.6166
    bearing_floor_rad: float = 1.641e-07
    tiev_bearing_floor_px: float = 0.01243
    tiev_bearing_knee_px2: float = 0.7892
    tiev_bearing_floor_rad: float = 2.818e-09
    tilt_floor_px: float = 0.02267
    tilt_knee_px2: float = 1.2
    tilt_perspective: float = 0.3853
    roll_floor_px: float = 0.0186
    roll_knee_px2: float = 2.263
    flip_logit_offset: float = 2.339
    flip_logit_ambiguity: float = 2.593
    flip_logit_size: float = -0.9501
    contrast_ref: float = 170.0
    contrast_power: float = 0.2495
    unread_side_factor: float = 1.52
    scale: float = 1.0


def _g(floor: float, knee: float, s: float) -> float:
    return math.sqrt(floor * floor + (knee / s) ** 2)


def side_px(corners: ArrayLike) -> float:
    """Square root of the area (px^2) of the (4, 2) corner quad: the tag's size in pixels."""
    return math.sqrt(abs(cv2.contourArea(np.asarray(corners, dtype=np.float32).reshape(4, 2))))


def min_side_px(corners: ArrayLike) -> float:
    """The shortest side of the (4, 2) corner quad, px."""
    c = np.asarray(corners, dtype=float).reshape(4, 2)
    return float(np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1).min())


def flip_probability(pose: TagPose, s: float, model: TagNoiseModel = TagNoiseModel()) -> float:
    """Probability that the other IPPE solution is the right one: logistic in the logs of
    the ambiguity ratio and of the tag's size ``s`` (px), calibrated on the simulator."""
    if pose.other is None or pose.ambiguity <= 0.0:
        return 0.0
    z = (model.flip_logit_offset + model.flip_logit_ambiguity * math.log(pose.ambiguity)
         + model.flip_logit_size * math.log(s))
    return 1.0 / (1.0 + math.exp(-z)) if z > -50.0 else 0.0


def contrast_factor(contrast: float, model: TagNoiseModel = TagNoiseModel()) -> float:
    """What every pixel error is multiplied by for a tag whose quiet zone and black border
    differ by ``contrast`` grey levels: ``(contrast_ref / contrast) ^ contrast_power``
    (contrast clipped to 20-255; 1 when unknown)."""
    if not math.isfinite(contrast) or model.contrast_power == 0.0:
        return 1.0
    return (model.contrast_ref / min(max(contrast, 20.0), 255.0)) ** model.contrast_power


def camera_covariance(
    pose: TagPose, s: float, f: float, model: TagNoiseModel = TagNoiseModel(),
    clipped: float = 0.0, min_side: float | None = None, contrast: float = math.nan,
    ring_sides: int = -1,
) -> FloatArray:
    """(6, 6) covariance of ``(position, rotation)`` in the camera frame (m, rad).

    Args:
        pose: the tag's pose (its ``position`` and ``rotation`` are the estimate).
        s: the tag's size in the image, px (:func:`side_px`).
        f: focal length, px.
        model: the constants.
        clipped: share of clipped (overexposed) pixels around the tag; above
            ``model.clipped_share`` every pixel error grows by
            ``sqrt(1 + clipped_floor^2 + (clipped_knee_px / min_side)^2)``.
        min_side: the tag's shortest side in the image, px (``s`` if None).
        contrast: grey levels between the tag's quiet zone and black border
            (:func:`contrast_factor`; NaN: unknown, no factor).
        ring_sides: sides of the border ring the corner refinement read (0-3: every pixel
            error times ``unread_side_factor``; 4, or -1 for corners not refined: 1).
    """
    p = np.asarray(pose.position, dtype=float)
    R = np.asarray(pose.rotation, dtype=float)
    rho = float(np.linalg.norm(p))
    u = p / rho
    k = model.scale * contrast_factor(contrast, model)
    if 0 <= ring_sides < 4:
        k *= model.unread_side_factor
    if clipped > model.clipped_share:
        knee = model.clipped_knee_px / (s if min_side is None else min_side)
        k *= math.sqrt(1.0 + model.clipped_floor**2 + knee**2)
    if pose.variant is PositionVariant.TIEV:
        g_perp = _g(model.tiev_bearing_floor_px, model.tiev_bearing_knee_px2, s)
        floor_perp = model.tiev_bearing_floor_rad
    else:
        g_perp = _g(model.bearing_floor_px, model.bearing_knee_px2, s)
        floor_perp = model.bearing_floor_rad
    s_rho = rho * math.hypot(k * _g(model.range_floor_px, model.range_knee_px2, s) / s,
                             model.range_rel_floor)
    s_perp = rho * math.hypot(k * g_perp / f, floor_perp)
    cov = np.zeros((6, 6))
    uu = np.outer(u, u)
    cov[:3, :3] = s_rho**2 * uu + s_perp**2 * (np.eye(3) - uu)
    # viewing angles about the tag's own x and y axes (line of sight in the tag frame)
    v = R.T @ -u
    theta_x = math.atan2(v[1], -v[2])
    theta_y = math.atan2(v[0], -v[2])
    g_tilt = k * _g(model.tilt_floor_px, model.tilt_knee_px2, s)
    persp = (model.tilt_perspective * s / f) ** 2
    s_x = g_tilt / (s * math.sqrt(persp + math.sin(theta_x) ** 2))
    s_y = g_tilt / (s * math.sqrt(persp + math.sin(theta_y) ** 2))
    s_z = k * _g(model.roll_floor_px, model.roll_knee_px2, s) / s
    cov[3:, 3:] = R @ np.diag([s_x**2, s_y**2, s_z**2]) @ R.T
    return 0.5 * (cov + cov.T)


def vehicle_pose_2d(
    position: ArrayLike, rotation: ArrayLike, T_vehicle_camera: ArrayLike
) -> tuple[FloatArray, float]:
    """The tag's ``vTt = (x, y, yaw)`` (yaw: heading of its outward normal) and the height
    of its centre (m), from its camera-frame pose and the camera's extrinsics."""
    T = np.asarray(T_vehicle_camera, dtype=float)
    pv = T[:3, :3] @ np.asarray(position, dtype=float) + T[:3, 3]
    nv = T[:3, :3] @ -np.asarray(rotation, dtype=float)[:, 2]
    return np.array([pv[0], pv[1], math.atan2(nv[1], nv[0])]), float(pv[2])


def vehicle_covariance(
    rotation: ArrayLike, cov6: ArrayLike, T_vehicle_camera: ArrayLike
) -> FloatArray:
    """(3, 3) covariance of ``vTt = (x, y, yaw)`` from the (6, 6) camera-frame covariance
    (first order: ``J cov6 J^T``)."""
    T = np.asarray(T_vehicle_camera, dtype=float)
    R_vc = T[:3, :3]
    n_c = -np.asarray(rotation, dtype=float)[:, 2]
    n_v = R_vc @ n_c
    h2 = n_v[0] ** 2 + n_v[1] ** 2
    if h2 < 1e-12:  # a tag lying flat has no heading
        h2 = 1e-12
    dyaw_dnv = np.array([-n_v[1], n_v[0], 0.0]) / h2
    skew = np.array([[0.0, -n_c[2], n_c[1]], [n_c[2], 0.0, -n_c[0]], [-n_c[1], n_c[0], 0.0]])
    J = np.zeros((3, 6))
    J[:2, :3] = R_vc[:2, :]
    J[2, 3:] = dyaw_dnv @ R_vc @ -skew
    out = J @ np.asarray(cov6, dtype=float) @ J.T
    return 0.5 * (out + out.T)


__all__ = [
    "TagNoiseModel",
    "camera_covariance",
    "contrast_factor",
    "flip_probability",
    "min_side_px",
    "side_px",
    "vehicle_covariance",
    "vehicle_pose_2d",
]
