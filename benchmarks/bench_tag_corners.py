"""Tag corner errors against the true corners: AprilTag's own against the ring refinement.

Renders the random views of ``bench_tags.py``'s sweep (the bench garage, one 0.5 m
tag36h11), detects the tag with and without ``DetectorSettings.ring_refinement`` and
prints, per distance band and exposure, the median over views of the RMS distance (px)
between detected and projected true corners.

    PYTHONPATH=. python benchmarks/bench_tag_corners.py [--views 3000] [--seed 11]
"""

from __future__ import annotations

import argparse
import math

import cv2
import numpy as np
from bench_tags import CAM, HEIGHTS, TAG_ID, bench_world, pose_seeing, true_camera_pose

from semslam.perception.tag_covariance import TagNoiseModel
from semslam.perception.tag_detection import DetectorSettings, detect_tags
from semslam.perception.tag_pose import square_object_points
from semslam.simulation.render_front import FrontRenderer

BANDS = ((1.5, 3.0), (3.0, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, 20.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=11)
    args = parser.parse_args()
    worlds = [bench_world(h) for h in HEIGHTS]
    renderers = [FrontRenderer(w, CAM) for w in worlds]
    rng = np.random.default_rng(args.seed)  # the same draws as bench_tags.sweep
    half_fov = math.atan((CAM.size[0] / 2 - 20) / CAM.K[0, 0])
    w_img, h_img = CAM.size
    plain = DetectorSettings(ring_refinement=False)
    rows = []
    for k in range(args.views):
        d, view = rng.uniform(1.5, 25.0), math.radians(rng.uniform(-70, 70))
        bearing, fseed = rng.uniform(-half_fov, half_fov), int(rng.integers(1 << 30))
        if d >= BANDS[-1][1]:
            continue
        tag = worlds[k % 4].tags[0]
        mTv = pose_seeing(tag, d, view, bearing)
        p, R = true_camera_pose(tag, mTv)
        uv, _ = cv2.projectPoints(square_object_points(0.5), cv2.Rodrigues(R)[0], p, CAM.K, None)
        truth = uv.reshape(4, 2)
        if not (p[2] > 0.3 and (truth > 1).all() and (truth[:, 0] < w_img - 2).all()
                and (truth[:, 1] < h_img - 2).all()):
            continue
        img = renderers[k % 4].render(mTv, fseed)
        april = [t for t in detect_tags(img, settings=plain) if t.tag_id == TAG_ID]
        ring = [t for t in detect_tags(img) if t.tag_id == TAG_ID]
        if not april or not ring:
            continue
        order = np.linalg.norm(april[0].corners[:, None] - truth[None], axis=2).argmin(axis=1)
        t = truth[order]
        rms = [float(np.sqrt(((det.corners - t) ** 2).sum(axis=1).mean()))
               for det in (april[0], ring[0])]
        rows.append((d, april[0].clipped > TagNoiseModel().clipped_share, *rms))
    a = np.array(rows, dtype=float)
    print("| distance m | exposure | views | AprilTag corners, RMS px (median) | "
          "ring refinement, RMS px (median) |")
    print("| --- | --- | --- | --- | --- |")
    for lo, hi in BANDS:
        for clipped, name in ((0.0, "well exposed"), (1.0, "overexposed")):
            m = (a[:, 0] >= lo) & (a[:, 0] < hi) & (a[:, 1] == clipped)
            if m.any():
                print(f"| {lo:g}-{hi:g} | {name} | {int(m.sum())} | {np.median(a[m, 2]):.3f} | "
                      f"{np.median(a[m, 3]):.3f} |")


if __name__ == "__main__":
    main()
