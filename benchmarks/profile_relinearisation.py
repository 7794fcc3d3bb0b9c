"""Where the mapper's iSAM2 time goes on a long drive: every update's time, and at every
relinearisation check how many variables move and the step of a few watched poses.

Maps a simulated drive (noisy observations) with the default configuration and prints the
checks that moved more than ``--show`` variables, then a summary per 500 keyframes
(updates, total and median update time). A step that changes sign from one check to the
next at the same pose is Gauss-Newton swinging, not new information.

    PYTHONPATH=. python benchmarks/profile_relinearisation.py DRIVE [--watch 1000 2000 3000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from gtsam.symbol_shorthand import X

from semslam.config import load_config
from semslam.io import Drive
from semslam.mapping.mapper import Mapper


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive")
    parser.add_argument("--watch", type=int, nargs="+", default=[1000, 2000, 3000])
    parser.add_argument("--show", type=int, default=300, help="checks moving more than this")
    args = parser.parse_args()
    drive = Drive.open(args.drive)
    odometry = drive.odometry()
    mapper = Mapper(load_config(None).mapping, drive.start_pose, odometry.t, odometry.speed,
                    odometry.yaw_rate)
    graph = mapper.graph
    updates: list[tuple[int, float]] = []  # (keyframes, seconds)
    checks: list[dict] = []
    timed_update, predicted = graph.update, graph._relinearized_by_isam2

    def update() -> None:
        start = time.perf_counter()
        timed_update()
        updates.append((len(mapper.keyframe_times), time.perf_counter() - start))

    def relinearised() -> list[int]:
        delta = graph.isam.getDelta()
        steps = {k: np.round(delta.at(X(k)), 3).tolist() for k in args.watch
                 if delta.exists(X(k))}
        moved = predicted()
        checks.append({"keyframes": len(mapper.keyframe_times), "moved": len(moved),
                       "variables": graph._theta.size(), "steps": steps})
        return moved

    graph.update, graph._relinearized_by_isam2 = update, relinearised
    start = time.perf_counter()
    for frame in drive.observations("noisy"):
        mapper.add_frame(frame)
    print(f"incremental pass {time.perf_counter() - start:.1f} s, "
          f"{len(updates)} updates {sum(t for _, t in updates):.1f} s")
    took = dict(updates)
    for c in checks:
        if c["moved"] > args.show:
            print(f"keyframe {c['keyframes']}: {c['moved']} of {c['variables']} moved, "
                  f"{took.get(c['keyframes'], 0.0):.2f} s; steps {c['steps']}")
    kf = np.array([k for k, _ in updates])
    dt = np.array([t for _, t in updates])
    print("| keyframes | updates | seconds | median ms |")
    print("|---|---|---|---|")
    for lo in range(0, int(kf.max()) + 1, 500):
        sel = (kf >= lo) & (kf < lo + 500)
        if sel.any():
            print(f"| {lo}-{lo + 499} | {sel.sum()} | {dt[sel].sum():.1f} | "
                  f"{1e3 * np.median(dt[sel]):.0f} |")


if __name__ == "__main__":
    main()
