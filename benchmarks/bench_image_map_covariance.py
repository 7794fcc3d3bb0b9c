"""Do maps from images know their error? Corner NEES of the map and the localizer's NEES.

For each seed: the `garage` world's drives 0 and 1 simulated with images, perceived once
(the cached observation set, as ``bench_slot_corner_errors.py --save-observations`` writes
it), drive 0 mapped twice from those detections:

- ``error model``: as perceived, each detection declaring its own and its shared error
  (``SlotObservation.corner_sigma_own`` / ``_shared``): slot covariances from the sandwich
  of :mod:`semslam.mapping.shared_error`;
- ``graph marginals``: the same detections with the two declarations removed: the graph's
  marginals under the weight ``corner_sigma`` alone (semslam before 2026-12-02);

each map scored against the truth (`semslam evaluate map`: corner RMSE, corner NEES; 2 is
honest), and drive 1 localized against each from no initial pose (`semslam localize --init
auto`, the demo's second half) and scored (`semslam evaluate trajectory`: ATE, NEES; 3 is
honest). The estimates of the two maps are the same: only their covariances differ.

    PYTHONPATH=. python benchmarks/bench_image_map_covariance.py --seeds 1 2 3 --work DIR

Drive folders already in ``DIR`` (``s{seed}d{drive}``) are reused, with their cached set
if they have one.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from dataclasses import replace
from pathlib import Path

from _common import report, run_semslam

from semslam.config import load_config
from semslam.io import Drive
from semslam.io.observations import read_observations, write_observations
from semslam.pipeline.perceive import perceive_drive

VARIANTS = ("error model", "graph marginals")


def drive_with_detections(work: Path, seed: int, drive: int) -> Path:
    """The drive folder, simulated and perceived unless already there."""
    folder = work / f"s{seed}d{drive}"
    if not (folder / "drive.json").is_file():
        run_semslam(["simulate", str(folder), "--preset", "garage", "--seed", str(seed),
                     "--drive", str(drive)])
    cached = folder / "observations" / "cached.jsonl"
    if not cached.is_file():
        frames = perceive_drive(Drive.open(folder), load_config(None), show_progress=False)
        write_observations(cached, frames)
    return folder


def without_error_model(folder: Path) -> Path:
    """A copy of the drive folder (images linked) whose cached detections declare no own or
    shared error."""
    plain = folder.with_name(folder.name + "-plain")
    if plain.exists():
        shutil.rmtree(plain)
    (plain / "observations").mkdir(parents=True)
    for item in folder.iterdir():
        if item.name != "observations":
            (plain / item.name).symlink_to(item.resolve())
    frames = read_observations(folder / "observations" / "cached.jsonl")
    stripped = [replace(f, slots=tuple(replace(s, corner_sigma_own=None,
                                               corner_sigma_shared=None) for s in f.slots))
                for f in frames]
    write_observations(plain / "observations" / "cached.jsonl", stripped)
    return plain


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--work", type=Path, required=True, help="folder for the drives")
    parser.add_argument("--json", type=Path, help="write the rows here too")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed in args.seeds:
        mapping, localizing = (drive_with_detections(args.work, seed, d) for d in (0, 1))
        sources = {"error model": mapping, "graph marginals": without_error_model(mapping)}
        for variant, folder in sources.items():
            tag = f"s{seed}-{variant.replace(' ', '-')}"
            map_path = args.work / f"{tag}.json"
            started = time.perf_counter()
            run_semslam(["map", str(folder), "--observations", "cached", "-o", str(map_path)])
            statistics = json.loads(map_path.read_text())["metadata"]["statistics"]
            scored = json.loads(run_semslam(["evaluate", "map", str(map_path), "--truth",
                                             str(mapping / "world.json"), "--json"]))
            track = args.work / f"{tag}.tum"
            run_semslam(["localize", str(localizing), "--map", str(map_path), "-o", str(track),
                         "--init", "auto", "--observations", "cached"])
            tracked = json.loads(run_semslam(["evaluate", "trajectory", str(track), "--truth",
                                              str(localizing / "groundtruth.tum"), "--map",
                                              str(map_path), "--json"]))
            rows.append({
                "seed": seed,
                "covariances": variant,
                "corner_rmse_m": round(scored["corner_rmse_m"], 4),
                "corner_nees_mean": round(scored["corner_nees_mean"], 2),
                "corner_nees_median": round(scored["corner_nees_median"], 2),
                "slot_covariance_s": statistics.get("slot_covariance_s"),
                "map_command_s": round(time.perf_counter() - started, 1),
                "ate_rmse_m": round(tracked["ate_rmse_m"], 4),
                "yaw_rmse_deg": round(tracked["yaw_rmse_deg"], 3),
                "localizer_nees_mean": round(tracked["nees_mean"], 2),
            })
            print(json.dumps(rows[-1]), flush=True)
    header = list(rows[0])
    table = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    table += ["| " + " | ".join(str(r[h]) for h in header) + " |" for r in rows]
    report("\n".join(table), {"rows": rows}, args.json)


if __name__ == "__main__":
    main()
