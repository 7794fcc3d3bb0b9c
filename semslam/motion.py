"""Constant turn rate and velocity (CTRV) motion model (Houben eq. 11).

State ``(x, y, yaw, v, yaw_rate)`` in the map frame: metres, metres, radians,
m/s, rad/s. Over a step of ``dt`` seconds speed and turn rate stay constant,
so the vehicle moves on a circular arc (a straight line when the turn rate is
zero). The same model drives the simulator, integrates odometry for the
mapper and predicts the localizer's filter.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from semslam.geometry import FloatArray, wrap_angle

# Below this |yaw_rate * dt| the arc functions use their Taylor series (error ~ a^5).
_SERIES_TURN = 1e-2


def arc_functions(a: float) -> tuple[float, float, float, float]:
    """``f1 = sin(a)/a``, ``f2 = (1 - cos a)/a`` and their derivatives, stable at a -> 0."""
    if abs(a) < _SERIES_TURN:
        a2 = a * a
        return (
            1 - a2 / 6 + a2 * a2 / 120,
            a / 2 - a * a2 / 24,
            -a / 3 + a * a2 / 30,
            0.5 - a2 / 8 + a2 * a2 / 144,
        )
    s, c = math.sin(a), math.cos(a)
    return s / a, (1 - c) / a, (a * c - s) / (a * a), (a * s - (1 - c)) / (a * a)


def ctrv_displacement(yaw: float, v: float, yaw_rate: float, dt: float) -> tuple[float, float]:
    """Displacement ``(dx, dy)`` in the map frame of one CTRV step from heading ``yaw``:
    the arc ``v/w (sin(yaw + w dt) - sin yaw, cos yaw - cos(yaw + w dt))``, written as
    ``v dt (cos yaw f1 - sin yaw f2, sin yaw f1 + cos yaw f2)`` so it stays exact as w -> 0."""
    f1, f2, _, _ = arc_functions(yaw_rate * dt)
    c, s = math.cos(yaw), math.sin(yaw)
    return v * dt * (c * f1 - s * f2), v * dt * (s * f1 + c * f2)


def ctrv_predict(state: ArrayLike, dt: float) -> FloatArray:
    """State after ``dt`` seconds of CTRV motion; yaw wrapped to (-pi, pi]."""
    x, y, yaw, v, w = np.asarray(state, dtype=float)
    dx, dy = ctrv_displacement(yaw, v, w, dt)
    return np.array([x + dx, y + dy, wrap_angle(yaw + w * dt), v, w])


def ctrv_jacobian(state: ArrayLike, dt: float) -> FloatArray:
    """5x5 Jacobian of :func:`ctrv_predict` with respect to the state (finite and exact
    through yaw_rate -> 0, the straight-line limit)."""
    _, _, yaw, v, w = np.asarray(state, dtype=float)
    f1, f2, d1, d2 = arc_functions(w * dt)
    c, s = math.cos(yaw), math.sin(yaw)
    ux, uy = c * f1 - s * f2, s * f1 + c * f2  # displacement per metre of travel
    F = np.eye(5)
    F[0, 2], F[1, 2] = -v * dt * uy, v * dt * ux
    F[0, 3], F[1, 3] = dt * ux, dt * uy
    F[0, 4] = v * dt * dt * (c * d1 - s * d2)
    F[1, 4] = v * dt * dt * (s * d1 + c * d2)
    F[2, 4] = dt
    return F


def integrate_odometry(
    start_pose: ArrayLike, t: ArrayLike, speed: ArrayLike, yaw_rate: ArrayLike
) -> FloatArray:
    """Dead-reckon poses at each odometry time.

    Args:
        start_pose: pose ``(x, y, yaw)`` at ``t[0]``.
        t: (N,) sample times in seconds, strictly increasing.
        speed: (N,) wheel speed in m/s; sample i holds from t[i] to t[i+1].
        yaw_rate: (N,) gyro yaw rate in rad/s, held like ``speed``.

    Returns:
        (N, 3) poses ``(x, y, yaw)`` at the sample times.
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(speed, dtype=float)
    w = np.asarray(yaw_rate, dtype=float)
    poses = np.empty((len(t), 3))
    x, y, yaw = (float(a) for a in np.asarray(start_pose, dtype=float))
    for i in range(len(t)):
        poses[i] = (x, y, yaw)
        if i + 1 < len(t):
            dt = t[i + 1] - t[i]
            dx, dy = ctrv_displacement(yaw, v[i], w[i], dt)
            x, y, yaw = x + dx, y + dy, float(wrap_angle(yaw + w[i] * dt))
    return poses
