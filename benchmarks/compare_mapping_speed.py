"""Mapping time of two versions of semslam on the same drives, one after the other.

    git worktree add /tmp/baseline REV
    PYTHONPATH=. python benchmarks/compare_mapping_speed.py --baseline /tmp/baseline \
        [--presets garage] [--seeds 1 2 3 4 5] [--false-rates 0.05 0.5 0.8] [--work /tmp/speed]

Per drive (`semslam simulate --no-images`, made once with the current version; with
``--false-rates``, one drive per expected fraction of false slot detections), `semslam
map` with the baseline's source tree and then with this one, alternating, so both meet the
same machine load; prints mapping time (the map's own ``mapping_s``: frames in to map out,
no file I/O) and its association part, the wall time of the whole command (``command_s``:
Python's start, imports, reading the drive, mapping, writing the map and its siblings),
driving time, speed-up against driving and the map's score for both. The maps should agree
to the digits shown when the change is only about speed.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

from _common import report, run_python_in

HERE = Path(__file__).resolve().parents[1]


def semslam(root: Path, args: list[str]) -> str:
    """``python -m semslam ARGS`` with the package imported from the source tree ``root``."""
    return run_python_in(root, ["-m", "semslam", *args])


def measure(root: Path, drive: Path, out: Path) -> dict:
    started = time.perf_counter()
    semslam(root, ["map", str(drive), "-o", str(out), "--no-progress"])
    command_s = round(time.perf_counter() - started, 2)
    score = json.loads(semslam(root, ["evaluate", "map", str(out), "--truth",
                                      str(drive / "world.json"), "--json"]))
    stats = json.loads(out.read_text())["metadata"]["statistics"]
    return {"mapping_s": stats["mapping_s"], "association_s": stats["association_s"],
            "driving_s": stats["driving_s"],
            "speedup": round(stats["driving_s"] / stats["mapping_s"], 1), "command_s": command_s,
            "command_speedup": round(stats["driving_s"] / command_s, 1),
            "corner_rmse_m": round(score["corner_rmse_m"], 4),
            "slots_matched": score["slots_matched"], "duplicates": score["duplicate_slots"],
            "wrong_merges": score["wrong_merges"], "false_slots": score["false_slots"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="source tree to compare")
    parser.add_argument("--presets", nargs="+", default=["garage"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    parser.add_argument("--false-rates", nargs="+", type=float, default=[None],
                        help="slot_false_rate of the simulated drives (default: the simulator's)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/semslam-speed"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    rows = []
    for preset in args.presets:
        for seed, rate in itertools.product(args.seeds, args.false_rates):
            name = f"{preset}-{seed}" + ("" if rate is None else f"-false{rate}")
            drive = args.work / name
            if not (drive / "drive.json").exists():
                config = []
                if rate is not None:
                    path = args.work / f"{name}.config.json"
                    path.write_text(json.dumps({"simulation": {"observation_noise": {
                        "slot_false_rate": rate}}}))
                    config = ["--config", str(path)]
                semslam(HERE, ["simulate", str(drive), "--preset", preset, "--seed", str(seed),
                               "--no-images", *config])
            for version, root in (("baseline", args.baseline.resolve()), ("this", HERE)):
                row = measure(root, drive, args.work / f"{name}-{version}.json")
                rows.append({"preset": preset, "seed": seed, "false_rate": rate,
                             "version": version, **row})
                print(rows[-1], file=sys.stderr, flush=True)
    lines = ["| preset | seed | false rate | version | mapping s | association s | "
             "whole command s | driving s | faster than driving (mapping / command) | "
             "corner RMSE m | matched | duplicates | wrong merges | false slots mapped |",
             "|" + " --- |" * 14]
    lines += [f"| {r['preset']} | {r['seed']} | {r['false_rate'] or 'default'} | "
              f"{r['version']} | {r['mapping_s']} | {r['association_s']} | "
              f"{r['command_s']} | {r['driving_s']} | {r['speedup']}x / "
              f"{r['command_speedup']}x | {r['corner_rmse_m']} | "
              f"{r['slots_matched']} | {r['duplicates']} | {r['wrong_merges']} | "
              f"{r['false_slots']} |" for r in rows]
    report("\n".join(lines), {"rows": rows}, args.json)


if __name__ == "__main__":
    main()
