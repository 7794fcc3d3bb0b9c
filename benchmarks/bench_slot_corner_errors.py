"""How far the image pipeline's slot corners are from the truth, against the sigma it declares.

Runs the top-view perception (marking-point CNN + slot inference + IDs) on every frame of a
simulated drive with images and matches each detected slot to the exact observation of the
same slot in that frame (mean corner distance < 1 m). Prints, for entrance and rear corners
apart, the RMS error per axis (vehicle frame), the median distance, and the mean NEES of the
corners with the declared isotropic sigma (2 = honest for a 2-D point), and the mean error
(x forward, y left: a bias shared by every detection moves the whole map).

It also splits each corner's error, turned into the map frame with the true pose, into the
part every detection of that slot shares (the mean over its detections: a bias the CNN has
for that slot's paint, or the depth prior's error at its rear, which more frames do not
average away) and the part of each frame's own (the rest): the two sigmas a map needs to
know how well it knows a corner (``SlotObservation.corner_sigma_own`` / ``_shared``).

    PYTHONPATH=. python benchmarks/bench_slot_corner_errors.py DRIVE [--save-observations]

(``DRIVE``: a simulated drive with images.)

``--save-observations`` also stores the perceived frames as the drive's ``cached``
observations, so ``semslam map DRIVE --observations cached`` maps them without perceiving
again.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from _common import true_slot

from semslam.config import load_config
from semslam.evaluation.trajectory_metrics import interpolate_poses
from semslam.io import Drive
from semslam.io.observations import write_observations
from semslam.pipeline.perceive import perceive_drive


def corner_errors(detected, exact, true_poses=None):
    """Per matched slot: (4, 2) corner errors (vehicle frame), the declared sigma, and, with
    the true poses (F, 3) of the frames, the errors turned into the map frame and the true
    slot's key (its map-frame centre to the centimetre)."""
    errors, sigmas, world, keys = [], [], [], []
    for f, (frame_found, frame_true) in enumerate(zip(detected, exact, strict=True)):
        for slot in frame_found.slots:
            truth = true_slot(slot, frame_true.slots)
            if truth is None:
                continue
            error = np.asarray(slot.vCorners) - np.asarray(truth.vCorners)
            errors.append(error)
            sigmas.append(float(slot.corner_sigma))
            if true_poses is not None:
                x, y, yaw = true_poses[f]
                c, s = np.cos(yaw), np.sin(yaw)
                R = np.array([[c, -s], [s, c]])
                world.append(error @ R.T)
                centre = R @ np.asarray(truth.vCorners).mean(axis=0) + (x, y)
                keys.append((round(float(centre[0]), 2), round(float(centre[1]), 2)))
    return errors, sigmas, world, keys


def shared_and_own(world: np.ndarray, keys: list) -> tuple[float, float, int]:
    """RMS per axis of the part of (n, 2) map-frame corner errors that every detection of a
    slot shares, and of each detection's own part; slots seen at least 5 times. The shared
    variance is the variance of the per-slot means less what each detection's own noise
    leaves in a mean of n_slot detections."""
    groups: dict = {}
    for e, key in zip(world, keys, strict=True):
        groups.setdefault(key, []).append(e)
    means, own, counts = [], [], []
    for errs in groups.values():
        if len(errs) < 5:
            continue
        errs = np.array(errs)
        means.append(errs.mean(axis=0))
        own.append(errs - errs.mean(axis=0))
        counts.append(len(errs))
    own_all = np.concatenate(own)
    n = np.array(counts, float)
    own_var = float(np.sum(own_all**2) / (2 * (len(own_all) - len(n))))  # per axis
    shared_var = float(np.mean(np.sum(np.array(means) ** 2, axis=1) / 2 - own_var / n))
    return float(np.sqrt(max(shared_var, 0.0))), float(np.sqrt(own_var)), len(n)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive")
    parser.add_argument("--json", help="write the figures here too")
    parser.add_argument("--save-observations", action="store_true",
                        help="store the perceived frames as the drive's cached observations")
    args = parser.parse_args()
    drive = Drive.open(args.drive)
    config = load_config(None)
    detected = perceive_drive(drive, config, show_progress=False)
    if args.save_observations:
        write_observations(drive.folder / "observations" / "cached.jsonl", detected)
    exact = drive.observations("exact")
    truth_t, truth_poses = drive.groundtruth()
    poses, _ = interpolate_poses(truth_t, truth_poses, [f.t for f in detected])
    errors, sigmas, world, keys = corner_errors(detected, exact, poses)
    e = np.array(errors)  # (n, 4, 2)
    s = np.array(sigmas)[:, None]
    out = {"drive": args.drive, "slots_matched": len(e), "declared_sigma_m": float(np.median(s))}
    for name, idx in (("entrance", [0, 1]), ("rear", [2, 3])):
        part = e[:, idx, :]
        out[f"{name}_rms_per_axis_m"] = float(np.sqrt(np.mean(part**2)))
        out[f"{name}_median_m"] = float(np.median(np.linalg.norm(part, axis=2)))
        out[f"{name}_nees"] = float(np.mean(np.sum(part**2, axis=2) / s**2))
        out[f"{name}_mean_m"] = [round(float(v), 4) for v in part.reshape(-1, 2).mean(axis=0)]
        w = np.array(world)[:, idx, :]
        shared, own, slots = shared_and_own(
            w.reshape(-1, 2), [(key, i) for key in keys for i in idx]
        )
        out[f"{name}_shared_rms_per_axis_m"] = round(shared, 4)
        out[f"{name}_own_rms_per_axis_m"] = round(own, 4)
    w = np.array(world).reshape(-1, 2)
    shared, own, corners = shared_and_own(w, [(key, i) for key in keys for i in range(4)])
    out["shared_rms_per_axis_m"] = round(shared, 4)
    out["own_rms_per_axis_m"] = round(own, 4)
    out["corners_seen_5_times"] = corners
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
