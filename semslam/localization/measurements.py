"""Measurement models of the localizer: what the car should see from a pose, and how that
changes with the pose.

Every model predicts a stacked measurement vector from vehicle poses ``mTv = (x, y, yaw)``
in the map frame (metres, radians). ``predict`` is vectorised over a (K, 3) batch of poses
(the sigma-point update evaluates 11 at once); ``jacobian`` is the analytic (m, 3)
derivative at one pose (the EKF update; checked numerically in the tests). The filter pads
the Jacobian with zeros for the speed and yaw-rate columns of its state.

- :class:`PointMeasurement`: map points (slot corners, metres) seen in the vehicle frame,
  ``vP = R(yaw)^T (mP - t)``.
- :class:`TagMeasurement`: a tag pose seen in the vehicle frame, ``vTt = mTv^-1 * mTt``.
- :class:`MarkingMeasurement`: Houben's line update. Each detected end point ``vE``,
  placed in the map by the pose, is projected onto the associated map marking and clamped
  to its end points. Inside the marking only the signed distance across the line is
  measured (one row, expected value 0: a detection may be shorter than the painted line,
  so its end says nothing along it); beyond an end point the detection overshoots the
  marking, and the end point itself is the measurement (two rows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from semslam.geometry import FloatArray, wrap_angle


def point_jacobian(pose: FloatArray, mP: FloatArray) -> FloatArray:
    """(2N, 3) derivative of ``R(yaw)^T (mP - t)`` (rows x0, y0, x1, ...) at ``pose``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = mP - pose[:2]
    H = np.zeros((2 * len(mP), 3))
    H[0::2, 0], H[0::2, 1] = -c, -s
    H[1::2, 0], H[1::2, 1] = s, -c
    H[0::2, 2] = -s * d[:, 0] + c * d[:, 1]
    H[1::2, 2] = -c * d[:, 0] - s * d[:, 1]
    return H


def _rotate_to_vehicle(yaw: FloatArray, d: FloatArray) -> FloatArray:
    """``R(yaw)^T d`` for (K,) yaws and (K, N, 2) vectors -> (K, N, 2)."""
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


