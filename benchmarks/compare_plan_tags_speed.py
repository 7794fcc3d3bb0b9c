"""`semslam plan-tags` time of two versions of semslam on routes of growing length.

    git worktree add /tmp/baseline REV
    PYTHONPATH=. python benchmarks/compare_plan_tags_speed.py --baseline /tmp/baseline \
        [--seed 1] [--passes 1 2 4] [--count 1] [--work /tmp/plan-speed]

One `garage` drive (`semslam simulate --no-images`) is mapped once with this version; its
true route (groundtruth.tum) driven out and back ``passes`` times is the route to plan on
(each pass reversed from the last, time running on), so the route grows and the garage
does not. For each route, `semslam plan-tags MAP --route ROUTE --count COUNT
--random-trials 1` with the baseline's source tree and then with this one, alternating;
prints the wall time of each and whether their greedy steps agree.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from _common import report, run_python_in

HERE = Path(__file__).resolve().parents[1]


def semslam(root: Path, args: list[str]) -> str:
    return run_python_in(root, ["-m", "semslam", *args])


def passes_route(truth: Path, passes: int, out: Path) -> int:
    """Write ``truth`` (TUM) driven out and back ``passes`` times to ``out``; its length."""
    d = np.loadtxt(truth, ndmin=2)
    parts, t0 = [], 0.0
    for i in range(passes):
        p = (d if i % 2 == 0 else d[::-1]).copy()
        p[:, 0] = t0 + np.abs(p[:, 0] - p[0, 0])
        t0 = p[-1, 0] + 0.05
        parts.append(p)
    route = np.vstack(parts)
    np.savetxt(out, route, fmt="%.6f")
    return len(route)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="source tree to compare")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--passes", nargs="+", type=int, default=[1, 2, 4])
    parser.add_argument("--count", type=int, default=1)
    parser.add_argument("--work", type=Path, default=Path("/tmp/semslam-plan-speed"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    drive, map_path = args.work / f"garage-{args.seed}", args.work / f"garage-{args.seed}.json"
    if not (drive / "drive.json").exists():
        semslam(HERE, ["simulate", str(drive), "--seed", str(args.seed), "--no-images"])
    if not map_path.exists():
        semslam(HERE, ["map", str(drive), "-o", str(map_path), "--no-progress"])
    rows = []
    for passes in args.passes:
        route = args.work / f"route-{passes}.tum"
        poses = passes_route(drive / "groundtruth.tum", passes, route)
        row = {"passes": passes, "route_poses": poses}
        greedy = {}
        for version, root in (("baseline", args.baseline.resolve()), ("this", HERE)):
            out = args.work / f"plan-{passes}-{version}"
            started = time.perf_counter()
            semslam(root, ["plan-tags", str(map_path), "--route", str(route), "-o", str(out),
                           "--count", str(args.count), "--random-trials", "1"])
            row[f"{version}_s"] = round(time.perf_counter() - started, 2)
            greedy[version] = json.loads((out / "tag_plan.json").read_text())["greedy"]
        row["same_plan"] = greedy["baseline"] == greedy["this"]
        rows.append(row)
        print(row, file=sys.stderr, flush=True)
    lines = ["| passes | route poses | baseline s | this s | same plan |", "|" + " --- |" * 5]
    lines += [f"| {r['passes']} | {r['route_poses']} | {r['baseline_s']} | {r['this_s']} | "
              f"{r['same_plan']} |" for r in rows]
    report("\n".join(lines), {"count": args.count, "rows": rows}, args.json)


if __name__ == "__main__":
    main()
