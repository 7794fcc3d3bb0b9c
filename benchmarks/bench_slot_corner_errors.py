"""How far the image pipeline's slot corners are from the truth, against the sigma it declares.

Runs the top-view perception (marking-point CNN + slot inference + IDs) on every frame of a
simulated drive with images and matches each detected slot to the exact observation of the
same slot in that frame (mean corner distance < 1 m). Prints, for entrance and rear corners
apart, the RMS error per axis (vehicle frame), the median distance, and the mean NEES of the
corners with the declared isotropic sigma (2 = honest for a 2-D point), and the mean error
(x forward, y left: a bias shared by every detection moves the whole map).

    PYTHONPATH=. python benchmarks/bench_slot_corner_errors.py DRIVE_WITH_IMAGES
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from _common import true_slot

from semslam.config import load_config
from semslam.io import Drive
from semslam.pipeline.perceive import perceive_drive


def corner_errors(detected, exact) -> tuple[list[np.ndarray], list[float]]:
    """Per matched slot: (4, 2) corner errors and the declared sigma."""
    errors, sigmas = [], []
    for frame_found, frame_true in zip(detected, exact, strict=True):
        for slot in frame_found.slots:
            truth = true_slot(slot, frame_true.slots)
            if truth is not None:
                errors.append(np.asarray(slot.vCorners) - np.asarray(truth.vCorners))
                sigmas.append(float(slot.corner_sigma))
    return errors, sigmas


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive")
    parser.add_argument("--json", help="write the figures here too")
    args = parser.parse_args()
    drive = Drive.open(args.drive)
    config = load_config(None)
    detected = perceive_drive(drive, config, show_progress=False)
    exact = drive.observations("exact")
    errors, sigmas = corner_errors(detected, exact)
    e = np.array(errors)  # (n, 4, 2)
    s = np.array(sigmas)[:, None]
    out = {"drive": args.drive, "slots_matched": len(e), "declared_sigma_m": float(np.median(s))}
    for name, idx in (("entrance", [0, 1]), ("rear", [2, 3])):
        part = e[:, idx, :]
        out[f"{name}_rms_per_axis_m"] = float(np.sqrt(np.mean(part**2)))
        out[f"{name}_median_m"] = float(np.median(np.linalg.norm(part, axis=2)))
        out[f"{name}_nees"] = float(np.mean(np.sum(part**2, axis=2) / s**2))
        out[f"{name}_mean_m"] = [round(float(v), 4) for v in part.reshape(-1, 2).mean(axis=0)]
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
