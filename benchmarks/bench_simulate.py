"""Simulator speed: per-frame render times (median, single thread) and the whole
`semslam simulate` command for a garage drive with images.

    python benchmarks/bench_simulate.py [--frames 200] [--preset garage] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from semslam.config import SimulationConfig
from semslam.simulation.render_front import FrontRenderer
from semslam.simulation.render_topview import TopviewRenderer
from semslam.simulation.scenario import frame_seed, simulate_drive


def median_ms(fn, items) -> float:
    times = []
    for item in items:
        started = time.perf_counter()
        fn(item)
        times.append((time.perf_counter() - started) * 1e3)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--preset", default="garage")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    sim = simulate_drive(args.preset, args.seed, 0, SimulationConfig())
    step = max(1, len(sim.frame_poses) // args.frames)
    frames = [(i, sim.frame_poses[i]) for i in range(0, len(sim.frame_poses), step)]
    top = TopviewRenderer(sim.world, sim.rig.topview)
    front = FrontRenderer(sim.world, sim.rig.cameras["front"])
    top.render(frames[0][1], 0)  # warm caches
    front.render(frames[0][1], 0)
    result = {
        "frames": len(frames),
        "topview_ms": median_ms(lambda f: top.render(f[1], frame_seed(args.seed, 0, f[0])), frames),
        "front_ms": median_ms(lambda f: front.render(f[1], frame_seed(args.seed, 0, f[0])), frames),
    }
    image = front.render(frames[0][1], 0)
    result["front_jpeg_encode_ms"] = median_ms(
        lambda _: cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 92]), range(50))
    with tempfile.TemporaryDirectory() as tmp:
        for images in (False, True):
            out = Path(tmp) / f"d{int(images)}"
            started = time.perf_counter()
            subprocess.run([sys.executable, "-m", "semslam", "simulate", str(out), "--preset",
                            args.preset, "--seed", str(args.seed), "--no-progress",
                            "--images" if images else "--no-images"], check=True,
                           capture_output=True)
            key = "simulate_with_images_s" if images else "simulate_no_images_s"
            result[key] = round(time.perf_counter() - started, 1)
    result["driving_s"] = round(float(sim.frame_times[-1]), 1)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
