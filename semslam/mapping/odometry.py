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
from semslam.motion import arc_functions


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
    segment = _segment(t, speed, yaw_rate, t_start, t_end)
    x, y, yaw, P = _integrate(*segment, t_start, t_end, 1.0, 0.0,
                              (speed_sigma, speed_scale_sigma, yaw_rate_sigma))
    P = 0.5 * (P + P.T) + np.eye(3) * 1e-10
    return np.array([x, y, float(wrap_angle(yaw))]), P


def pose_between(
    t: FloatArray, speed: FloatArray, yaw_rate: FloatArray, t_start: float, t_end: float
) -> FloatArray:
    """Relative pose (x, y, yaw) of the vehicle at ``t_end`` in its frame at ``t_start``,
    as :func:`odometry_between` without the covariance (cheaper)."""
    x, y, yaw, _ = _integrate(*_segment(t, speed, yaw_rate, t_start, t_end), t_start, t_end,
                              1.0, 0.0, None)
    return np.array([x, y, float(wrap_angle(yaw))])


def calibration_jacobian(
    t: FloatArray, speed: FloatArray, yaw_rate: FloatArray, t_start: float, t_end: float
) -> FloatArray:
    """(3, 2) derivative of the segment's relative pose with respect to the odometry
    calibration ``(speed scale, gyro bias)`` at (1, 0): speed is multiplied by the scale,
    the bias is subtracted from the yaw rate (central differences; the segment is short)."""
    eps_s, eps_b = 1e-4, 1e-5
    segment = _segment(t, speed, yaw_rate, t_start, t_end)

    def rel(scale: float, bias: float) -> FloatArray:
        return np.array(_integrate(*segment, t_start, t_end, scale, bias, None)[:3])

    J = np.empty((3, 2))
    J[:, 0] = (rel(1 + eps_s, 0) - rel(1 - eps_s, 0)) / (2 * eps_s)
    J[:, 1] = (rel(1, eps_b) - rel(1, -eps_b)) / (2 * eps_b)
    return J


def _segment(
    t: FloatArray, speed: FloatArray, yaw_rate: FloatArray, t_start: float, t_end: float
) -> tuple[list[float], list[float], list[float]]:
    """The samples that hold during ``[t_start, t_end]`` as lists: the one in force at
    ``t_start`` to the first at or after ``t_end`` (or the drive's last, which then holds
    until ``t_end``)."""
    first = max(int(np.searchsorted(t, t_start, side="right")) - 1, 0)
    stop = int(np.searchsorted(t, t_end, side="left")) + 1
    return t[first:stop].tolist(), speed[first:stop].tolist(), yaw_rate[first:stop].tolist()


def _integrate(
    t: list[float],
    speed: list[float],
    yaw_rate: list[float],
    t_start: float,
    t_end: float,
    scale: float,
    bias: float,
    noise: tuple[float, float, float] | None,
) -> tuple[float, float, float, FloatArray]:
    """CTRV integration of the samples over ``[t_start, t_end]`` with speed times ``scale``
    and yaw rate minus ``bias``; with ``noise`` (speed sigma, speed scale sigma, yaw-rate
    sigma) also the covariance ``P <- F P F^T + G Q G^T`` of the relative pose, where ``F``
    and ``G`` are the pose and (speed, yaw rate) blocks of :func:`~semslam.motion.
    ctrv_jacobian`, written out in floats (this runs for every frame of a drive)."""
    x = y = yaw = 0.0
    p00 = p01 = p02 = p11 = p12 = p22 = 0.0
    now = t_start
    n = len(t)
    i = 0
    while now < t_end - 1e-12 and i < n:
        nxt = t[i + 1] if i + 1 < n else t_end  # the last sample holds to the end
        dt = min(nxt, t_end) - now
        if dt > 0:
            v, w = speed[i] * scale, yaw_rate[i] - bias
            f1, f2, d1, d2 = arc_functions(w * dt)
            c, s = math.cos(yaw), math.sin(yaw)
            ux, uy = c * f1 - s * f2, s * f1 + c * f2  # displacement per metre of travel
            if noise is not None:
                a, b = -v * dt * uy, v * dt * ux  # d(x, y) / d yaw
                g00, g10 = dt * ux, dt * uy  # d(x, y) / d speed
                g01 = v * dt * dt * (c * d1 - s * d2)  # d(x, y, yaw) / d yaw rate
                g11 = v * dt * dt * (s * d1 + c * d2)
                sv = math.hypot(noise[0], noise[1] * v)
                qv, qw = sv * sv, noise[2] * noise[2]
                p00, p01, p02, p11, p12 = (
                    p00 + 2 * a * p02 + a * a * p22 + g00 * g00 * qv + g01 * g01 * qw,
                    p01 + a * p12 + b * (p02 + a * p22) + g00 * g10 * qv + g01 * g11 * qw,
                    p02 + a * p22 + g01 * dt * qw,
                    p11 + 2 * b * p12 + b * b * p22 + g10 * g10 * qv + g11 * g11 * qw,
                    p12 + b * p22 + g11 * dt * qw,
                )
                p22 = p22 + dt * dt * qw
            x, y, yaw = x + v * dt * ux, y + v * dt * uy, yaw + w * dt
        now = min(nxt, t_end)
        i += 1
    P = np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]])
    return x, y, yaw, P
