"""Residuals of semslam's landmark factors with analytic Jacobians (gtsam local coordinates).

Pose2 perturbations are gtsam's: ``pose.retract(d)`` moves by ``d = (dx, dy, dyaw)``
in the pose's own frame; Point2 perturbations are plain additions. Every
Jacobian here is checked numerically in tests/mapping/test_factors.py.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np

from semslam.geometry import FloatArray


def point_in_pose(
    pose: gtsam.Pose2, point: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``q = pose^-1 * point`` (vehicle-frame coordinates of a map point) and its Jacobians
    (2x3 w.r.t. the pose, 2x2 w.r.t. the point)."""
    c, s = np.cos(pose.theta()), np.sin(pose.theta())
    Rt = np.array([[c, s], [-s, c]])
    q = Rt @ (np.asarray(point) - np.array([pose.x(), pose.y()]))
    H_pose = np.array([[-1.0, 0.0, q[1]], [0.0, -1.0, -q[0]]])
    return q, H_pose, Rt


def slot_observation_residual(pose_key: int, corner_keys: Sequence[int], measured: FloatArray):
    """Residual of a slot seen from a keyframe: predicted minus measured vehicle-frame
    corners, (8,) = 4 corners x (x, y); ``measured`` is (4, 2) in the vehicle frame."""
    corner_keys = list(corner_keys)
    z = np.asarray(measured, dtype=float).reshape(8)

    def residual(values: gtsam.Values, want_jacobians: bool):
        pose = values.atPose2(pose_key)
        x, y, yaw = pose.x(), pose.y(), pose.theta()
        c, s = math.cos(yaw), math.sin(yaw)
        d = np.array([values.atPoint2(key) for key in corner_keys]) - (x, y)  # (4, 2)
        q = np.empty(8)  # vehicle-frame corners (x0, y0, x1, ...)
        q[0::2] = c * d[:, 0] + s * d[:, 1]
        q[1::2] = c * d[:, 1] - s * d[:, 0]
        r = q - z
        if not want_jacobians:
            return r, None
        H_pose = np.zeros((8, 3))
        H_pose[0::2, 0] = -1.0
        H_pose[1::2, 1] = -1.0
        H_pose[0::2, 2] = q[1::2]
        H_pose[1::2, 2] = -q[0::2]
        H = {pose_key: H_pose}
        for k, key in enumerate(corner_keys):
            block = np.zeros((8, 2))
            block[2 * k : 2 * k + 2] = ((c, s), (-s, c))
            H[key] = block
        return r, H

    return residual


def slot_shape_residual(corner_keys: Sequence[int], right_angles: bool, width: float, depth: float):
    """Residual of a slot's shape prior over its 4 corners (entrance-left, entrance-right,
    rear-right, rear-left): parallelogram closure ``c0 - c1 + c2 - c3`` (2, m), then, if
    ``right_angles``, the cosine of the entrance corner angle (1), then side lengths minus
    the priors ``width`` and ``depth`` (2, m). Residual dimension 5 (or 4)."""
    keys = list(corner_keys)

    def residual(values: gtsam.Values, want_jacobians: bool):
        c = [np.asarray(values.atPoint2(k)) for k in keys]
        I2 = np.eye(2)
        rows: list[FloatArray] = [c[0] - c[1] + c[2] - c[3]]
        J: list[list[FloatArray]] = [[I2, -I2, I2, -I2]]
        u, v = c[1] - c[0], c[3] - c[0]
        lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        uh, vh = u / lu, v / lv
        if right_angles:
            cos = float(uh @ vh)
            du = (vh - cos * uh) / lu  # d cos / d u
            dv = (uh - cos * vh) / lv
            rows.append(np.array([cos]))
            z = np.zeros((1, 2))
            J.append([-(du + dv)[None, :], du[None, :], z, dv[None, :]])
        rows.append(np.array([lu - width, lv - depth]))
        z2 = np.zeros(2)
        J.append([np.stack([-uh, -vh]), np.stack([uh, z2]), np.zeros((2, 2)), np.stack([z2, vh])])
        r = np.concatenate(rows)
        if not want_jacobians:
            return r, None
        return r, {key: np.vstack([blocks[k] for blocks in J]) for k, key in enumerate(keys)}

    return residual


def calibrated_odometry_residual(
    key_a: int, key_b: int, key_calibration: int, delta: FloatArray, J_calibration: FloatArray
):
    """Residual of odometry between keyframes a and b whose wheel-speed scale and gyro bias
    are estimated (a Vector2 variable ``(scale, bias)``, nominal (1, 0)).

    The predicted relative pose is ``p = delta + J_calibration @ (scale - 1, bias)``; the
    residual ``(R(p_yaw)' (rel_t - p_t), rel_yaw - p_yaw)`` with ``rel = a^-1 * b`` (3,).
    """
    delta = np.asarray(delta, dtype=float)
    Jk = np.asarray(J_calibration, dtype=float)

    def residual(values: gtsam.Values, want_jacobians: bool):
        a, b = values.atPose2(key_a), values.atPose2(key_b)
        k = np.asarray(values.atVector(key_calibration), dtype=float)
        p = delta + Jk @ np.array([k[0] - 1.0, k[1]])
        ca, sa = np.cos(a.theta()), np.sin(a.theta())
        Ra_t = np.array([[ca, sa], [-sa, ca]])
        rel_t = Ra_t @ np.array([b.x() - a.x(), b.y() - a.y()])
        rel_yaw = b.theta() - a.theta()
        cp, sp = np.cos(p[2]), np.sin(p[2])
        Rp_t = np.array([[cp, sp], [-sp, cp]])
        r_t = Rp_t @ (rel_t - p[:2])
        r = np.array([r_t[0], r_t[1], np.arctan2(np.sin(rel_yaw - p[2]), np.cos(rel_yaw - p[2]))])
        if not want_jacobians:
            return r, None
        d_rel_a = np.zeros((3, 3))
        d_rel_a[:2, :2] = -np.eye(2)
        d_rel_a[:2, 2] = [rel_t[1], -rel_t[0]]
        d_rel_a[2, 2] = -1.0
        c, s = np.cos(rel_yaw), np.sin(rel_yaw)
        d_rel_b = np.zeros((3, 3))
        d_rel_b[:2, :2] = [[c, -s], [s, c]]
        d_rel_b[2, 2] = 1.0
        d_r_rel = np.zeros((3, 3))
        d_r_rel[:2, :2] = Rp_t
        d_r_rel[2, 2] = 1.0
        d_r_p = np.zeros((3, 3))
        d_r_p[:2, :2] = -Rp_t
        d_r_p[:2, 2] = [r_t[1], -r_t[0]]
        d_r_p[2, 2] = -1.0
        return r, {key_a: d_r_rel @ d_rel_a, key_b: d_r_rel @ d_rel_b, key_calibration: d_r_p @ Jk}

    return residual


