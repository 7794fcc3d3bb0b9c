"""The localizer's Kalman filter: CTRV state, odometry as measurements, two frame updates.

State ``(x, y, yaw, v, yaw_rate)`` in the map frame (m, m, rad, m/s, rad/s) with its 5x5
covariance. Prediction is the CTRV model of :mod:`semslam.motion` with its analytic
Jacobian (Houben eq. 11-20); process noise is white acceleration and yaw acceleration
entering through the speed and turn-rate columns, plus a small random walk on the pose for
what CTRV does not model. Wheel speed and gyro are linear measurements of ``v`` and
``yaw_rate``.

Frame updates take stacked measurements (:mod:`semslam.localization.measurements`):

- ``ekf``: linearise each model at the prediction (analytic Jacobians), Joseph-form update.
- ``sigma``: Houben's unscented update (Alg. 3): 11 sigma points along the eigenvectors of
  ``P``, ``X0 = x`` with weight ``alpha``, ``X±i = x ± sqrt(5 / (1 - alpha) * lambda_i) e_i``
  with weights ``(1 - alpha) / 10`` (this scale reproduces ``P`` exactly from the points),
  innovation covariance and cross-covariance from the spread of the predicted measurements.

Both expose the innovation and its covariance before committing, so the caller can reject
a whole frame whose Mahalanobis distance is too large (Houben).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semslam.geometry import FloatArray, wrap_angle
from semslam.motion import ctrv_jacobian, ctrv_predict

_H_ODOMETRY = np.array([[0, 0, 0, 1.0, 0], [0, 0, 0, 0, 1.0]])


@dataclass(frozen=True)
class ProcessNoise:
    """Continuous-time noise densities of the prediction."""

    acceleration: float  # m/s^2 per sqrt(Hz), on v
    yaw_acceleration: float  # rad/s^2 per sqrt(Hz), on yaw_rate
    position_walk: float  # m per sqrt(s), on x and y
    yaw_walk: float  # rad per sqrt(s), on yaw


@dataclass(frozen=True)
class Innovation:
    """A prepared update: residual ``nu`` (m,), its covariance ``S`` (m, m) and the
    state-measurement cross-covariance ``C`` (5, m)."""

    nu: FloatArray
    S: FloatArray
    C: FloatArray

    @property
    def nis(self) -> float:
        """Normalised innovation squared (chi-square with m degrees of freedom)."""
        return float(self.nu @ np.linalg.solve(self.S, self.nu))


class CtrvFilter:
    """Extended / sigma-point Kalman filter on the CTRV state."""

    def __init__(self, x: FloatArray, P: FloatArray, noise: ProcessNoise, alpha: float = 0.2):
        self.x = np.asarray(x, dtype=float).copy()
        self.P = np.asarray(P, dtype=float).copy()
        self.noise = noise
        self.alpha = alpha

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
        F = ctrv_jacobian(self.x, dt)
        n = self.noise
        G = F[:, 3:5]  # noise enters as a change of v and yaw_rate at the start of the step
        Q = G @ np.diag([n.acceleration**2 * dt, n.yaw_acceleration**2 * dt]) @ G.T
        Q[0, 0] += n.position_walk**2 * dt
        Q[1, 1] += n.position_walk**2 * dt
        Q[2, 2] += n.yaw_walk**2 * dt
        self.x = ctrv_predict(self.x, dt)
        self.P = F @ self.P @ F.T + Q
        self._symmetrise()

    def update_odometry(self, speed: float, yaw_rate: float, speed_sigma: float,
                        yaw_rate_sigma: float) -> None:
        """Wheel speed (m/s) and gyro (rad/s) as direct measurements of v and yaw_rate."""
        R = np.diag([speed_sigma**2, yaw_rate_sigma**2])
        nu = np.array([speed - self.x[3], yaw_rate - self.x[4]])
        S = self.P[3:5, 3:5] + R
        C = self.P[:, 3:5]
        K = C @ np.linalg.inv(S)
        self.x = self.x + K @ nu
        self.x[2] = wrap_angle(self.x[2])
        IKH = np.eye(5) - K @ _H_ODOMETRY
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self._symmetrise()

    # ---------------------------------------------------------------- frame updates
    def innovation(self, measurements: list, R: FloatArray, mode: str = "ekf") -> Innovation:
        """Innovation of the stacked ``measurements`` (covariance ``R``) at the current state."""
        if mode == "ekf":
            pose = self.x[:3]
            nu = np.concatenate([m.residual(m.predict(pose)[0]) for m in measurements])
            H = np.zeros((len(nu), 5))
            H[:, :3] = np.vstack([m.jacobian(pose) for m in measurements])
            C = self.P @ H.T
            S = H @ C + R
            return Innovation(nu, 0.5 * (S + S.T), C)
        if mode == "sigma":
            X, w = self.sigma_points()
            Z = np.concatenate([m.predict(X[:, :3]) for m in measurements], axis=1)
            dZ = _residuals(measurements, Z)  # z - Z_i, angles wrapped, (11, m)
            mean_dZ = w @ dZ  # z - z_hat, the innovation
            E = dZ - mean_dZ  # Z_i - z_hat up to sign
            dX = X - self.x
            dX[:, 2] = wrap_angle(dX[:, 2])
            S = (E * w[:, None]).T @ E + R
            C = -(dX * w[:, None]).T @ E
            return Innovation(mean_dZ, 0.5 * (S + S.T), C)
        raise ValueError(f"update mode {mode!r}: choose ekf or sigma")

    def apply(self, innovation: Innovation) -> None:
        """Commit a prepared update."""
        K = np.linalg.solve(innovation.S, innovation.C.T).T
        self.x = self.x + K @ innovation.nu
        self.x[2] = wrap_angle(self.x[2])
        self.P = self.P - K @ innovation.S @ K.T
        self._symmetrise()

    def sigma_points(self) -> tuple[FloatArray, FloatArray]:
        """Houben's 11 sigma points (11, 5) and weights (11,)."""
        lam, E = np.linalg.eigh(self.P)
        lam = np.maximum(lam, 0.0)
        scale = np.sqrt(5.0 / (1.0 - self.alpha) * lam)
        offsets = (E * scale).T  # row i = scale_i * e_i
        X = np.vstack([self.x, self.x + offsets, self.x - offsets])
        w = np.full(11, (1.0 - self.alpha) / 10.0)
        w[0] = self.alpha
        return X, w

    def reset(self, x: FloatArray, P: FloatArray) -> None:
        self.x = np.asarray(x, dtype=float).copy()
        self.P = np.asarray(P, dtype=float).copy()

    def _symmetrise(self) -> None:
        self.P = 0.5 * (self.P + self.P.T)


def _residuals(measurements: list, Z: FloatArray) -> FloatArray:
    out, i = [], 0
    for m in measurements:
        n = len(m.z)
        out.append(m.residual(Z[:, i : i + n]))
        i += n
    return np.concatenate(out, axis=1)
