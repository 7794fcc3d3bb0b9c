"""Wheel-speed + gyro odometry between keyframes: relative pose and its covariance.

Each odometry sample (speed, yaw rate) holds from its time to the next
(zero-order hold, as :func:`semslam.motion.integrate_odometry`). The relative
pose of the segment's end in the frame of its start is integrated with the
CTRV arc, and its covariance propagated through the same Jacobians with
white noise on speed and yaw rate, so it grows with distance and time.
"""

from __future__ import annotations

import math

import numpy as np

from semslam.geometry import FloatArray, wrap_angle
from semslam.motion import ctrv_displacement, ctrv_jacobian


def odometry_between(
    t: FloatArray,
    speed: FloatArray,
    yaw_rate: FloatArray,
    t_start: float,
    t_end: float,
    speed_sigma: float,
    speed_scale_sigma: float,
    yaw_rate_sigma: float,
) -> tuple[FloatArray, FloatArray]:
    """Relative pose (x, y, yaw) of the vehicle at ``t_end`` in its frame at ``t_start``.

    Args:
        t, speed, yaw_rate: (N,) odometry samples (s, m/s, rad/s), times increasing.
        t_start, t_end: the segment, seconds.
        speed_sigma: white noise on speed, m/s.
        speed_scale_sigma: relative speed error, added in quadrature to ``speed_sigma``.
        yaw_rate_sigma: white noise on yaw rate, rad/s.

    Returns:
        (3,) relative pose and its (3, 3) covariance (m^2, m*rad, rad^2).
    """
    first = max(int(np.searchsorted(t, t_start, side="right")) - 1, 0)
    x = y = yaw = 0.0
    P = np.zeros((3, 3))
    now = t_start
    i = first
    while now < t_end - 1e-12 and i < len(t):
        nxt = t[i + 1] if i + 1 < len(t) else t_end
        dt = min(nxt, t_end) - now
        if dt > 0:
            v, w = float(speed[i]), float(yaw_rate[i])
            F5 = ctrv_jacobian(np.array([x, y, yaw, v, w]), dt)
            F, G = F5[:3, :3], F5[:3, 3:]
            sv = math.hypot(speed_sigma, speed_scale_sigma * v)
            P = F @ P @ F.T + G @ np.diag([sv * sv, yaw_rate_sigma**2]) @ G.T
            dx, dy = ctrv_displacement(yaw, v, w, dt)
            x, y, yaw = x + dx, y + dy, yaw + w * dt
        now = min(nxt, t_end)
        i += 1
    P = 0.5 * (P + P.T) + np.eye(3) * 1e-10
    return np.array([x, y, float(wrap_angle(yaw))]), P


def calibration_jacobian(
    t: FloatArray, speed: FloatArray, yaw_rate: FloatArray, t_start: float, t_end: float
) -> FloatArray:
    """(3, 2) derivative of the segment's relative pose with respect to the odometry
    calibration ``(speed scale, gyro bias)`` at (1, 0): speed is multiplied by the scale,
    the bias is subtracted from the yaw rate (central differences; the segment is short)."""
    eps_s, eps_b = 1e-4, 1e-5

    def rel(scale: float, bias: float) -> FloatArray:
        return odometry_between(t, speed * scale, yaw_rate - bias, t_start, t_end, 0, 0, 0)[0]

    J = np.empty((3, 2))
    J[:, 0] = (rel(1 + eps_s, 0) - rel(1 - eps_s, 0)) / (2 * eps_s)
    J[:, 1] = (rel(1, eps_b) - rel(1, -eps_b)) / (2 * eps_b)
    return J