@dataclass(frozen=True)
class Measurement:
    """A stacked measurement: ``z`` observed, ``R`` its covariance, ``angle_rows`` the rows
    holding angles (their residuals are wrapped)."""

    z: FloatArray
    R: FloatArray
    angle_rows: tuple[int, ...] = field(default=(), kw_only=True)

    def residual(self, predicted: FloatArray) -> FloatArray:
        """``z - predicted`` for (m,) or (K, m) predictions, angles wrapped."""
        r = self.z - predicted
        for i in self.angle_rows:
            r[..., i] = wrap_angle(r[..., i])
        return r

    def linearise(self, pose: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The residual (m,) and the Jacobian (m, 3) at one ``pose`` (the EKF update)."""
        return self.residual(self.predict(pose)[0]), self.jacobian(pose)


@dataclass(frozen=True)
class PointMeasurement(Measurement):
    """Map points ``mP`` (N, 2) observed at ``z`` = (N, 2) flattened, in the vehicle frame
    turned by ``turn`` rad: ``z = R(turn) vP`` (``turn`` 0: the vehicle frame itself).

    A fixed turn is an orthogonal change of the measurement's frame: the filter's update is
    the same in any such frame. The localizer turns slot corners by the predicted heading,
    which puts them on the map's axes, where the map's corner covariances need no turning.
    """

    mP: FloatArray
    turn: float = field(default=0.0, kw_only=True)
    # (pose, residual, Jacobian) already worked out at one pose (by the association's gate)
    linearised: tuple | None = field(default=None, kw_only=True, compare=False, repr=False)

    def predict(self, poses: FloatArray) -> FloatArray:
        poses = np.atleast_2d(poses)
        d = self.mP[None, :, :] - poses[:, None, :2]
        return _rotate_to_vehicle(poses[:, 2] - self.turn, d).reshape(len(poses), -1)

    def jacobian(self, pose: FloatArray) -> FloatArray:
        return point_jacobian(np.array([pose[0], pose[1], pose[2] - self.turn]), self.mP)

    def linearise(self, pose: FloatArray) -> tuple[FloatArray, FloatArray]:
        if self.linearised is not None and self.linearised[0] == tuple(pose):
            return self.linearised[1], self.linearised[2]
        c, s = math.cos(pose[2] - self.turn), math.sin(pose[2] - self.turn)
        predicted = (self.mP - pose[:2]) @ np.array([[c, -s], [s, c]])  # R(yaw - turn)^T d
        H = np.empty((len(self.mP), 2, 3))  # point_jacobian, from the prediction
        H[:, :, :2] = np.array([[-c, -s], [s, -c]])
        H[:, 0, 2] = predicted[:, 1]
        H[:, 1, 2] = -predicted[:, 0]
        return self.z - predicted.ravel(), H.reshape(-1, 3)


@dataclass(frozen=True)
class TagMeasurement(Measurement):
    """A map tag at ``mTt`` (x, y, yaw) observed as ``z`` = vTt (x, y, yaw)."""

    mTt: FloatArray
    angle_rows: tuple[int, ...] = field(default=(2,), kw_only=True)

    def predict(self, poses: FloatArray) -> FloatArray:
        poses = np.atleast_2d(poses)
        d = (self.mTt[:2] - poses[:, :2])[:, None, :]
        xy = _rotate_to_vehicle(poses[:, 2], d)[:, 0, :]
        return np.column_stack([xy, wrap_angle(self.mTt[2] - poses[:, 2])])

    def jacobian(self, pose: FloatArray) -> FloatArray:
        H = np.zeros((3, 3))
        H[:2] = point_jacobian(pose, self.mTt[None, :2])
        H[2, 2] = -1.0
        return H

    def linearise(self, pose: FloatArray) -> tuple[FloatArray, FloatArray]:
        x, y, yaw = (float(v) for v in pose)
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = float(self.mTt[0]) - x, float(self.mTt[1]) - y
        px, py = c * dx + s * dy, -s * dx + c * dy  # the tag's position seen from the pose
        heading = wrap_angle(float(self.mTt[2]) - yaw)
        z = self.z
        r = np.array([z[0] - px, z[1] - py, wrap_angle(float(z[2]) - heading)])
        return r, np.array([[-c, -s, py], [s, -c, -px], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class MarkingMeasurement(Measurement):
    """Detected end points ``vE`` (N, 2, vehicle frame) against map markings ``a``, ``b``
    (N, 2 each, map frame), row kinds fixed at the linearisation pose ``clamped`` (N,):
    False gives one row (signed distance across the line, z = 0), True two rows (the
    clamped marking end ``end`` in the vehicle frame, z = vE). ``rows`` (N,) is the first
    row of each end point. Vectorised over end points and poses."""

    vE: FloatArray
    a: FloatArray
    b: FloatArray
    clamped: FloatArray
    end: FloatArray  # (N, 2) the marking end a clamped point is compared with
    rows: FloatArray

    @staticmethod
    def build(
        pose: FloatArray,
        vE: FloatArray,
        a: FloatArray,
        b: FloatArray,
        sigma: float | FloatArray,
        margin: float | FloatArray = 0.0,
        reach: float = math.inf,
    ) -> MarkingMeasurement:
        """The measurement of end points ``vE`` against markings ``(a, b)`` (``sigma`` and
        ``margin``: metres, one for all or one per end point), deciding at
        ``pose`` which end points fall beyond their marking: by more than ``margin`` (noise)
        and less than ``reach`` they are clamped to its end; farther out the map's marking
        is taken as incomplete there (a map drawn from what was seen), and only the
        distance across the line is measured."""
        mE = _to_map(pose, vE)
        d = b - a
        length2 = np.maximum((d * d).sum(axis=1), 1e-12)
        s = ((mE - a) * d).sum(axis=1) / length2
        L = np.sqrt(length2)
        beyond = np.maximum(-s, s - 1) * L  # m past the nearer end (< 0: inside)
        clamped = (beyond > margin) & (beyond < reach)
        end = np.where((s < 0.5)[:, None], a, b)
        sizes = np.where(clamped, 2, 1)
        rows = np.cumsum(sizes) - sizes
        z = np.zeros(int(sizes.sum()))
        z[rows[clamped]] = vE[clamped, 0]
        z[rows[clamped] + 1] = vE[clamped, 1]
        sigma = np.full(len(vE), sigma) if np.ndim(sigma) == 0 else np.asarray(sigma, float)
        R = np.diag(np.repeat(sigma * sigma, sizes))
        return MarkingMeasurement(z, R, vE, a, b, clamped, end, rows)

    def _normals(self) -> FloatArray:
        d = self.b - self.a
        return np.column_stack([-d[:, 1], d[:, 0]]) / np.linalg.norm(d, axis=1)[:, None]

    def predict(self, poses: FloatArray) -> FloatArray:
        poses = np.atleast_2d(poses)
        out = np.zeros((len(poses), len(self.z)))
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        free = ~self.clamped
        if free.any():  # signed distance across the line of each end point
            e, a, n = self.vE[free], self.a[free], self._normals()[free]
            ex = poses[:, :1] + c * e[:, 0] - s * e[:, 1]  # (K, F)
            ey = poses[:, 1:2] + s * e[:, 0] + c * e[:, 1]
            out[:, self.rows[free]] = (ex - a[:, 0]) * n[:, 0] + (ey - a[:, 1]) * n[:, 1]
        if self.clamped.any():  # the marking end in the vehicle frame
            d = self.end[self.clamped][None, :, :] - poses[:, None, :2]
            v = _rotate_to_vehicle(poses[:, 2], d)
            out[:, self.rows[self.clamped]] = v[..., 0]
            out[:, self.rows[self.clamped] + 1] = v[..., 1]
        return out

    def linearise(self, pose: FloatArray) -> tuple[FloatArray, FloatArray]:
        """:meth:`residual` of :meth:`predict` and :meth:`jacobian` at one pose, sharing
        their work (the EKF update)."""
        c, s = math.cos(pose[2]), math.sin(pose[2])
        r, H = np.empty(len(self.z)), np.empty((len(self.z), 3))
        free, clamped = ~self.clamped, self.clamped
        if free.any():  # 0 minus the distance across the line; rows [n, n . dE/dyaw]
            e, n, rows = self.vE[free], self._normals()[free], self.rows[free]
            mE = e @ np.array([[c, s], [-s, c]]) + pose[:2]
            r[rows] = -((mE - self.a[free]) * n).sum(axis=1)
            H[rows, :2] = n
            H[rows, 2] = ((e @ np.array([[-s, c], [-c, -s]])) * n).sum(axis=1)
        if clamped.any():  # the marking end in the vehicle frame, as point_jacobian
            rows = self.rows[clamped]
            v = (self.end[clamped] - pose[:2]) @ np.array([[c, -s], [s, c]])
            r[rows], r[rows + 1] = self.z[rows] - v[:, 0], self.z[rows + 1] - v[:, 1]
            H[rows, :2], H[rows + 1, :2] = (-c, -s), (s, -c)
            H[rows, 2], H[rows + 1, 2] = v[:, 1], -v[:, 0]
        return r, H

    def jacobian(self, pose: FloatArray) -> FloatArray:
        H = np.zeros((len(self.z), 3))
        c, s = np.cos(pose[2]), np.sin(pose[2])
        free = ~self.clamped
        if free.any():
            e, n = self.vE[free], self._normals()[free]
            dEx = -s * e[:, 0] - c * e[:, 1]
            dEy = c * e[:, 0] - s * e[:, 1]
            H[self.rows[free]] = np.column_stack([n[:, 0], n[:, 1], n[:, 0] * dEx + n[:, 1] * dEy])
        if self.clamped.any():
            J = point_jacobian(pose, self.end[self.clamped])
            H[self.rows[self.clamped]] = J[0::2]
            H[self.rows[self.clamped] + 1] = J[1::2]
        return H


def _to_map(pose: FloatArray, vP: FloatArray) -> FloatArray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return vP @ np.array([[c, s], [-s, c]]) + pose[:2]


def stack(measurements: list) -> tuple[FloatArray, FloatArray, list]:
    """Observed vector and block-diagonal covariance of several measurements."""
    if len(measurements) == 1:  # most frames: slots alone
        return measurements[0].z, measurements[0].R, measurements
    z = np.concatenate([m.z for m in measurements])
    R = np.zeros((len(z), len(z)))
    i = 0
    for m in measurements:
        n = len(m.z)
        R[i : i + n, i : i + n] = m.R
        i += n
    return z, R, measurements
