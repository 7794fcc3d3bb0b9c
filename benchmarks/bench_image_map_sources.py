"""Where the error of a map from images comes from: swap one kind of observation at a time.

On a simulated drive with images (the demo's mapping drive, for instance), perceives every
frame once, then maps it with each observation kind taken from the images or from the
simulator's noisy sensor (which has independent errors), and with the sigmas the image
slot corners and painted lines declare changed. Prints the corner RMSE of each map against
the drive's world.json.

    PYTHONPATH=. python benchmarks/bench_image_map_sources.py DEMO_OUT/drive_map [--grid]
"""

from __future__ import annotations

import argparse
import dataclasses

from _common import true_slot

from semslam.config import load_config
from semslam.evaluation.map_metrics import evaluate_map
from semslam.io import Drive
from semslam.mapping.mapper import Mapper
from semslam.perception.topview_perception import DEFAULT_CORNER_SIGMA
from semslam.pipeline.perceive import perceive_drive
from semslam.types import FrameObservations


def _true_labels(found: FrameObservations, exact: FrameObservations) -> tuple:
    """The detected slots with the label of the true slot they match (confidence 0.99)."""
    out = []
    for slot in found.slots:
        truth = true_slot(slot, exact.slots)
        if truth is not None and truth.label:
            slot = dataclasses.replace(slot, label=truth.label, label_confidence=0.99)
        out.append(slot)
    return tuple(out)


def _corners_at(frames: list[FrameObservations], sigma: float) -> list[FrameObservations]:
    return [
        dataclasses.replace(f, slots=tuple(
            dataclasses.replace(s, corner_sigma=sigma) for s in f.slots))
        for f in frames
    ]


def _lines_at(frames: list[FrameObservations], sigma: float) -> list[FrameObservations]:
    return [
        dataclasses.replace(f, markings=tuple(
            dataclasses.replace(m, sigma=sigma) for m in f.markings))
        for f in frames
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive")
    parser.add_argument(
        "--grid", action="store_true",
        help="only the corner RMSE over declared corner sigma x line sigma",
    )
    args = parser.parse_args()
    drive = Drive.open(args.drive)
    config = load_config(None)
    images = perceive_drive(drive, config, show_progress=False)
    noisy, exact = drive.observations("noisy"), drive.observations("exact")
    pairs = list(zip(images, noisy, strict=True))
    variants = {
        "all from images": images,
        "images, tags from the noisy sensor": [
            dataclasses.replace(f, tags=n.tags) for f, n in pairs
        ],
        "images, true slot labels": [
            dataclasses.replace(f, slots=_true_labels(f, e))
            for f, e in zip(images, exact, strict=True)
        ],
        "images, lines from the noisy sensor": [
            dataclasses.replace(f, markings=n.markings) for f, n in pairs
        ],
        "images, no lines": [dataclasses.replace(f, markings=()) for f in images],
        "noisy sensor, lines from images": [
            dataclasses.replace(n, markings=f.markings) for f, n in pairs
        ],
        "all from the noisy sensor": noisy,
        "images, slot corner sigma x0.5": _corners_at(images, 0.5 * DEFAULT_CORNER_SIGMA),
        "images, slot corner sigma x2": _corners_at(images, 2.0 * DEFAULT_CORNER_SIGMA),
        "images, slot corner sigma x3": _corners_at(images, 3.0 * DEFAULT_CORNER_SIGMA),
    }
    for sigma in (0.05, 0.10, 0.20):
        variants[f"images, lines declared at {sigma:.2f} m"] = _lines_at(images, sigma)
    odometry = drive.odometry()

    def corner_rmse(frames: list[FrameObservations]) -> tuple[float, int]:
        mapper = Mapper(config.mapping, drive.start_pose, odometry.t, odometry.speed,
                        odometry.yaw_rate)
        for frame in frames:
            mapper.add_frame(frame)
        metrics = evaluate_map(mapper.finish().map, drive.world())
        return metrics.corner_rmse_m, metrics.slots_matched

    if args.grid:
        corners, lines = (0.10, 0.15, 0.20, 0.30, 0.45), (0.05, 0.10, 0.15, 0.20)
        print("| corner sigma \\ line sigma | " + " | ".join(f"{s:.2f} m" for s in lines) + " |")
        print("|---" * (len(lines) + 1) + "|")
        for c in corners:
            row = [corner_rmse(_lines_at(_corners_at(images, c), s))[0] for s in lines]
            print(f"| {c:.2f} m | " + " | ".join(f"{r:.3f}" for r in row) + " |", flush=True)
        return
    print("| observations | corner RMSE m | slots matched |")
    print("|---|---|---|")
    for name, frames in variants.items():
        rmse, matched = corner_rmse(frames)
        print(f"| {name} | {rmse:.3f} | {matched} |", flush=True)

if __name__ == "__main__":
    main()
