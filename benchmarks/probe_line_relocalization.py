"""Could painted lines alone relocalize the starts that see no slot and no tag? (issue 4)

`bench_localization.py --observability-only` finds starts of its 100 random `--init auto`
trials in which, for 2 s, the exact sensor reports painted lines but no slot and no tag
(the turns at the row ends). This probe asks whether those lines would fix the pose:

- the noisy line detections of the 2 s are merged into the vehicle frame of the last frame
  by dead reckoning the drive's own odometry (what the localizer's recent-frames memory
  does for slots), and sampled every 0.2 m along each segment;
- the fit of a pose is the mean distance of the moved samples to the nearest painted line
  of the map (``semslam map`` of drive 0, noisy observations), truncated at 0.3 m, on a
  5 cm distance transform: 0 is a perfect fit, 0.3 m fits nothing;
- an exhaustive search over the map (yaw every 2 deg, position every 0.2 m, on at most 120 of
  the samples) then a local
  refinement (0.5 deg, 0.05 m) of the 30 best poses and of the true pose.

A start could be relocalized from its lines only if the best pose lies at the truth and
no distinct pose (more than 1 m or 10 deg away) fits nearly as well. Printed per start:
the fit at the (refined) true pose, the best distinct pose's fit and its distance from the
truth.

    PYTHONPATH=. python benchmarks/probe_line_relocalization.py [--seeds 1 2 3 4 5]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import numpy as np
from bench_localization import _random_starts, _sees, _truth_at, simulate_and_map

from semslam.geometry import between, wrap_angle
from semslam.motion import integrate_odometry

RES = 0.05  # m per pixel of the distance transform
TRUNCATE = 0.3  # m: a sample farther than this from every line counts this much
SAMPLE = 0.2  # m between samples along a detected segment
DISTINCT_M, DISTINCT_DEG = 1.0, 10.0
COARSE_SAMPLES = 120  # samples scored in the exhaustive search (all in the refinement)


class LineFit:
    """Mean truncated distance of points to the map's painted lines, on a raster."""

    def __init__(self, markings) -> None:
        import cv2

        ends = np.array([[m.a, m.b] for m in markings], float)
        self.origin = ends.reshape(-1, 2).min(0) - 15.0
        size = np.ceil((ends.reshape(-1, 2).max(0) + 15.0 - self.origin) / RES).astype(int)
        img = np.full((size[1], size[0]), 255, np.uint8)
        for a, b in (ends - self.origin) / RES:
            cv2.line(img, tuple(int(round(c)) for c in a), tuple(int(round(c)) for c in b), 0, 1)
        self.cost = np.minimum(cv2.distanceTransform(img, cv2.DIST_L2, 5) * RES, TRUNCATE)
        self.lo = self.origin + 5.0
        self.hi = self.origin + size * RES - 5.0

    def at(self, points: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """(K,) fit of (N, 2) vehicle-frame points at (K, 3) poses."""
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        x = poses[:, None, 0] + c[:, None] * points[:, 0] - s[:, None] * points[:, 1]
        y = poses[:, None, 1] + s[:, None] * points[:, 0] + c[:, None] * points[:, 1]
        ix = np.clip(((x - self.origin[0]) / RES).astype(int), 0, self.cost.shape[1] - 1)
        iy = np.clip(((y - self.origin[1]) / RES).astype(int), 0, self.cost.shape[0] - 1)
        return self.cost[iy, ix].mean(axis=1)

    def search(self, points: np.ndarray, yaw_step_deg: float = 2.0, step: float = 0.2):
        """Every pose on the grid: (M, 4) rows ``fit, x, y, yaw``, best first (the 400 best
        per yaw), scored on at most :data:`COARSE_SAMPLES` of the points (a fixed draw)."""
        if len(points) > COARSE_SAMPLES:
            pick = np.random.default_rng(0).choice(len(points), COARSE_SAMPLES, replace=False)
            points = points[pick]
        xs = np.arange(self.lo[0], self.hi[0], step)
        ys = np.arange(self.lo[1], self.hi[1], step)
        k = int(round(step / RES))
        rows = []
        for yaw in np.radians(np.arange(0.0, 360.0, yaw_step_deg)):
            c, s = math.cos(yaw), math.sin(yaw)
            moved = points @ np.array([[c, s], [-s, c]])
            total = np.zeros((len(ys), len(xs)))
            for qx, qy in moved:
                ix0 = int(round((self.lo[0] + qx - self.origin[0]) / RES))
                iy0 = int(round((self.lo[1] + qy - self.origin[1]) / RES))
                ix = np.clip(ix0 + k * np.arange(len(xs)), 0, self.cost.shape[1] - 1)
                iy = np.clip(iy0 + k * np.arange(len(ys)), 0, self.cost.shape[0] - 1)
                total += self.cost[np.ix_(iy, ix)]
            total /= len(moved)
            best = np.argpartition(total.ravel(), 400)[:400]
            r, q = np.unravel_index(best, total.shape)
            rows.append(np.stack([total[r, q], xs[q], ys[r], np.full(len(best), yaw)], 1))
        rows = np.concatenate(rows)
        return rows[np.argsort(rows[:, 0])]

    def refine(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """``fit, x, y, yaw`` of the best pose within 0.3 m and 3 deg of ``pose``."""
        d = np.arange(-0.3, 0.301, 0.05)
        a = np.radians(np.arange(-3.0, 3.01, 0.5))
        grid = np.array([(pose[0] + dx, pose[1] + dy, pose[2] + da)
                         for dx in d for dy in d for da in a])
        f = self.at(points, grid)
        k = int(np.argmin(f))
        return np.array([f[k], *grid[k]])


def merged_line_samples(frames, first: int, odo_pose_at) -> tuple[np.ndarray, int]:
    """Samples of the line detections of the 2 s from frame ``first``, in the vehicle
    frame of the last of those frames (dead reckoning), and that last frame's index."""
    t0 = frames[first].t
    last = first
    while last + 1 < len(frames) and frames[last + 1].t - t0 <= 2.0:
        last += 1
    now = odo_pose_at(frames[last].t)
    points = []
    for f in frames[first : last + 1]:
        rel = between(now, odo_pose_at(f.t))
        c, s = math.cos(rel[2]), math.sin(rel[2])
        for m in f.markings:
            n = max(2, int(np.hypot(*(m.vB - m.vA)) / SAMPLE) + 1)
            for u in np.linspace(0.0, 1.0, n):
                p = m.vA + (m.vB - m.vA) * u
                points.append((rel[0] + c * p[0] - s * p[1], rel[1] + s * p[0] + c * p[1]))
    return np.array(points, float).reshape(-1, 2), last


def probe(drive_dir: Path, map_path: Path, seed: int) -> list[dict]:
    from semslam.io import Drive, load_map

    drive = Drive.open(drive_dir)
    frames = drive.observations("noisy")
    exact = drive.observations("exact")
    truth_t, truth_poses = drive.groundtruth()
    odo = drive.odometry()
    dead = integrate_odometry(np.zeros(3), odo.t, odo.speed, odo.yaw_rate)
    dead_yaw = np.unwrap(dead[:, 2])

    def odo_pose_at(t: float) -> np.ndarray:
        return np.array([np.interp(t, odo.t, dead[:, 0]), np.interp(t, odo.t, dead[:, 1]),
                         np.interp(t, odo.t, dead_yaw)])

    fit = LineFit(load_map(map_path).markings)
    rng = np.random.default_rng(seed)  # the trials' own draws (bench_localization.py)
    rows = []
    for first in (int(k) for k in _random_starts(rng, len(frames), 100)):
        if _sees(exact, first, 2.0, lines=False) or not _sees(exact, first, 2.0, lines=True):
            continue
        points, last = merged_line_samples(frames, first, odo_pose_at)
        truth = _truth_at(truth_t, truth_poses, frames[last].t)
        if not len(points):
            rows.append({"seed": seed, "start": first, "samples": 0})
            continue
        at_truth = fit.refine(points, truth)
        coarse = fit.search(points)
        refined = np.array([fit.refine(points, r[1:]) for r in coarse[:30]])
        far = (np.hypot(refined[:, 1] - truth[0], refined[:, 2] - truth[1]) > DISTINCT_M) | (
            np.degrees(np.abs(wrap_angle(refined[:, 3] - truth[2]))) > DISTINCT_DEG)
        rival = refined[far][np.argmin(refined[far, 0])] if far.any() else None
        rows.append({
            "seed": seed, "start": first, "samples": len(points),
            "fit_at_truth_m": round(float(at_truth[0]), 3),
            "best_distinct_fit_m": None if rival is None else round(float(rival[0]), 3),
            "best_distinct_from_truth_m": None if rival is None else round(float(
                np.hypot(rival[1] - truth[0], rival[2] - truth[1])), 1),
            "best_distinct_yaw_off_deg": None if rival is None else round(float(
                np.degrees(abs(wrap_angle(rival[3] - truth[2])))), 0),
            "truth_fits_best": bool(rival is None or at_truth[0] < rival[0]),
        })
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1])
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for seed in args.seeds:
            rows += probe(*simulate_and_map(root, seed), seed)
    probed = [r for r in rows if r.get("samples")]
    print(json.dumps({
        "line_only_starts": len(rows),
        "with_line_samples": len(probed),
        "truth_fits_best": sum(r["truth_fits_best"] for r in probed),
    }))


if __name__ == "__main__":
    main()
