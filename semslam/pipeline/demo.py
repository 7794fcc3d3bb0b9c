"""`semslam demo`: the main job on the built-in default, in one command.

Simulates a ``garage`` drive and a second drive through the same world (images
rendered), runs perception on the images of both (slots, IDs and lines from the top
views, tags from the front camera), maps the first drive, localizes the second against
that map from no initial pose, evaluates both against the simulator's truth, and writes
a short report (``report.md`` with pictures) into the output folder::

    OUT/drive_map/  OUT/drive_localize/   the two drive folders
    OUT/map.json (+ siblings)             the map (as `semslam map` writes it)
    OUT/trajectory.tum, trajectory.csv    the localized drive
    OUT/report.md, OUT/pictures/*.png     the report
    OUT/results.json                      every figure of the report
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from semslam.config import SemslamConfig
from semslam.errors import SemslamError


def check_demo_folder(out_dir: Path) -> None:
    """Refuse an ``out_dir`` that holds files but no earlier demo (its ``results.json``, or
    the mapping drive it writes first): the demo writes map.json, report.md and more there,
    over whatever has those names."""
    out = Path(out_dir)
    if not out.is_dir() or not any(out.iterdir()):
        return
    if (out / "results.json").is_file() or (out / "drive_map" / "drive.json").is_file():
        return
    raise SemslamError(
        f"{out}: folder is not empty and holds no earlier demo, whose files the demo would "
        "replace; choose another folder"
    )


def run_demo(
    out_dir: Path,
    config: SemslamConfig,
    preset: str = "garage",
    seed: int = 1,
    show_progress: bool | None = None,
    log=print,
) -> dict[str, Any]:
    """Run the whole demo into ``out_dir``; the results (also in ``results.json``)."""
    import cv2

    from semslam.evaluation.trajectory_metrics import interpolate_poses
    from semslam.io import Drive, load_map
    from semslam.io.atomic import atomic_write_bytes, atomic_write_text
    from semslam.io.images import read_image
    from semslam.io.track_csv import read_track_csv
    from semslam.io.tum import read_tum
    from semslam.perception.topview_perception import TopviewPerception
    from semslam.pipeline.detect import draw_overlay
    from semslam.pipeline.evaluate import evaluate_map_files, evaluate_trajectory_files
    from semslam.pipeline.localize import localize_drive
    from semslam.pipeline.mapping import build_map
    from semslam.pipeline.simulate import simulate
    from semslam.plots import audit_figure, error_figure, map_figure, trajectory_figure

    out = Path(out_dir)
    check_demo_folder(out)
    out.mkdir(parents=True, exist_ok=True)
    pictures = out / "pictures"
    timings: dict[str, float] = {}
    started = time.perf_counter()

    def step(name: str, fn, *args):
        log(f"[{time.perf_counter() - started:6.0f} s] {name}")
        t0 = time.perf_counter()
        value = fn(*args)
        timings[name] = round(time.perf_counter() - t0, 1)
        return value

    drive_map, drive_loc = out / "drive_map", out / "drive_localize"
    sim_map = step(
        "simulate the mapping drive (images)",
        simulate,
        drive_map,
        preset,
        seed,
        0,
        True,
        config,
        show_progress,
    )
    sim_loc = step(
        "simulate a second drive (images)",
        simulate,
        drive_loc,
        preset,
        seed,
        1,
        True,
        config,
        show_progress,
    )
    map_path = out / "map.json"
    map_summary = step(
        "perception + mapping", build_map, drive_map, map_path, "images", config, show_progress
    )
    traj = out / "trajectory.tum"
    loc_summary = step(
        "perception + localization (no initial pose)",
        localize_drive,
        drive_loc,
        map_path,
        traj,
        "images",
        "auto",
        config,
        show_progress,
    )
    map_metrics = evaluate_map_files(map_path, drive_map / "world.json")
    traj_metrics = evaluate_trajectory_files(traj, drive_loc / "groundtruth.tum", map_path)

    log(f"[{time.perf_counter() - started:6.0f} s] pictures and report")
    semantic_map, truth_map = load_map(map_path), load_map(drive_map / "world.json")
    t, est = read_tum(traj)
    true_at, _ = interpolate_poses(*read_tum(drive_loc / "groundtruth.tum"), t)
    err = np.hypot(*(est[:, :2] - true_at[:, :2]).T)
    track = read_track_csv(traj.with_suffix(".csv"))
    sigma = np.sqrt(np.maximum(np.linalg.eigvalsh(track.covariances[:, :2, :2])[:, 1], 0.0))
    audit_rows = [
        json.loads(line)
        for line in map_path.with_name("map.audit.jsonl").read_text().splitlines()
        if line
    ]
    per_slot = json.loads(map_path.with_name("map.audit.json").read_text())["slots"]
    figures = {
        "map.png": map_figure(semantic_map, truth_map, "map from images (drive 0)"),
        "trajectory.png": trajectory_figure(
            est, true_at, err, semantic_map, "drive 1 localized against the map"
        ),
        "error.png": error_figure(track.t, np.interp(track.t, t, err), sigma, track.status),
        "audit.png": audit_figure(audit_rows, per_slot),
    }
    perception, drive = TopviewPerception(), Drive.open(drive_loc)
    for k, i in enumerate(np.linspace(sim_loc.frames * 0.1, sim_loc.frames * 0.9, 3).astype(int)):
        image = read_image(drive.image_path("topview", int(i)))
        overlay = draw_overlay(image, perception, perception.detect(image))
        figures[f"detections_{k + 1}.png"] = cv2.imencode(".png", overlay)[1].tobytes()
    for name, data in figures.items():
        atomic_write_bytes(pictures / name, data)
    timings["total"] = round(time.perf_counter() - started, 1)
    results = {
        "preset": preset,
        "seed": seed,
        "map": {
            k: map_metrics.get(k)
            for k in (
                "slots_matched",
                "corner_rmse_m",
                "corner_p95_m",
                "duplicate_slots",
                "false_slots",
                "wrong_merges",
                "id_accuracy",
                "id_labelled",
                "id_accuracy_labelled",
                "id_confident",
                "id_confident_accuracy",
                "tags_rmse_m",
            )
        },
        "localization": {
            k: traj_metrics.get(k)
            for k in (
                "ate_rmse_m",
                "ate_p95_m",
                "yaw_rmse_deg",
                "parallel_mean_m",
                "orthogonal_mean_m",
                "nees_mean",
                "frames",
                "frames_lost",
            )
        },
        "first_pose_after_s": loc_summary.first_pose_after_s,
        "mapping_s": map_summary.mapping_s,
        "driving_s": map_summary.driving_s,
        "map_slots": map_summary.slots,
        "map_tags": map_summary.tags,
        "drives": [
            asdict(sim_map) | {"folder": os.fspath(sim_map.folder)},
            asdict(sim_loc) | {"folder": os.fspath(sim_loc.folder)},
        ],
        "timings_s": timings,
    }
    atomic_write_text(out / "results.json", json.dumps(results, indent=2, default=str) + "\n")
    atomic_write_text(out / "report.md", _report(results, list(figures)))
    return results


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _report(results: dict[str, Any], pictures: list[str]) -> str:
    lines = [
        f"# semslam demo: `{results['preset']}` world, seed {results['seed']}",
        "",
        "Drive 0 was mapped from its images (slots and IDs by the CNNs, lines by Houben's "
        "detector, tags by AprilTag + PnP); drive 1, another route through the same garage, "
        "was localized against that map with no initial pose. Truth is the simulator's.",
        "",
        "| map | value |",
        "| --- | --- |",
        *[f"| {k} | {_fmt(v)} |" for k, v in results["map"].items()],
        f"| mapping time / driving time | {_fmt(results['mapping_s'])} s / "
        f"{_fmt(results['driving_s'])} s |",
        "",
        "`id_accuracy` counts every matched slot, and a slot without a label as wrong: an ID "
        "under a parked car, or only ever seen from across the aisle (outside the 10 m top "
        "view), is never read. `id_accuracy_labelled` is over the `id_labelled` slots that "
        "got a label, `id_confident_accuracy` over the `id_confident` ones whose label "
        "confidence is 0.9 or more.",
        "",
        "| localization | value |",
        "| --- | --- |",
        *[f"| {k} | {_fmt(v)} |" for k, v in results["localization"].items()],
        f"| first pose after | {_fmt(results['first_pose_after_s'])} s |",
        "",
        "| step | seconds |",
        "| --- | --- |",
        *[f"| {k} | {v} |" for k, v in results["timings_s"].items()],
        "",
    ]
    lines += [f"![{p}](pictures/{p})" for p in pictures]
    return "\n".join(lines) + "\n"


__all__ = ["run_demo"]