def line_normal(theta: float) -> tuple[FloatArray, FloatArray]:
    """Unit normal ``n = (cos theta, sin theta)`` of a line and its derivative."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([c, s]), np.array([-s, c])


def marking_observation_residual(pose_key: int, line_key: int, anchor: FloatArray,
                                 measured: FloatArray):
    """Residual of a painted line seen from a keyframe: the signed distances (m) of the
    detection's end points ``measured`` ((2, 2), vehicle frame) from the line landmark.

    The line is a Vector2 ``(theta, d)``: the points ``p`` with ``n(theta) . (p - anchor) =
    d``, the anchor a fixed map point near the line (it keeps theta and d well
    conditioned far from the origin). Only the distance across the line is measured: a
    detection may be a piece of the painted line, so its ends say nothing along it.
    """
    ax, ay = (float(v) for v in anchor)
    (ex0, ey0), (ex1, ey1) = (map(float, row) for row in np.asarray(measured, dtype=float))

    def residual(values: gtsam.Values, want_jacobians: bool):
        # floats, not 2-vectors: this runs for every painted line seen from every keyframe
        pose = values.atPose2(pose_key)
        theta, d = values.atVector(line_key)
        x, y, yaw = pose.x(), pose.y(), pose.theta()
        c, s = math.cos(yaw), math.sin(yaw)
        nx, ny = math.cos(theta), math.sin(theta)
        # end points in the map, relative to the anchor
        u0, v0 = x + c * ex0 - s * ey0 - ax, y + s * ex0 + c * ey0 - ay
        u1, v1 = x + c * ex1 - s * ey1 - ax, y + s * ex1 + c * ey1 - ay
        r = np.array([u0 * nx + v0 * ny - d, u1 * nx + v1 * ny - d])
        if not want_jacobians:
            return r, None
        m0, m1 = nx * c + ny * s, -nx * s + ny * c  # n^T R
        H_pose = np.array([[m0, m1, -ey0 * m0 + ex0 * m1], [m0, m1, -ey1 * m0 + ex1 * m1]])
        H_line = np.array([[-u0 * ny + v0 * nx, -1.0], [-u1 * ny + v1 * nx, -1.0]])
        return r, {pose_key: H_pose, line_key: H_line}

    return residual


def same_line_residual(key_a: int, anchor_a: FloatArray, key_b: int, anchor_b: FloatArray):
    """Residual tying two line landmarks (``(theta, d)`` with their anchors) into one: the
    angle between them (rad) and the distance (m) of line b's foot point
    ``anchor_b + d_b n_b`` from line a."""
    anchor_a = np.asarray(anchor_a, dtype=float)
    anchor_b = np.asarray(anchor_b, dtype=float)

    def residual(values: gtsam.Values, want_jacobians: bool):
        ta, da = np.asarray(values.atVector(key_a), dtype=float)
        tb, db = np.asarray(values.atVector(key_b), dtype=float)
        na, dna = line_normal(ta)
        nb, dnb = line_normal(tb)
        foot = anchor_b + db * nb
        angle = np.arctan2(np.sin(tb - ta), np.cos(tb - ta))
        # lines are undirected: a normal flipped by pi describes the same line
        flip = abs(angle) > np.pi / 2
        if flip:
            angle = np.arctan2(np.sin(tb - ta + np.pi), np.cos(tb - ta + np.pi))
        r = np.array([angle, (foot - anchor_a) @ na - da])
        if not want_jacobians:
            return r, None
        H_a = np.array([[-1.0, 0.0], [(foot - anchor_a) @ dna, -1.0]])
        H_b = np.array([[1.0, 0.0], [db * (dnb @ na), nb @ na]])
        return r, {key_a: H_a, key_b: H_b}

    return residual


def custom_factor(
    keys: Sequence[int], residual, noise: gtsam.noiseModel.Base
) -> gtsam.CustomFactor:
    """A gtsam CustomFactor from one of the residual functions above and a noise model
    (gtsam whitens, and applies a robust loss if ``noise`` is robust)."""
    keys = list(keys)

    def error_function(this: gtsam.CustomFactor, values: gtsam.Values, H):
        r, J = residual(values, H is not None)
        if H is not None:
            for n, key in enumerate(keys):
                H[n] = J[key]
        return r

    return gtsam.CustomFactor(noise, keys, error_function)
