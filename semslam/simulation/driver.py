"""Drive a route with the CTRV model: true trajectory and noisy wheel-speed + gyro odometry.

A pure-pursuit steering law and a speed profile (a smooth random target
between ``min_speed`` and ``max_speed``, slowed for curvature, limited in
acceleration) give speed and yaw rate for each odometry step; the true pose
advances by the exact CTRV arc with those held constant over the step, so
integrating the true odometry reproduces the truth to rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semslam.config import DriveConfig, OdometryNoiseConfig
from semslam.geometry import FloatArray, wrap_angle
from semslam.motion import ctrv_displacement
from semslam.simulation.route import Path


@dataclass(frozen=True, eq=False)
class DriveRecord:
    """A simulated drive at the odometry rate.

    Attributes:
        t: (N,) times, s, starting at 0.
        poses: (N, 3) true poses ``mTv`` (x, y, yaw) in the map frame.
        speed, yaw_rate: (N,) true speed (m/s) and yaw rate (rad/s), held from t[i] to t[i+1].
        odo_speed, odo_yaw_rate: (N,) what the wheel encoders and the gyro report.
        frame_index: (M,) indices into ``t`` of the camera frames.
    """

    t: FloatArray
    poses: FloatArray
    speed: FloatArray
    yaw_rate: FloatArray
    odo_speed: FloatArray
    odo_yaw_rate: FloatArray
    frame_index: np.ndarray


def _speed_targets(path: Path, cfg: DriveConfig, rng: np.random.Generator) -> FloatArray:
    """Target speed along the path (per path sample), m/s."""
    # smooth random profile: knots every ~25 m, cosine-interpolated
    n_knots = max(2, int(path.length // 25.0) + 2)
    # knots from 0.3 m/s above the floor (the curvature limits slow the car further), or
    # at the ceiling where the two are closer than that
    knots = rng.uniform(min(cfg.min_speed + 0.3, cfg.max_speed), cfg.max_speed, n_knots)
    u = path.s / path.length * (n_knots - 1)
    i0 = np.minimum(u.astype(int), n_knots - 2)
    f = (1 - np.cos(np.pi * (u - i0))) / 2.0
    target = knots[i0] * (1 - f) + knots[i0 + 1] * f
    # slow for curvature, looking ahead by the braking distance
    with np.errstate(divide="ignore"):
        v_turn = np.sqrt(cfg.lateral_accel / np.maximum(np.abs(path.curvature), 1e-9))
    target = np.minimum(target, v_turn)
    # backward pass: be able to brake into each slow part
    for k in range(len(target) - 2, -1, -1):
        ds = path.s[k + 1] - path.s[k]
        target[k] = min(target[k], math.sqrt(target[k + 1] ** 2 + 2 * cfg.accel * ds))
    return np.clip(target, cfg.min_speed, cfg.max_speed)


def drive_path(
    path: Path,
    cfg: DriveConfig,
    noise: OdometryNoiseConfig,
    rng: np.random.Generator,
) -> DriveRecord:
    """Follow ``path`` from its first point and heading until its end."""
    dt = 1.0 / cfg.odometry_rate
    steps_per_frame = max(1, int(round(cfg.odometry_rate / cfg.frame_rate)))
    target = _speed_targets(path, cfg, rng)
    p0, p1 = path.points[0], path.points[min(5, len(path.points) - 1)]
    x, y, yaw = float(p0[0]), float(p0[1]), math.atan2(p1[1] - p0[1], p1[0] - p0[0])
    v, w = float(target[0]), 0.0
    idx = 0
    ts, poses, vs, ws = [], [], [], []
    t = 0.0
    max_steps = int(4 * path.length / cfg.min_speed / dt) + 100
    for _ in range(max_steps):
        # progress: nearest path sample ahead of the current one
        window = path.points[idx : idx + 200]
        idx += int(np.argmin(np.sum((window - (x, y)) ** 2, axis=1)))
        if path.length - path.s[idx] < 0.5:
            break
        if cfg.max_duration is not None and t > cfg.max_duration:
            break
        lookahead = max(2.5, 1.2 * v)
        j = int(np.searchsorted(path.s, path.s[idx] + lookahead))
        j = min(j, len(path.points) - 1)
        gx, gy = path.points[j] - (x, y)
        alpha = float(wrap_angle(math.atan2(gy, gx) - yaw))
        w_cmd = 2.0 * v * math.sin(alpha) / max(lookahead, 1e-3)
        w_cmd = max(-0.8, min(0.8, w_cmd))
        w += (w_cmd - w) * min(1.0, dt / 0.15)  # steering lag
        dv = target[idx] - v
        v += max(-cfg.accel * dt, min(cfg.accel * dt, dv))
        ts.append(t)
        poses.append((x, y, yaw))
        vs.append(v)
        ws.append(w)
        dx, dy = ctrv_displacement(yaw, v, w, dt)
        x, y, yaw = x + dx, y + dy, float(wrap_angle(yaw + w * dt))
        t = round(t + dt, 9)
    t_arr = np.array(ts)
    # end on a whole frame
    n = (len(t_arr) - 1) // steps_per_frame * steps_per_frame + 1
    t_arr = t_arr[:n]
    speed, yaw_rate = np.array(vs)[:n], np.array(ws)[:n]
    odo_speed, odo_rate = odometry_with_errors(speed, yaw_rate, dt, noise, rng)
    return DriveRecord(
        t=t_arr,
        poses=np.array(poses)[:n],
        speed=speed,
        yaw_rate=yaw_rate,
        odo_speed=odo_speed,
        odo_yaw_rate=odo_rate,
        frame_index=np.arange(0, n, steps_per_frame),
    )


def odometry_with_errors(
    speed: FloatArray,
    yaw_rate: FloatArray,
    dt: float | FloatArray,
    noise: OdometryNoiseConfig,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """Wheel speed (m/s) and yaw rate (rad/s) as an automotive odometry reports them: speed
    times one scale error per drive plus white noise; yaw rate plus a constant bias, its
    random walk and white noise (``noise``; ``dt``: seconds from each sample to the next,
    a scalar or one per sample). Used for simulated drives and to add drift to a recorded
    drive whose odometry is its ground truth. The draws are taken component by component
    from ``rng``, so the gyro noise depends on the number of samples: a drive cut short
    (``max_duration``) has the same speeds and observations as the start of the whole
    drive, but other gyro noise."""
    n = len(speed)
    scale = 1.0 + rng.normal(0.0, noise.speed_scale_sigma)
    odo_speed = np.asarray(speed) * scale + rng.normal(0.0, noise.speed_sigma, n)
    bias = rng.normal(0.0, noise.gyro_bias_sigma) + np.cumsum(
        rng.normal(0.0, noise.gyro_bias_walk * np.sqrt(dt), n)
    )
    odo_rate = np.asarray(yaw_rate) + bias + rng.normal(0.0, noise.gyro_sigma, n)
    return odo_speed, odo_rate
