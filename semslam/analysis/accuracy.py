"""Predicted positioning accuracy from a map (Hofmann 2011), before any drive.

At a vehicle pose ``mTv = (x, y, yaw)`` the landmarks the sensors would see give the
observation equations of one frame; stacked, their Jacobian ``A`` with respect to the
pose and the weight matrix ``P`` (inverse measurement covariance, map uncertainty
included) give the single-frame covariance ``Q_xx = (A^T P A)^-1`` (3 x 3: x, y in metres,
yaw in radians). Along a route, a Kalman filter with an odometry / IMU ``grade`` bridges
the stretches where a frame alone cannot fix the pose: prediction with the grade's speed
and yaw-rate noise, update with the frame's information ``A^T P A``.

What the sensors see (:class:`SensorModel`): slot corners inside the top view (10 m x
10 m around the car, outside the ego box), tags in the front camera's field of view within
the range limit and facing the car, painted lines inside the top view (their clipped end
points, across the line only). Occlusion by parked cars is not modelled, so the figures
are what the map allows at best. Pure numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semslam.geometry import FloatArray, clip_segment, rotation
from semslam.localization.measurements import point_jacobian
from semslam.types import SemanticMap

UNOBSERVABLE = math.inf
"""Reported sigma where a frame (or the filter) cannot fix the pose."""


@dataclass(frozen=True)
class SensorModel:
    """What the car sees and how well (defaults: the simulator's noisy sensors).

    Attributes:
        topview_half_m: half side of the top view, m (ps2.0: 5 m).
        ego_half_length_m, ego_half_width_m: the blind ego box, m.
        corner_sigma: slot corner noise per axis, m.
        marking_sigma: painted line end point across the line, m.
        tag_range_limit: farthest tag used, m.
        tag_fov_deg: front camera horizontal field of view, deg.
        tag_max_incidence_deg: largest angle between the tag normal and the view ray.
        tag_range_sigma_abs, tag_range_sigma_rel: range noise ``abs + rel * r``, m.
        tag_bearing_sigma_deg, tag_yaw_sigma_deg: bearing and tag-yaw noise, deg.
        camera_x: the front camera's position ahead of the vehicle centre, m.
    """

    topview_half_m: float = 5.0
    ego_half_length_m: float = 1.8
    ego_half_width_m: float = 0.8
    corner_sigma: float = 0.05
    marking_sigma: float = 0.05
    tag_range_limit: float = 20.0
    tag_fov_deg: float = 90.0
    tag_max_incidence_deg: float = 70.0
    tag_range_sigma_abs: float = 0.02
    tag_range_sigma_rel: float = 0.01
    tag_bearing_sigma_deg: float = 0.3
    tag_yaw_sigma_deg: float = 3.0
    camera_x: float = 1.2


@dataclass(frozen=True)
class OdometryGrade:
    """Dead-reckoning quality in Hofmann's terms: speed noise (m/s), the heading's initial
    uncertainty (deg) and yaw-rate noise (deg/s). Speed and rate noise are taken as white
    with a 1 s correlation: the variance they add grows as sigma^2 * t (t in seconds)."""

    name: str
    speed_sigma: float
    heading_sigma_deg: float
    rate_sigma_deg: float


GRADES = {
    "precise": OdometryGrade("precise", 0.02, 0.01, 0.001),
    "automotive": OdometryGrade("automotive", 0.1, 0.1, 0.005),
}
"""Hofmann's two grades: a precise IMU and automotive sensors."""


def _in_topview(vP: FloatArray, s: SensorModel) -> np.ndarray:
    inside = (np.abs(vP) <= s.topview_half_m).all(axis=1)
    ego = (np.abs(vP[:, 0]) <= s.ego_half_length_m) & (np.abs(vP[:, 1]) <= s.ego_half_width_m)
    return inside & ~ego


class MapGeometry:
    """The map's landmarks as arrays, ready for many poses."""

    def __init__(self, semantic_map: SemanticMap) -> None:
        slots = semantic_map.slots
        self.corners = np.array([c for s in slots for c in s.corners], float).reshape(-1, 2)
        self.corner_cov = np.array([c for s in slots for c in s.corner_covariances], float).reshape(
            -1, 2, 2
        )
        tags = semantic_map.tags
        self.tags = np.array([t.mTt for t in tags], float).reshape(-1, 3)
        self.tag_cov = np.array([t.covariance for t in tags], float).reshape(-1, 3, 3)
        self.lines = np.array([[m.a, m.b] for m in semantic_map.markings], float).reshape(-1, 2, 2)

    def bounds(self, margin: float = 2.0) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of every landmark, widened by ``margin`` metres."""
        pts = np.concatenate([self.corners, self.tags[:, :2], self.lines.reshape(-1, 2)])
        if not len(pts):
            return (-margin, -margin, margin, margin)
        lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def frame_information(
    geometry: MapGeometry, pose: FloatArray, sensors: SensorModel = SensorModel()
) -> tuple[FloatArray, dict[str, int]]:
    """``A^T P A`` (3 x 3) of one frame at ``pose`` and the count of each landmark kind used.

    Map covariances add to the measurement covariance (projected into the vehicle frame).
    """
    pose = np.asarray(pose, float)
    R = rotation(pose[2])
    info = np.zeros((3, 3))
    counts = {"corners": 0, "tags": 0, "lines": 0}
    # slot corners: vP = R^T (mP - t)
    if len(geometry.corners):
        vP = (geometry.corners - pose[:2]) @ R
        seen = np.nonzero(_in_topview(vP, sensors))[0]
        if len(seen):
            H = point_jacobian(pose, geometry.corners[seen]).reshape(len(seen), 2, 3)
            cov = R.T @ geometry.corner_cov[seen] @ R + np.eye(2) * sensors.corner_sigma**2
            W = np.linalg.inv(cov)
            info += np.einsum("kai,kab,kbj->ij", H, W, H)
            counts["corners"] = len(seen)
    # tags: vTt = mTv^-1 mTt, in the camera's field of view, facing it
    if len(geometry.tags):
        tag_info, seen_tags = tag_information(pose[None], geometry.tags, geometry.tag_cov, sensors)
        info += tag_info[0]
        counts["tags"] = int(seen_tags[0])
    # painted lines: the visible part's end points, across the line only
    half = sensors.topview_half_m
    for a, b in geometry.lines:
        va, vb = (np.array([a, b]) - pose[:2]) @ R
        clipped = clip_segment(va, vb, -half, half)
        if clipped is None:
            continue
        ends = np.array(clipped, float).reshape(2, 2)
        d = b - a
        length = float(np.hypot(*d))
        if length < 1e-6 or float(np.hypot(*(ends[1] - ends[0]))) < 0.3:
            continue
        n = np.array([-d[1], d[0]]) / length
        for vE in ends:  # d(n . (t + R vE)) / d(x, y, yaw)
            h = np.array([n[0], n[1], _yaw_row(n, R, vE)])
            info += np.outer(h, h) / sensors.marking_sigma**2
        counts["lines"] += 1
    return info, counts


def tag_information(
    poses: FloatArray,
    tags: FloatArray,
    tag_cov: FloatArray | None = None,
    sensors: SensorModel = SensorModel(),
) -> tuple[FloatArray, np.ndarray]:
    """Information (N, 3, 3) that tags ``mTt`` (T, 3) give at each of ``poses`` (N, 3), and
    how many are seen (N,): those within the range limit, inside the front camera's
    field of view and facing it. Range noise along the view ray, bearing noise across,
    yaw noise on the tag's yaw; the tags' map covariance (T, 3, 3) adds (vehicle frame)."""
    poses = np.asarray(poses, float).reshape(-1, 3)
    tags = np.asarray(tags, float).reshape(-1, 3)
    tag_cov = np.zeros((len(tags), 3, 3)) if tag_cov is None else np.asarray(tag_cov, float)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    dx = tags[None, :, 0] - poses[:, :1]
    dy = tags[None, :, 1] - poses[:, 1:2]
    vx, vy = c * dx + s * dy, -s * dx + c * dy  # tag centre in the vehicle frame (N, T)
    rx, ry = vx - sensors.camera_x, vy
    r = np.hypot(rx, ry)
    bearing = np.arctan2(ry, rx)
    facing = np.cos(tags[None, :, 2] - poses[:, 2:3] - bearing - np.pi)
    seen = (
        (r <= sensors.tag_range_limit)
        & (r >= 0.5)
        & (np.abs(bearing) <= np.radians(sensors.tag_fov_deg) / 2)
        & (facing >= math.cos(math.radians(sensors.tag_max_incidence_deg)))
    )
    info = np.zeros((len(poses), 3, 3))
    n_idx, t_idx = np.nonzero(seen)
    if not len(n_idx):
        return info, seen.sum(axis=1)
    rr = r[n_idx, t_idx]
    cb, sb_ = np.cos(bearing[n_idx, t_idx]), np.sin(bearing[n_idx, t_idx])
    sr = sensors.tag_range_sigma_abs + sensors.tag_range_sigma_rel * rr
    st = math.radians(sensors.tag_bearing_sigma_deg) * rr
    C = np.zeros((len(n_idx), 3, 3))
    C[:, 0, 0] = sr**2 * cb**2 + st**2 * sb_**2
    C[:, 1, 1] = sr**2 * sb_**2 + st**2 * cb**2
    C[:, 0, 1] = C[:, 1, 0] = (sr**2 - st**2) * cb * sb_
    C[:, 2, 2] = math.radians(sensors.tag_yaw_sigma_deg) ** 2
    Rt = np.zeros((len(n_idx), 3, 3))
    cc, ss = c[n_idx, 0], s[n_idx, 0]
    Rt[:, 0, 0], Rt[:, 0, 1], Rt[:, 1, 0], Rt[:, 1, 1] = cc, -ss, ss, cc
    Rt[:, 2, 2] = 1.0
    C += np.transpose(Rt, (0, 2, 1)) @ tag_cov[t_idx] @ Rt
    # Jacobian of (R^T (t_tag - t), yaw_tag - yaw) with respect to (x, y, yaw)
    H = np.zeros((len(n_idx), 3, 3))
    ddx, ddy = dx[n_idx, t_idx], dy[n_idx, t_idx]
    H[:, 0, 0], H[:, 0, 1] = -cc, -ss
    H[:, 1, 0], H[:, 1, 1] = ss, -cc
    H[:, 0, 2] = -ss * ddx + cc * ddy
    H[:, 1, 2] = -cc * ddx - ss * ddy
    H[:, 2, 2] = -1.0
    contrib = np.transpose(H, (0, 2, 1)) @ np.linalg.inv(C) @ H
    np.add.at(info, n_idx, contrib)
    return info, seen.sum(axis=1)


def _yaw_row(n: FloatArray, R: FloatArray, vE: FloatArray) -> float:
    """d(n . R(yaw) vE) / d(yaw) = n . (J R vE), J the 90 deg rotation."""
    w = R @ vE
    return float(n[0] * -w[1] + n[1] * w[0])


def position_sigma(cov: FloatArray) -> float:
    """Square root of the largest eigenvalue of the 2 x 2 position block (m): the semi-axis
    of the 1-sigma error ellipse; infinite where the pose is not observable."""
    if not np.all(np.isfinite(cov)):
        return UNOBSERVABLE
    return float(math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2]).max(), 0.0)))


def single_frame_covariance(info: FloatArray) -> FloatArray:
    """``(A^T P A)^-1``, or a matrix of infinities where the frame cannot fix the pose."""
    w = np.linalg.eigvalsh(info)
    if w.min() <= 1e-9 * max(w.max(), 1e-300):
        return np.full((3, 3), UNOBSERVABLE)
    return np.linalg.inv(info)


def route_information(
    geometry: MapGeometry, poses: FloatArray, sensors: SensorModel = SensorModel()
) -> tuple[FloatArray, dict[str, np.ndarray]]:
    """:func:`frame_information` at every pose: (N, 3, 3) and the counts per pose."""
    poses = np.asarray(poses, float).reshape(-1, 3)
    infos = np.zeros((len(poses), 3, 3))
    counts = {k: np.zeros(len(poses), int) for k in ("corners", "tags", "lines")}
    for k, pose in enumerate(poses):
        infos[k], seen = frame_information(geometry, pose, sensors)
        for key, value in seen.items():
            counts[key][k] = value
    return infos, counts


def filter_route(
    infos: FloatArray,
    poses: FloatArray,
    times: FloatArray,
    grade: OdometryGrade = GRADES["automotive"],
) -> FloatArray:
    """Filtered pose covariance (N, 3, 3) along a route from the frames' information.

    The filter starts from the first frame's own covariance (or 1 m / 5 deg if it has
    none, the heading never better than the grade's) and predicts between poses with
    the grade: speed noise along the travelled step, yaw-rate noise on the heading (see
    :class:`OdometryGrade`), heading uncertainty carried into the position by the step.
    """
    poses = np.asarray(poses, float).reshape(-1, 3)
    times = np.asarray(times, float).reshape(-1)
    out = np.zeros((len(poses), 3, 3))
    sv2, sw2 = grade.speed_sigma**2, math.radians(grade.rate_sigma_deg) ** 2
    first = single_frame_covariance(infos[0])
    P = first.copy() if np.all(np.isfinite(first)) else np.diag([1.0, 1.0, math.radians(5) ** 2])
    P[2, 2] = max(P[2, 2], math.radians(grade.heading_sigma_deg) ** 2)
    out[0] = P
    F = np.eye(3)
    for k in range(1, len(poses)):
        dt = max(float(times[k] - times[k - 1]), 1e-6)
        step = poses[k, :2] - poses[k - 1, :2]
        c, s = math.cos(poses[k - 1, 2]), math.sin(poses[k - 1, 2])
        F[0, 2], F[1, 2] = -step[1], step[0]
        P = F @ P @ F.T
        P[:2, :2] += sv2 * dt * np.array([[c * c, c * s], [c * s, s * s]])
        P[2, 2] += sw2 * dt
        if infos[k].any():
            P = np.linalg.inv(np.linalg.inv(P) + infos[k])
        P = (P + P.T) / 2
        out[k] = P
    return out


def predicted_along_route(
    geometry: MapGeometry,
    poses: FloatArray,
    times: FloatArray,
    grade: OdometryGrade = GRADES["automotive"],
    sensors: SensorModel = SensorModel(),
) -> dict[str, FloatArray]:
    """Single-frame and filtered (:func:`filter_route`) predicted accuracy at every pose.

    Returns:
        ``single_sigma`` and ``filtered_sigma`` (m, position semi-axis), ``single_yaw_deg``
        and ``filtered_yaw_deg`` (1-sigma), ``corners``, ``tags``, ``lines`` (counts seen).
    """
    infos, counts = route_information(geometry, poses, sensors)
    filtered = filter_route(infos, poses, times, grade)
    singles = [single_frame_covariance(info) for info in infos]
    return {
        "single_sigma": np.array([position_sigma(q) for q in singles]),
        "filtered_sigma": np.array([position_sigma(p) for p in filtered]),
        "single_yaw_deg": np.degrees(np.sqrt(np.array([q[2, 2] for q in singles]))),
        "filtered_yaw_deg": np.degrees(np.sqrt(filtered[:, 2, 2])),
        **{k: v.astype(float) for k, v in counts.items()},
    }


def predicted_on_grid(
    geometry: MapGeometry,
    step: float = 1.0,
    headings_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0),
    sensors: SensorModel = SensorModel(),
    bounds: tuple[float, float, float, float] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Single-frame position sigma (m) on a grid over ``bounds`` (xmin, ymin, xmax, ymax;
    default: the map's landmarks plus 2 m): the worst over ``headings_deg`` at each cell.
    Returns the grid's x (W,), y (H,) and sigma (H, W)."""
    x0, y0, x1, y1 = bounds or geometry.bounds()
    xs = np.arange(x0, x1 + 1e-9, step)
    ys = np.arange(y0, y1 + 1e-9, step)
    sigma = np.zeros((len(ys), len(xs)))
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            worst = 0.0
            for h in headings_deg:
                info, _ = frame_information(geometry, np.array([x, y, math.radians(h)]), sensors)
                worst = max(worst, position_sigma(single_frame_covariance(info)))
            sigma[i, j] = worst
    return xs, ys, sigma


def worst_stretches(
    distance: FloatArray, sigma: FloatArray, threshold: float, limit: int = 5
) -> list[dict[str, float]]:
    """Contiguous stretches of a route where ``sigma`` exceeds ``threshold`` (m), longest
    first: start and end (metres along the route), length and the worst sigma."""
    above = np.asarray(sigma) > threshold
    out = []
    k = 0
    while k < len(above):
        if not above[k]:
            k += 1
            continue
        j = k
        while j + 1 < len(above) and above[j + 1]:
            j += 1
        out.append(
            {
                "start_m": float(distance[k]),
                "end_m": float(distance[j]),
                "length_m": float(distance[j] - distance[k]),
                "worst_sigma_m": float(np.max(sigma[k : j + 1])),
            }
        )
        k = j + 1
    out.sort(key=lambda s: (-s["length_m"], -s["worst_sigma_m"]))
    return out[:limit]


__all__ = [
    "GRADES",
    "UNOBSERVABLE",
    "MapGeometry",
    "OdometryGrade",
    "SensorModel",
    "frame_information",
    "filter_route",
    "position_sigma",
    "predicted_along_route",
    "predicted_on_grid",
    "route_information",
    "single_frame_covariance",
    "tag_information",
    "worst_stretches",
]
