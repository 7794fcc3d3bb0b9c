"""The localizer's Kalman filter: CTRV state, odometry as measurements, two frame updates.

State ``(x, y, yaw, v, yaw_rate)`` in the map frame (m, m, rad, m/s, rad/s) with its 5x5
covariance, or, to estimate the odometry's own errors, ``(x, y, yaw, v, yaw_rate, scale,
bias)`` with a 7x7 one: ``scale`` the wheel speed's relative error (0: exact), ``bias`` the
gyro's offset (rad/s). Prediction is the CTRV model of :mod:`semslam.motion` with its
analytic Jacobian (Houben eq. 11-20); process noise is white acceleration and yaw
acceleration on ``v`` and ``yaw_rate`` at the end of each step (odometry samples hold until
the next one, so a change of rate does not move the pose already travelled), an optional
random walk on the pose for what CTRV does not model, and a slow drift of ``scale`` and
``bias``.
Wheel speed measures ``(1 + scale) v`` and the gyro ``yaw_rate + bias`` (the 5-state
filter: ``v`` and ``yaw_rate`` themselves).

Frame updates take stacked measurements (:mod:`semslam.localization.measurements`):

- ``ekf``: linearise each model at the prediction (analytic Jacobians), Joseph-form update.
- ``sigma``: Houben's unscented update (Alg. 3): ``2n + 1`` sigma points (11 for his
  5 states) along the eigenvectors of ``P``, ``X0 = x`` with weight ``alpha``,
  ``X±i = x ± sqrt(n / (1 - alpha) * lambda_i) e_i`` with weights ``(1 - alpha) / 2n``
  (this scale reproduces ``P`` exactly from the points),
  innovation covariance and cross-covariance from the spread of the predicted measurements.

Both expose the innovation and its covariance before committing, so the caller can reject
a whole frame whose Mahalanobis distance is too large (Houben).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from semslam.geometry import FloatArray, wrap_angle
from semslam.motion import ctrv_jacobian, ctrv_predict

CTRV_STATES, CALIBRATED_STATES = 5, 7  # (x, y, yaw, v, yaw_rate) [+ (scale, bias)]


@dataclass(frozen=True)
class ProcessNoise:
    """Continuous-time noise densities of the prediction."""

    acceleration: float  # m/s^2 per sqrt(Hz), on v
    yaw_acceleration: float  # rad/s^2 per sqrt(Hz), on yaw_rate
    position_walk: float  # m per sqrt(s), on x and y
    yaw_walk: float  # rad per sqrt(s), on yaw
    scale_walk: float = 0.0  # per sqrt(s), on the wheel-speed scale error (7 states)
    bias_walk: float = 0.0  # rad/s per sqrt(s), on the gyro bias (7 states)


@dataclass(frozen=True)
class Innovation:
    """A prepared update: residual ``nu`` (m,), its covariance ``S`` (m, m) and the
    state-measurement cross-covariance ``C`` (n, m)."""

    nu: FloatArray
    S: FloatArray
    C: FloatArray

    @functools.cached_property
    def _solved(self) -> FloatArray:
        """``S^-1 [C^T | nu]`` (m, n + 1): the gain's transpose and ``S^-1 nu``, one solve."""
        return solve_spd(self.S, np.column_stack([self.C.T, self.nu]))

    @property
    def nis(self) -> float:
        """Normalised innovation squared (chi-square with m degrees of freedom)."""
        return float(self.nu @ self._solved[:, -1])

    @property
    def gain(self) -> FloatArray:
        """Kalman gain ``K = C S^-1`` (n, m)."""
        return self._solved[:, :-1].T


def solve_spd(S: FloatArray, B: FloatArray) -> FloatArray:
    """``S^-1 B`` for a symmetric positive definite ``S`` (m, m) and ``B`` (m,) or (m, k):
    Cholesky, LAPACK's ``posv`` called directly (numpy's ``solve`` costs two to three times
    as much on the small systems of a frame); LU when ``S`` is not numerically positive
    definite."""
    _, solved, info = lapack.dposv(S, B)
    return solved if info == 0 else np.linalg.solve(S, B)


