"""Where a map's error comes from: the same world and route mapped with each noise source
switched off in turn, and whether the map's exported covariances know the error left.

Variants (one simulated world and route, `--seed`; the drive is re-simulated with the
simulator's odometry noise changed through `SEMSLAM_SIMULATION__ODOMETRY_NOISE__*`):

- as simulated: noisy observations, noisy odometry (the default drive);
- exact observations: the same drive mapped with `--observations exact`;
- perfect odometry: odometry noise all zero, noisy observations;
- exact observations, no gyro white noise: the odometry keeps its speed noise, scale and
  gyro bias;
- exact observations, no gyro bias: the odometry keeps its speed noise, scale and gyro
  white noise.

Runs the real commands (`semslam simulate`, `semslam map`, `semslam evaluate map`) in a
temporary folder, two at a time, and prints a Markdown table plus JSON. A `large` world
takes 10-15 minutes on two cores.

    python benchmarks/map_error_sources.py [--preset large] [--seed 4]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from _common import report, run_semslam

NOISE = "SEMSLAM_SIMULATION__ODOMETRY_NOISE__"
ODOMETRY = {  # drive name -> simulator odometry noise overrides
    "default": {},
    "perfect": {f"{NOISE}{k}": "0" for k in (
        "SPEED_SIGMA", "SPEED_SCALE_SIGMA", "GYRO_SIGMA", "GYRO_BIAS_SIGMA", "GYRO_BIAS_WALK")},
    "no-gyro-white": {f"{NOISE}GYRO_SIGMA": "0"},
    "no-gyro-bias": {f"{NOISE}GYRO_BIAS_SIGMA": "0", f"{NOISE}GYRO_BIAS_WALK": "0"},
}
VARIANTS = [  # (name, drive, observations)
    ("as simulated", "default", "noisy"),
    ("exact observations", "default", "exact"),
    ("perfect odometry", "perfect", "noisy"),
    ("exact observations, no gyro white noise", "no-gyro-white", "exact"),
    ("exact observations, no gyro bias", "no-gyro-bias", "exact"),
]
KEYS = ["corner_rmse_m", "corner_p95_m", "slots_true", "slots_matched", "false_slots",
        "wrong_merges", "corner_nees_mean", "corner_nees_median", "tags_rmse_m"]


def simulate(folder: Path, preset: str, seed: int, drive: str) -> Path:
    out = folder / drive
    run_semslam(["simulate", str(out), "--preset", preset, "--seed", str(seed), "--no-images",
                 "--no-progress"], ODOMETRY[drive])
    return out


def map_and_score(drive: Path, observations: str, out: Path) -> dict:
    run_semslam(["map", str(drive), "-o", str(out), "--observations", observations,
                 "--no-progress"])
    metrics = json.loads(run_semslam(["evaluate", "map", str(out), "--truth",
                                      str(drive / "world.json"), "--json"]))
    stats = json.loads(out.read_text())["metadata"]["statistics"]
    return {**{k: metrics[k] for k in KEYS}, "mapping_s": stats["mapping_s"]}


def _cell(value, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="large")
    parser.add_argument("--seed", type=int, default=4)
    parser.add_argument("--json", type=Path, help="also write the JSON here")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(2) as pool:
        folder = Path(tmp)
        drives = dict(zip(ODOMETRY, pool.map(
            lambda d: simulate(folder, args.preset, args.seed, d), ODOMETRY), strict=True))
        scores = list(pool.map(
            lambda v: map_and_score(drives[v[1]], v[2], folder / f"map-{VARIANTS.index(v)}.json"),
            VARIANTS))
    rows = [
        "| variant | corner RMSE m | p95 m | slots matched / true | false | wrong merges "
        "| corner NEES mean / median (2 / 1.39 if consistent) | tags RMSE m |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for (name, _, _), s in zip(VARIANTS, scores, strict=True):
        rows.append(
            f"| {name} | {_cell(s['corner_rmse_m'])} | {_cell(s['corner_p95_m'])} "
            f"| {s['slots_matched']} / {s['slots_true']} | {s['false_slots']} "
            f"| {s['wrong_merges']} | {_cell(s['corner_nees_mean'], 1)} / "
            f"{_cell(s['corner_nees_median'], 1)} | {_cell(s['tags_rmse_m'])} |"
        )
    result = {"preset": args.preset, "seed": args.seed,
              "variants": {name: s for (name, _, _), s in zip(VARIANTS, scores, strict=True)}}
    report("\n".join(rows), result, args.json)


if __name__ == "__main__":
    main()
