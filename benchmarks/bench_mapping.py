"""Mapping benchmark: accuracy on the simulated garage (robust vs plain least squares vs
odometry only) and mapping time against driving time for small / garage / large.

Runs the real commands (`semslam simulate`, `semslam map`, `semslam evaluate map`) in a
temporary folder and prints a Markdown table plus JSON.

    python benchmarks/bench_mapping.py [--presets small garage large] [--seeds 1 2 3]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from _common import run_semslam

KEYS = ["corner_rmse_m", "corner_p95_m", "slots_true", "slots_mapped", "slots_matched",
        "duplicate_slots", "false_slots", "wrong_merges", "id_accuracy", "tags_rmse_m",
        "corner_nees_mean", "corner_nees_median", "id_brier", "id_confident_accuracy",
        "marking_nees_mean", "marking_nees_median"]

VARIANTS = {
    "maxmix (default)": ([], {}),
    "plain least squares, same front end": (["--robust", "none"], {}),
    "plain least squares, IDs trusted, every detection kept": (
        ["--robust", "none"],
        {"SEMSLAM_MAPPING__ID_GATE": "1000", "SEMSLAM_MAPPING__NEW_LANDMARK_OBSERVATIONS": "1",
         "SEMSLAM_MAPPING__MIN_ACCEPTED_OBSERVATIONS": "1"},
    ),
    "odometry only (--optimizer none)": (["--optimizer", "none"], {}),
}


run = run_semslam


def map_and_score(drive: Path, out: Path, extra: list[str], env: dict[str, str]) -> dict:
    run(["map", str(drive), "-o", str(out), "--no-progress", *extra], env)
    metrics = json.loads(run(["evaluate", "map", str(out), "--truth",
                              str(drive / "world.json"), "--json"]))
    stats = json.loads(out.read_text())["metadata"]["statistics"]
    return {**{k: metrics[k] for k in KEYS}, "mapping_s": stats["mapping_s"],
            "driving_s": stats["driving_s"], "speedup": stats["speedup"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["small", "garage", "large"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1])
    parser.add_argument("--variants", action="store_true", help="also run the baselines")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for preset in args.presets:
            for seed in args.seeds:
                drive = Path(tmp) / f"{preset}-{seed}"
                run(["simulate", str(drive), "--preset", preset, "--seed", str(seed),
                     "--no-images", "--no-progress"])
                variants = VARIANTS if args.variants else {"maxmix (default)": ([], {})}
                for name, (extra, env) in variants.items():
                    row = map_and_score(drive, Path(tmp) / f"{preset}-{seed}.json", extra, env)
                    results.append({"preset": preset, "seed": seed, "variant": name, **row})
                    print(json.dumps(results[-1]), file=sys.stderr, flush=True)
    cols = ["preset", "seed", "variant", "corner_rmse_m", "corner_p95_m", "slots_true",
            "slots_matched", "duplicate_slots", "false_slots", "wrong_merges", "id_accuracy",
            "id_brier", "id_confident_accuracy", "corner_nees_mean", "corner_nees_median",
            "marking_nees_mean", "marking_nees_median", "driving_s", "mapping_s", "speedup"]
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in results:
        cells = [f"{r[c]:.3f}" if isinstance(r[c], float) and c.endswith(("_m", "accuracy"))
                 else f"{r[c]:.2f}" if isinstance(r[c], float) and "nees" in c
                 else f"{r[c]:.1e}" if isinstance(r[c], float) and "brier" in c
                 else str(r[c]) for c in cols]
        print("| " + " | ".join(cells) + " |")
    print(json.dumps(results))


if __name__ == "__main__":
    main()
