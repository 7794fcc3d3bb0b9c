"""The localizer's update time of two versions of semslam on the same drives, alternating.

    git worktree add /tmp/baseline REV
    PYTHONPATH=. python benchmarks/compare_localizer_speed.py --baseline /tmp/baseline \
        [--seeds 1 2 3] [--repeats 3] [--work /tmp/loc-speed]

Per seed, with this version: `semslam simulate` drives 0 and 1 of `garage` (no images) and
`semslam map` of drive 0 (noisy observations). Then drive 1 is localized against that map
(`localize_drive`, noisy observations, start pose given) by the baseline's source tree and
by this one, alternating ``--repeats`` times, so both meet the same machine load. Prints
the median per-frame update time (association + update, the figure of issue 4's 1 ms
target) of every run, and whether the two versions wrote the same trajectory.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from _common import report, run_python_in

HERE = Path(__file__).resolve().parents[1]

_LOCALIZE = """
import json, sys
from pathlib import Path
from semslam.config import SemslamConfig
from semslam.pipeline.localize import localize_drive
drive, map_path, out = (Path(a) for a in sys.argv[1:4])
summary = localize_drive(drive, map_path, out, "noisy", None, SemslamConfig(), False)
print(json.dumps({"update_ms_median": summary.update_ms_median}))
"""


def prepare(work: Path, seed: int) -> tuple[Path, Path]:
    """Drive 1 of `garage` ``seed`` and the map of its drive 0 (made once, this version)."""
    d0, d1, map_path = (work / f"garage-{seed}-{n}" for n in ("d0", "d1", "map.json"))
    for drive, n in ((d0, 0), (d1, 1)):
        if not (drive / "drive.json").exists():
            run_python_in(HERE, ["-m", "semslam", "simulate", str(drive), "--preset", "garage",
                                 "--seed", str(seed), "--drive", str(n), "--no-images",
                                 "--no-progress"])
    if not map_path.exists():
        run_python_in(HERE, ["-m", "semslam", "map", str(d0), "-o", str(map_path), "--no-progress"])
    return d1, map_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="source tree to compare")
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--work", type=Path, default=Path("/tmp/semslam-loc-speed"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed in args.seeds:
        drive, map_path = prepare(args.work, seed)
        times: dict[str, list[float]] = {"baseline": [], "this": []}
        for _ in range(args.repeats):
            for name, root in (("baseline", args.baseline.resolve()), ("this", HERE)):
                out = args.work / f"garage-{seed}-{name}.tum"
                command = ["-c", _LOCALIZE, str(drive), str(map_path), str(out)]
                got = json.loads(run_python_in(root, command))
                times[name].append(round(got["update_ms_median"], 3))
                print(seed, name, times[name][-1], file=sys.stderr, flush=True)
        same = ((args.work / f"garage-{seed}-baseline.tum").read_text()
                == (args.work / f"garage-{seed}-this.tum").read_text())
        rows.append({"seed": seed, "baseline_ms": times["baseline"], "this_ms": times["this"],
                     "baseline_median_ms": statistics.median(times["baseline"]),
                     "this_median_ms": statistics.median(times["this"]),
                     "same_trajectory": same})
    lines = ["| seed | baseline update ms (runs) | this update ms (runs) | medians | same "
             "trajectory |", "|" + " --- |" * 5]
    lines += [f"| {r['seed']} | {' / '.join(map(str, r['baseline_ms']))} | "
              f"{' / '.join(map(str, r['this_ms']))} | {r['baseline_median_ms']} -> "
              f"{r['this_median_ms']} | {'yes' if r['same_trajectory'] else 'NO'} |"
              for r in rows]
    report("\n".join(lines), {"rows": rows}, args.json)


if __name__ == "__main__":
    main()
