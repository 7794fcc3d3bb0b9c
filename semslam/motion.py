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

# Below this |yaw_rate * dt| the arc formulas lose precision; a second-order
# series is used instead (continuous with the exact formula).
_SMALL_TURN = 1e-6


def ctrv_displacement(yaw: float, v: float, yaw_rate: float, dt: float) -> tuple[float, float]:
    """Displacement ``(dx, dy)`` in the map frame of one CTRV step from heading ``yaw``."""
    turn = yaw_rate * dt
    if abs(turn) < _SMALL_TURN:
        c, s = math.cos(yaw + 0.5 * turn), math.sin(yaw + 0.5 * turn)
        return v * dt * c, v * dt * s
    return (
        v / yaw_rate * (math.sin(yaw + turn) - math.sin(yaw)),
        v / yaw_rate * (math.cos(yaw) - math.cos(yaw + turn)),
    )


def ctrv_predict(state: ArrayLike, dt: float) -> FloatArray:
    """State after ``dt`` seconds of CTRV motion; yaw wrapped to (-pi, pi]."""
    x, y, yaw, v, w = np.asarray(state, dtype=float)
    dx, dy = ctrv_displacement(yaw, v, w, dt)
    return np.array([x + dx, y + dy, wrap_angle(yaw + w * dt), v, w])


def ctrv_jacobian(state: ArrayLike, dt: float) -> FloatArray:
    """5x5 Jacobian of :func:`ctrv_predict` with respect to the state.

    Uses the straight-line limit (exact to second order in ``yaw_rate * dt``)
    when the turn over the step is tiny, so it stays finite as yaw_rate -> 0.
    """
    _, _, yaw, v, w = np.asarray(state, dtype=float)
    F = np.eye(5)
    turn = w * dt
    if abs(turn) < _SMALL_TURN:
        c, s = math.cos(yaw), math.sin(yaw)
        F[0, 2], F[1, 2] = -v * dt * s, v * dt * c
        F[0, 3], F[1, 3] = dt * c, dt * s
        F[0, 4], F[1, 4] = -0.5 * v * dt * dt * s, 0.5 * v * dt * dt * c
    else:
        s0, c0 = math.sin(yaw), math.cos(yaw)
        s1, c1 = math.sin(yaw + turn), math.cos(yaw + turn)
        F[0, 2] = v / w * (c1 - c0)
        F[1, 2] = v / w * (s1 - s0)
        F[0, 3] = (s1 - s0) / w
        F[1, 3] = (c0 - c1) / w
        F[0, 4] = v * dt * c1 / w - v * (s1 - s0) / (w * w)
        F[1, 4] = v * dt * s1 / w - v * (c0 - c1) / (w * w)
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
