"""Fisheye top view (issue 5): speed of ``TopviewBuilder.build`` and a picture to look at.

    PYTHONPATH=. python benchmarks/bench_topview.py OUT_DIR [--calls 100] [--seed 5]
        [--json out.json]

- one-time table build of :class:`TopviewBuilder` for the surround rig (four 960 x 640
  fisheyes -> 600 x 600), median of 3 builds;
- ``build()``: median and 90th percentile over ``--calls`` calls on four rendered fisheye
  images of a `small` world (one copy into the atlas + one ``cv2.remap``);
- the simulator's side: first ``render_fisheye_rig`` (per-camera ray tables) and the
  median per frame of four cameras after that;
- pictures in ``OUT_DIR`` (never into the repository): ``fisheye_cameras.jpg`` (the four
  rendered images), ``topview_built.png`` (the built top view), ``topview_overlay.png``
  (the true painted lines in magenta and marking points as green circles over the built
  top view, the camera seams in thin colours) and ``topview_rendered.png`` (the
  top-view renderer's own imitation at the same pose, for comparison).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from _common import report

from semslam.perception.topview import TopviewBuilder
from semslam.rig import surround_rig
from semslam.simulation.render_fisheye import FisheyeRenderer
from semslam.simulation.render_topview import TopviewRenderer
from semslam.simulation.topview_samples import random_aisle_pose
from semslam.simulation.world import make_world


def _to_vehicle(mTv: np.ndarray, mP: np.ndarray) -> np.ndarray:
    c, s = math.cos(mTv[2]), math.sin(mTv[2])
    d = np.asarray(mP, float) - mTv[:2]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def _overlay(top: np.ndarray, world, mTv: np.ndarray, builder: TopviewBuilder) -> np.ndarray:
    spec = builder.spec
    out = top.copy()
    idx = builder.camera_index
    seam = np.zeros(idx.shape, bool)
    seam[:, 1:] |= idx[:, 1:] != idx[:, :-1]
    seam[1:] |= idx[1:] != idx[:-1]
    out[seam] = (255, 255, 0)
    for m in world.markings:  # centre lines of the true paint
        ab = spec.vehicle_to_pixel(_to_vehicle(mTv, np.array([m.a, m.b], float)))
        if np.abs(ab - spec.size_px / 2).max() < 5 * spec.size_px:
            p, q = (tuple(int(v) for v in np.round(x * 16)) for x in ab)
            cv2.line(out, p, q, (255, 0, 255), 1, cv2.LINE_AA, 4)
    for mp in world.marking_points:
        ((u, v),) = spec.vehicle_to_pixel(_to_vehicle(mTv, np.asarray(mp.position, float)[None]))
        if 0 <= u < spec.size_px and 0 <= v < spec.size_px:
            cv2.circle(out, (round(u * 16), round(v * 16)), 6 * 16, (0, 255, 0), 1, cv2.LINE_AA, 4)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", type=Path, help="where the pictures go (not the repository)")
    ap.add_argument("--calls", type=int, default=100)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)

    rig = surround_rig()
    table_s = []
    for _ in range(3):
        t0 = time.perf_counter()
        builder = TopviewBuilder(rig)
        table_s.append(time.perf_counter() - t0)

    world = make_world("small", 1)
    mTv = random_aisle_pose(world, np.random.default_rng(args.seed))
    cams = [rig.cameras[n] for n in builder.cameras]
    t0 = time.perf_counter()
    renderer = FisheyeRenderer(world)
    images = renderer.render(mTv, args.seed, cams)
    first_render = time.perf_counter() - t0
    render_ms = []
    for k in range(5):
        t0 = time.perf_counter()
        renderer.render(mTv, args.seed + k, cams)
        render_ms.append((time.perf_counter() - t0) * 1000.0)

    build_ms = []
    for _ in range(max(args.calls, 1)):
        t0 = time.perf_counter()
        top = builder.build(images)
        build_ms.append((time.perf_counter() - t0) * 1000.0)
    build_ms.sort()

    grid = np.vstack(
        [
            np.hstack([images["fisheye_front"], images["fisheye_rear"]]),
            np.hstack([images["fisheye_left"], images["fisheye_right"]]),
        ]
    )
    cv2.imwrite(str(args.out_dir / "fisheye_cameras.jpg"), grid, [cv2.IMWRITE_JPEG_QUALITY, 85])
    cv2.imwrite(str(args.out_dir / "topview_built.png"), top)
    cv2.imwrite(str(args.out_dir / "topview_overlay.png"), _overlay(top, world, mTv, builder))
    rendered, _ = TopviewRenderer(world).render(mTv, args.seed)
    cv2.imwrite(str(args.out_dir / "topview_rendered.png"), rendered)

    result = {
        "table_build_s": round(statistics.median(table_s), 3),
        "build_ms_median": round(statistics.median(build_ms), 2),
        "build_ms_p90": round(build_ms[int(0.9 * (len(build_ms) - 1))], 2),
        "calls": len(build_ms),
        "render_first_s": round(first_render, 2),
        "render_frame_ms_median": round(statistics.median(render_ms), 1),
        "pose": [round(float(v), 3) for v in mTv],
        "out_dir": str(args.out_dir),
    }
    md = "\n".join(
        [
            "| what | value |",
            "| --- | --- |",
            f"| table build (once, 4 x 960x640 -> 600x600) | {result['table_build_s']} s |",
            f"| `build()` median / p90 over {len(build_ms)} calls | "
            f"{result['build_ms_median']} / {result['build_ms_p90']} ms |",
            f"| simulator: first frame (ray tables) | {result['render_first_s']} s |",
            f"| simulator: four fisheye images per frame, median | "
            f"{result['render_frame_ms_median']} ms |",
        ]
    )
    report(md, result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
