"""Real garage drive: the localizer on its painted lines against the hand-made vector map.

The drive has no ground truth. Its odometry (the recording's own poses, which the drive's
odometry.csv dead-reckons to within 4 cm) places the slot-line detections within about
0.13 m (median) of the vector map, so it is the yardstick: the localized poses should put
the detections at least as close to the vector map, and should not wander from the
odometry by more than the vector map's own disagreement with it. Reported: the status
counts; the distance of every detected end point to the nearest vector-map line, placed
by the odometry and by the localized poses (median, p75, p95); the localized positions
against the odometry's, along and across the direction of travel.

    PYTHONPATH=. python benchmarks/bench_garage_bev_localization.py DRIVE [--map MAP.json]
        [--config LOCALIZATION.json] [--json out.json]

``DRIVE`` is a folder written by ``semslam import garage-bev`` (for example the ``--work``
folder's ``drive`` of ``bench_garage_bev.py``); ``--map`` defaults to its
``vector_map.json`` (markings only); ``--config`` holds the localization settings.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from _common import run_semslam


def end_point_distances(frames, poses: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distance (m) of every detected end point, placed by ``poses`` (one per frame), to
    the nearest of ``segments`` (S, 2, 2)."""
    from semslam.evaluation.line_map import point_segment_distances
    from semslam.geometry import transform_points

    points = [transform_points(pose, np.array([m.vA, m.vB]))
              for frame, pose in zip(frames, poses, strict=True) for m in frame.markings]
    if not points:
        return np.zeros(0)
    return point_segment_distances(np.concatenate(points), segments.reshape(-1, 4))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive", type=Path)
    parser.add_argument("--map", type=Path)
    parser.add_argument("--config", type=Path)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()

    from semslam.io import Drive, load_map, read_track_csv
    from semslam.motion import integrate_odometry

    drive = Drive.open(args.drive)
    map_path = args.map or args.drive / "vector_map.json"
    vector_map = load_map(args.drive / "vector_map.json")
    segments = np.array([[m.a, m.b] for m in vector_map.markings], dtype=float)
    frames = drive.observations("cached")
    odo = drive.odometry()
    reckoned = integrate_odometry(drive.start_pose, odo.t, odo.speed, odo.yaw_rate)
    t = np.array([f.t for f in frames])
    by_odometry = reckoned[np.clip(np.searchsorted(odo.t, t, side="right") - 1, 0, None)]

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "track.tum"
        cmd = ["localize", str(args.drive), "--map", str(map_path), "--observations",
               "cached", "-o", str(out), "--no-progress"]
        run_semslam(cmd + (["--config", str(args.config)] if args.config else []))
        track = read_track_csv(out.with_suffix(".csv"))
    localized = track.poses

    def stats(d: np.ndarray) -> dict:
        return {q: round(float(np.percentile(d, p)), 3)
                for q, p in (("median_m", 50), ("p75_m", 75), ("p95_m", 95))}

    c, s = np.cos(by_odometry[:, 2]), np.sin(by_odometry[:, 2])
    dx, dy = (localized[:, :2] - by_odometry[:, :2]).T
    along, across = c * dx + s * dy, -s * dx + c * dy
    status, counts = np.unique(track.status, return_counts=True)
    result = {
        "map": str(map_path),
        "frames": len(frames),
        "frames_with_detections": sum(bool(f.markings) for f in frames),
        "status": dict(zip(status.tolist(), counts.tolist(), strict=True)),
        "end_points_to_vector_map_by_odometry": stats(
            end_point_distances(frames, by_odometry, segments)),
        "end_points_to_vector_map_localized": stats(
            end_point_distances(frames, localized, segments)),
        "localized_minus_odometry": {
            "distance": stats(np.hypot(along, across)),
            "along_abs": stats(np.abs(along)),
            "across_abs": stats(np.abs(across)),
            "max_m": round(float(np.hypot(along, across).max()), 3),
        },
    }
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