class CtrvFilter:
    """Extended / sigma-point Kalman filter on the CTRV state (5 states), or on the CTRV
    state and the odometry's scale and bias (7 states, when ``x`` has 7 entries)."""

    def __init__(self, x: FloatArray, P: FloatArray, noise: ProcessNoise, alpha: float = 0.2):
        self.noise = noise
        self.alpha = alpha
        self.reset(x, P)

    @property
    def calibrated(self) -> bool:
        """Does the state hold the odometry's scale and bias?"""
        return len(self.x) == CALIBRATED_STATES

    @property
    def pose(self) -> FloatArray:
        return self.x[:3].copy()

    @property
    def pose_covariance(self) -> FloatArray:
        return self.P[:3, :3].copy()

    # ---------------------------------------------------------------- prediction
    def predict(self, dt: float) -> None:
        """Move the state ``dt`` seconds ahead (dt >= 0)."""
        if dt <= 0:
            return
        F = np.eye(len(self.x))
        F[:CTRV_STATES, :CTRV_STATES] = ctrv_jacobian(self.x[:CTRV_STATES], dt)
        n = self.noise
        # v and yaw_rate change at the END of the step: wheel speed and gyro are samples
        # held until the next one, so a change seen in the next sample must not move the
        # pose this step has already travelled (noise entering at the start of the step,
        # through F's speed and rate columns, turns every change of the yaw rate into a
        # heading error of dt times that change)
        Q = np.zeros_like(F)
        Q[3, 3] = n.acceleration**2 * dt
        Q[4, 4] = n.yaw_acceleration**2 * dt
        Q[0, 0] += n.position_walk**2 * dt
        Q[1, 1] += n.position_walk**2 * dt
        Q[2, 2] += n.yaw_walk**2 * dt
        if self.calibrated:
            Q[5, 5] += n.scale_walk**2 * dt
            Q[6, 6] += n.bias_walk**2 * dt
        self.x[:CTRV_STATES] = ctrv_predict(self.x[:CTRV_STATES], dt)
        self.P = F @ self.P @ F.T + Q
        self._symmetrise()

    def update_odometry(self, speed: float, yaw_rate: float, speed_sigma: float,
                        yaw_rate_sigma: float) -> None:
        """Wheel speed (m/s) and gyro (rad/s): measurements of ``(1 + scale) v`` and
        ``yaw_rate + bias`` (of ``v`` and ``yaw_rate`` in the 5-state filter)."""
        R = np.diag([speed_sigma**2, yaw_rate_sigma**2])
        predicted, H = odometry_measurement(self.x)
        nu = np.array([speed, yaw_rate]) - predicted
        C = self.P @ H.T
        S = H @ C + R
        K = C @ np.linalg.inv(S)
        self.x = self.x + K @ nu
        self.x[2] = wrap_angle(self.x[2])
        IKH = np.eye(len(self.x)) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self._symmetrise()

    # ---------------------------------------------------------------- frame updates
    def innovation(self, measurements: list, R: FloatArray, mode: str = "ekf") -> Innovation:
        """Innovation of the stacked ``measurements`` (covariance ``R``) at the current state."""
        if mode == "ekf":
            pose = self.x[:3]
            parts = [m.linearise(pose) for m in measurements]
            if len(parts) == 1:
                nu, H = parts[0]
            else:
                nu = np.concatenate([r for r, _ in parts])
                H = np.vstack([J for _, J in parts])
            C = self.P[:, :3] @ H.T  # H is zero beyond the pose's columns
            # symmetric up to rounding: the Cholesky of solve_spd reads its upper triangle
            return Innovation(nu, H @ C[:3] + R, C)
        if mode == "sigma":
            X, w = self.sigma_points()
            Z = np.concatenate([m.predict(X[:, :3]) for m in measurements], axis=1)
            dZ = _residuals(measurements, Z)  # z - Z_i, angles wrapped, (2n + 1, m)
            mean_dZ = w @ dZ  # z - z_hat, the innovation
            E = dZ - mean_dZ  # Z_i - z_hat up to sign
            dX = X - self.x  # the offsets themselves, never wrapped: sum w dX dX^T = P
            S = (E * w[:, None]).T @ E + R
            C = -(dX * w[:, None]).T @ E
            return Innovation(mean_dZ, 0.5 * (S + S.T), C)
        raise ValueError(f"update mode {mode!r}: choose ekf or sigma")

    def apply(self, innovation: Innovation) -> None:
        """Commit a prepared update."""
        K = innovation.gain
        self.x = self.x + K @ innovation.nu
        self.x[2] = wrap_angle(self.x[2])
        self.P = self.P - K @ innovation.C.T  # K S K^T = C S^-1 C^T
        self._symmetrise()

    def sigma_points(self) -> tuple[FloatArray, FloatArray]:
        """Houben's ``2n + 1`` sigma points (2n + 1, n) and weights (2n + 1,)."""
        n = len(self.x)
        lam, E = np.linalg.eigh(self.P)
        lam = np.maximum(lam, 0.0)
        scale = np.sqrt(n / (1.0 - self.alpha) * lam)
        offsets = (E * scale).T  # row i = scale_i * e_i
        X = np.vstack([self.x, self.x + offsets, self.x - offsets])
        w = np.full(2 * n + 1, (1.0 - self.alpha) / (2 * n))
        w[0] = self.alpha
        return X, w

    def reset(self, x: FloatArray, P: FloatArray) -> None:
        x = np.asarray(x, dtype=float).copy()
        P = np.asarray(P, dtype=float).copy()
        if len(x) not in (CTRV_STATES, CALIBRATED_STATES) or P.shape != (len(x), len(x)):
            raise ValueError(f"filter state of {len(x)} entries with a {P.shape} covariance: "
                             "expected 5 or 7 entries and a square covariance to match")
        self.x, self.P = x, P

    def _symmetrise(self) -> None:
        self.P = 0.5 * (self.P + self.P.T)


def odometry_measurement(x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """What wheel speed and gyro read in state ``x`` (5 or 7 entries): ``(1 + scale) v``
    and ``yaw_rate + bias`` (m/s, rad/s), and the (2, n) Jacobian of that reading."""
    H = np.zeros((2, len(x)))
    H[0, 3], H[1, 4] = 1.0, 1.0
    reading = np.array([x[3], x[4]], dtype=float)
    if len(x) == CALIBRATED_STATES:
        v, scale, bias = x[3], x[5], x[6]
        reading += [scale * v, bias]
        H[0, 3], H[0, 5], H[1, 6] = 1.0 + scale, v, 1.0
    return reading, H


def _residuals(measurements: list, Z: FloatArray) -> FloatArray:
    out, i = [], 0
    for m in measurements:
        n = len(m.z)
        out.append(m.residual(Z[:, i : i + n]))
        i += n
    return np.concatenate(out, axis=1)
