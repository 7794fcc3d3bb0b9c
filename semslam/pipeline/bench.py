"""`semslam bench`: every speed target re-measured by one command, medians in ms.

Per stage, on frames of a simulated ``garage`` drive rendered in memory:
``topview_ms`` (four fisheye images -> top view, one remap), ``slots_ms`` (marking-point
CNN + slot inference), ``ids_ms`` (ID CNN on the slots found), ``markings_ms`` (Houben's
line detector), ``tags_ms`` (AprilTag + PnP on the 1280 x 800 front image),
``perception_ms`` (slots + IDs + lines of one top view); then ``filter_update_ms`` (the
localizer's association + update per frame, from ``semslam localize`` on a second drive)
and, per preset, mapping time against driving time from noisy observations
(``mapping_speedup`` is the garage drive's driving time / mapping time).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from semslam.config import SemslamConfig


def _median_ms(samples: list[float]) -> float:
    return round(statistics.median(samples) * 1e3, 3)


def route_poses(config: SemslamConfig, world, frames: int) -> list[np.ndarray]:
    """``frames`` poses (x, y, yaw; world frame, m and rad) evenly along drive 0's route
    through ``world`` (lane offset and turn radius from ``config.simulation.drive``)."""
    from semslam.simulation.route import make_path

    drive = config.simulation.drive
    path = make_path(world, 0, drive.lane_offset, drive.turn_radius)
    poses = []
    for k in np.linspace(0, len(path.points) - 2, frames).astype(int):
        d = path.points[k + 1] - path.points[k]
        poses.append(np.array([*path.points[k], np.arctan2(d[1], d[0])]))
    return poses


def perception_timings(config: SemslamConfig, frames: int = 40, seed: int = 1) -> dict[str, Any]:
    """Median per-stage times (ms) over ``frames`` frames along the route of a simulated
    garage drive (lane offset and turn radius from ``config.simulation.drive``)."""
    import cv2

    from semslam.perception.tags import TagSettings, observe_tags
    from semslam.perception.topview import TopviewBuilder
    from semslam.perception.topview_perception import TopviewPerception
    from semslam.rig import surround_rig
    from semslam.simulation.render_fisheye import render_fisheye_rig
    from semslam.simulation.render_front import FrontRenderer
    from semslam.simulation.render_topview import TopviewRenderer
    from semslam.simulation.world import make_world

    cv2.setNumThreads(1)
    world = make_world("garage", seed)
    rig = surround_rig()
    poses = route_poses(config, world, frames)
    fisheyes = [c for name, c in rig.cameras.items() if name.startswith("fisheye_")]
    builder = TopviewBuilder(rig)
    topview_renderer = TopviewRenderer(world, rig.topview)
    front = FrontRenderer(world, rig.cameras["front"])
    perception = TopviewPerception(spec=rig.topview)
    settings = TagSettings()
    t_top, t_slots, t_ids, t_lines, t_perc, t_tags = ([] for _ in range(6))
    for n, pose in enumerate(poses):
        images = render_fisheye_rig(world, pose, n, fisheyes)
        t0 = time.perf_counter()
        builder.build(images)
        t_top.append(time.perf_counter() - t0)
        top, _ = topview_renderer.render(pose, n)
        t0 = time.perf_counter()
        det = perception.detect(top)
        t_perc.append(time.perf_counter() - t0)
        t_slots.append(det.timings_ms["slots"] / 1e3)
        t_ids.append(det.timings_ms["ids"] / 1e3)
        t_lines.append(det.timings_ms["markings"] / 1e3)
        image = front.render(pose, n)
        t0 = time.perf_counter()
        observe_tags(image, rig.cameras["front"], settings)
        t_tags.append(time.perf_counter() - t0)
    return {
        "frames": len(poses),
        "topview_ms": _median_ms(t_top),
        "slots_ms": _median_ms(t_slots),
        "ids_ms": _median_ms(t_ids),
        "slots_and_ids_ms": round(statistics.median(np.add(t_slots, t_ids).tolist()) * 1e3, 3),
        "markings_ms": _median_ms(t_lines),
        "perception_ms": _median_ms(t_perc),
        "tags_ms": _median_ms(t_tags),
    }


def mapping_timings(
    config: SemslamConfig, presets: tuple[str, ...] = ("small", "garage"), seed: int = 1
) -> dict[str, Any]:
    """Per preset: driving and mapping time (s) of drive 0 from noisy observations; for
    the garage also the filter's median update time on drive 1 against that map."""
    from semslam.pipeline.localize import localize_drive
    from semslam.pipeline.mapping import build_map
    from semslam.pipeline.simulate import simulate

    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="semslam-bench-") as tmp:
        root = Path(tmp)
        for preset in presets:
            simulate(root / preset, preset, seed, 0, False, config, False)
            summary = build_map(root / preset, root / f"{preset}.json", "noisy", config, False)
            out[f"{preset}_driving_s"] = round(summary.driving_s, 1)
            out[f"{preset}_mapping_s"] = round(summary.mapping_s, 2)
            out[f"{preset}_speedup"] = round(summary.driving_s / summary.mapping_s, 1)
            if preset == "garage":
                simulate(root / "loc", preset, seed, 1, False, config, False)
                loc = localize_drive(
                    root / "loc",
                    root / f"{preset}.json",
                    root / "loc.tum",
                    "noisy",
                    None,
                    config,
                    False,
                )
                out["filter_update_ms"] = round(loc.update_ms_median, 3)
    if "garage_speedup" in out:
        out["mapping_speedup"] = out["garage_speedup"]
    return out


def run_bench(
    config: SemslamConfig, frames: int = 40, large: bool = False, log=print
) -> dict[str, Any]:
    """Every stage's median time; ``large`` adds the 25-minute ``large`` drive's mapping."""
    import os
    import platform

    from semslam.perception.marking_points import DEFAULT_MODELS

    log("perception stages ...")
    result: dict[str, Any] = {
        "machine": (
            f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
        ),
        # the grid pair this CPU runs (8-bit with VNNI, 7-bit weights with AVX2 alone, else
        # float): the marking points' time depends on it
        "grid_models": " + ".join(DEFAULT_MODELS),
        **perception_timings(config, frames),
    }
    log("mapping and localization ...")
    presets = ("small", "garage", "large") if large else ("small", "garage")
    result.update(mapping_timings(config, presets))
    return result


__all__ = ["mapping_timings", "perception_timings", "route_poses", "run_bench"]
