"""The marking-point grid pair in float and in 8 bits, timed in one run, view by view.

    PYTHONPATH=. python benchmarks/compare_grid_precision.py [--frames 40] [--rounds 5]

The top views of ``semslam bench`` (the route of a simulated ``garage`` drive, world seed
1) go through two :class:`TopviewPerception` (lines off) that differ only in the grid pair,
``FLOAT_MODELS`` and ``INT8_MODELS``, one after the other for each view, so that the
machine's changes of speed fall on both alike. Per round and over all rounds: the median ms
of marking points + slots + IDs per view, and how many points and slots each found.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import cv2
import numpy as np
from _common import report

from semslam.config import SemslamConfig
from semslam.perception.marking_points import FLOAT_MODELS, INT8_MODELS
from semslam.perception.onnx_model import model_path
from semslam.perception.slots import SlotDetector
from semslam.perception.topview_perception import TopviewPerception
from semslam.pipeline.bench import route_poses
from semslam.rig import surround_rig
from semslam.simulation.render_topview import TopviewRenderer
from semslam.simulation.world import make_world


def route_views(frames: int, seed: int = 1) -> list[np.ndarray]:
    """The top views ``semslam bench`` times: ``frames`` poses along drive 0's route."""
    world = make_world("garage", seed)
    renderer = TopviewRenderer(world, surround_rig().topview)
    poses = route_poses(SemslamConfig(), world, frames)
    return [renderer.render(pose, n)[0] for n, pose in enumerate(poses)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    views = route_views(args.frames)
    pairs = {"float": FLOAT_MODELS, "int8": INT8_MODELS}
    detectors = {
        name: TopviewPerception(
            lines=False, slot_detector=SlotDetector([model_path(n) for n in models])
        )
        for name, models in pairs.items()
    }
    times: dict[str, list[list[float]]] = {name: [] for name in pairs}
    found = {name: [0, 0] for name in pairs}
    for r in range(args.rounds):
        for name in pairs:
            times[name].append([])
        for view in views:
            for name, perception in detectors.items():
                det = perception.detect(view)
                times[name][-1].append(det.timings_ms["slots"] + det.timings_ms["ids"])
                if r == 0:
                    found[name][0] += len(det.points)
                    found[name][1] += len(det.slots)
    rows = ["| round | float ms | int8 ms |", "| --- | --- | --- |"]
    for r in range(args.rounds):
        rows.append(f"| {r + 1} | {statistics.median(times['float'][r]):.1f} | "
                    f"{statistics.median(times['int8'][r]):.1f} |")
    medians = {name: round(statistics.median(sum(t, [])), 2) for name, t in times.items()}
    rows.append(f"| all | **{medians['float']:.1f}** | **{medians['int8']:.1f}** |")
    rows.append("")
    rows.append(f"Points / slots found in the {len(views)} views: float {found['float'][0]} / "
                f"{found['float'][1]}, int8 {found['int8'][0]} / {found['int8'][1]}.")
    report("\n".join(rows), {"median_ms": medians, "found": found,
                             "rounds_ms": {k: [round(statistics.median(x), 2) for x in v]
                                           for k, v in times.items()}},
           None if args.json is None else Path(args.json))


if __name__ == "__main__":
    main()
