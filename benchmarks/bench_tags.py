"""Fiducial tags (issue 6): speed, real photos, simulated accuracy, detection rate, NEES.

    PYTHONPATH=. python benchmarks/bench_tags.py [--samples 2000] [--frames 600]
        [--calibrate | --calibrate-only] [--speed-only] [--plot docs/tag_detection_rate.png]
        [--json out.json]

- speed: ``estimate_tags`` (detection + undistortion + both IPPE solutions + covariance)
  per 1280 x 800 front frame, median over frames along a simulated `garage` drive;
- duckietown rotation set (real, 15 photos): all found, largest distance of the tag
  position from its mean, largest turn residual after one common offset, against
  pupil-apriltags' own ``estimate_tag_pose``;
- apriltag-regression (real, 3 photos): reference tags found, corner differences;
- simulated sweep: one tag on a pillar seen from random distances (1.5-25 m), viewing
  angles (+-70 deg) and image positions; range / bearing errors by distance for both
  position variants, detection rate by distance (plotted), and the NEES of the vehicle-
  frame observations against chi-square bounds; also the NEES on the tags seen along a
  `garage` drive;
- ``--calibrate`` (``--calibrate-only``: and nothing else): fits the covariance constants
  on a separate sweep (seed 11) and prints them (``model``: copy into ``TagNoiseModel``);
  ``--calibration-codes 16`` fits them on 16 codes instead of tag 77 (codes read on all
  four ring sides, none of the check sweeps' nor of the `garage` worlds 1-7), and with
  ``--calibrate`` the checks then run with the model just fitted instead of the shipped one.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from _common import report
from scipy import stats

from semslam.config import SimulationConfig
from semslam.geometry import inverse_transform_points, wrap_angle
from semslam.perception.tag_covariance import (
    TagNoiseModel,
    camera_covariance,
    min_side_px,
    side_px,
    vehicle_covariance,
    vehicle_pose_2d,
)
from semslam.perception.tag_detection import (
    REFERENCE_SETTINGS,
    DetectorSettings,
    configured_detector,
    detect_tags,
)
from semslam.perception.tag_pose import PositionVariant, estimate_pose
from semslam.perception.tags import (
    TagSettings,
    estimate_tag,
    estimate_tags,
    to_observations,
    usable,
)
from semslam.rig import Camera, CameraModel, default_front_camera
from semslam.simulation.render_front import FrontRenderer
from semslam.simulation.scenario import frame_seed, simulate_drive
from semslam.simulation.world_types import Aisle, Pillar, Wall, World
from semslam.types import Tag, TagFamily

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / "apriltag-photos"
CAM = default_front_camera()
TAG_ID = 77
HEIGHTS = (1.45, 1.6, 1.75, 1.9)
LIGHT_SHIFTS = (0.0, 3.0, 6.0, 9.0)  # m: the tag under a light down to between lights
# pupil-apriltags' own defaults (it truncates decode_sharpening 0.25 to an int)
_APRILTAG3_DEFAULTS = DetectorSettings(decode_sharpening=0.0, min_white_black_diff=5, max_hamming=2)
DIST_BINS = ((1.5, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, 20.0), (20.0, 25.0))


# --------------------------------------------------------------------------- simulated sweep


def bench_world(height: float, light_shift: float = 0.0, tag_id: int = TAG_ID) -> World:
    """An empty garage (floor, walls, ceiling lights along two aisles) with one pillar at
    the origin carrying tag ``tag_id`` (0.5 m) on its +x face, centre ``height`` m up; the
    aisles and their lights moved ``light_shift`` m away, so the tag is lit less (light
    level at the pillar 1.56 / 1.41 / 0.94 / 0.69 for :data:`LIGHT_SHIFTS`)."""
    c = [np.array(p, float) for p in ((-40, -25), (40, -25), (40, 25), (-40, 25))]
    tag = Tag(TagFamily.TAG36H11, tag_id, 0.5, np.array([0.305, 0.0, 0.0]), height,
              np.zeros((3, 3)))
    aisles = (Aisle(np.array([-38.0, 3.5 + light_shift]), np.array([38.0, 3.5 + light_shift]),
                    6.0),
              Aisle(np.array([12.0 + light_shift, -23.0]), np.array([12.0 + light_shift, 23.0]),
                    6.0))  # for the lights
    return World(preset="bench", seed=0, slots=(), tags=(tag,), markings=(),
                 marking_points=(), slot_paint=(), pillars=(Pillar(np.zeros(2), 0.6, 3.0),),
                 walls=tuple(Wall(c[i], c[(i + 1) % 4], 3.0) for i in range(4)),
                 parked_cars=(), aisles=aisles, bounds=(-40.0, -25.0, 40.0, 25.0),
                 line_colour=(235, 235, 235))


def pose_seeing(tag: Tag, d: float, view: float, bearing: float) -> np.ndarray:
    """Vehicle pose whose camera is ``d`` m (horizontally) from the tag centre, ``view``
    rad off its normal, turned so the tag appears ``bearing`` rad off the optical axis."""
    x, y, yaw = (float(v) for v in tag.mTt)
    a = yaw + view
    cam = np.array([x, y]) + d * np.array([math.cos(a), math.sin(a)])
    heading = a + math.pi + bearing
    off = CAM.T_vehicle_camera[:2, 3]
    c, s = math.cos(heading), math.sin(heading)
    centre = cam - np.array([c * off[0] - s * off[1], s * off[0] + c * off[1]])
    return np.array([centre[0], centre[1], wrap_angle(heading)])


def true_camera_pose(tag: Tag, mTv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True tag centre (3,) and rotation camera-from-tag (3, 3) in the camera frame."""
    x, y, yaw = mTv
    T_mv = np.eye(4)
    T_mv[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    T_mv[:2, 3] = x, y
    T_cm = np.linalg.inv(T_mv @ CAM.T_vehicle_camera)
    ty = float(tag.mTt[2])
    R_mt = np.column_stack([[-math.sin(ty), math.cos(ty), 0.0], [0.0, 0.0, -1.0],
                            [-math.cos(ty), -math.sin(ty), 0.0]])
    p_m = np.array([tag.mTt[0], tag.mTt[1], tag.height])
    return T_cm[:3, :3] @ p_m + T_cm[:3, 3], T_cm[:3, :3] @ R_mt


def true_vTt(tag: Tag, mTv: np.ndarray) -> np.ndarray:
    xy = inverse_transform_points(mTv, tag.mTt[:2]).ravel()
    return np.array([xy[0], xy[1], wrap_angle(tag.mTt[2] - mTv[2])])


def sweep(n: int, seed: int, codes: tuple[int, ...] | None = None) -> list[dict]:
    """Render and measure ``n`` random views of the bench tag: 16 worlds (4 light levels x
    4 heights), one drawn per view, each with its code from ``codes`` (default: tag 77,
    whose ring is read at 3 / 4 / 4 / 3 white data cells)."""
    codes = codes or (TAG_ID,)
    worlds = [bench_world(h, shift, codes[k % len(codes)]) for k, (shift, h) in
              enumerate((sh, h) for sh in LIGHT_SHIFTS for h in HEIGHTS)]
    renderers = [FrontRenderer(w, CAM) for w in worlds]
    rng = np.random.default_rng(seed)
    half_fov = math.atan((CAM.size[0] / 2 - 20) / CAM.K[0, 0])
    w_img, h_img = CAM.size
    out = []
    for _ in range(n):
        d, view = rng.uniform(1.5, 25.0), math.radians(rng.uniform(-70, 70))
        bearing, fseed = rng.uniform(-half_fov, half_fov), int(rng.integers(1 << 30))
        world = int(rng.integers(len(worlds)))
        tag = worlds[world].tags[0]
        mTv = pose_seeing(tag, d, view, bearing)
        p_true, R_true = true_camera_pose(tag, mTv)
        uv, _ = cv2.projectPoints(np.array([[-.25, .25, 0], [.25, .25, 0], [.25, -.25, 0],
                                            [-.25, -.25, 0]]), cv2.Rodrigues(R_true)[0],
                                  p_true, CAM.K, None)
        uv = uv.reshape(-1, 2)
        inside = bool(p_true[2] > 0.3 and (uv > 1).all() and (uv[:, 0] < w_img - 2).all()
                      and (uv[:, 1] < h_img - 2).all())
        row = {"d": d, "view": view, "inside": inside, "p_true": p_true, "R_true": R_true,
               "vTt_true": true_vTt(tag, mTv), "height": tag.height, "detection": None}
        if inside:
            found = [t for t in detect_tags(renderers[world].render(mTv, fseed))
                     if t.tag_id == tag.tag_id]
            row["detection"] = found[0] if found else None
        out.append(row)
    return out


def pose_errors(rows: list[dict], variant: PositionVariant) -> dict[str, np.ndarray]:
    """Range (m) and horizontal bearing (deg) errors per detected row, and distances."""
    d, e_range, e_bear, clipped = [], [], [], []
    for r in rows:
        if r["detection"] is None:
            continue
        pose = estimate_pose(r["detection"].corners, 0.5, CAM.K, variant)
        p, pt = pose.position, r["p_true"]
        d.append(r["d"])
        clipped.append(r["detection"].clipped > TagNoiseModel().clipped_share)
        e_range.append(np.linalg.norm(p) - np.linalg.norm(pt))
        e_bear.append(math.degrees(wrap_angle(math.atan2(p[0], p[2]) - math.atan2(pt[0], pt[2]))))
    return {"d": np.array(d), "range": np.array(e_range), "bearing": np.array(e_bear),
            "clipped": np.array(clipped, dtype=bool),
            "true_range": np.array([np.linalg.norm(r["p_true"]) for r in rows
                                    if r["detection"] is not None])}


def accuracy_table(rows: list[dict]) -> list[dict]:
    out = []
    for variant in PositionVariant:
        e = pose_errors(rows, variant)
        for lo, hi in DIST_BINS:
            m = (e["d"] >= lo) & (e["d"] < hi)
            if not m.any():
                continue
            bound = 0.01 * e["true_range"][m] + 0.02
            within = np.abs(e["range"][m]) <= bound
            clip = e["clipped"][m]
            out.append({
                "variant": variant.value, "distance_m": f"{lo:g}-{hi:g}", "n": int(m.sum()),
                "range_rms_cm": round(float(np.sqrt(np.mean(e["range"][m] ** 2))) * 100, 2),
                "range_max_cm": round(float(np.abs(e["range"][m]).max()) * 100, 2),
                "range_within_1pct_2cm": round(float(np.mean(within)), 3),
                "overexposed_views": int(clip.sum()),
                "range_within_1pct_2cm_not_overexposed": round(float(np.mean(within[~clip])), 3),
                "range_within_1pct_2cm_overexposed": (round(float(np.mean(within[clip])), 3)
                                                      if clip.any() else None),
                "bearing_rms_deg": round(float(np.sqrt(np.mean(e["bearing"][m] ** 2))), 4),
                "bearing_max_deg": round(float(np.abs(e["bearing"][m]).max()), 4),
            })
    return out


def detection_rate(rows: list[dict], plot: Path | None) -> list[dict]:
    edges = np.arange(1.5, 25.01, 2.0)
    groups = (("|view| < 30 deg", 0, 30), ("30-50 deg", 30, 50), ("50-70 deg", 50, 70))
    d = np.array([r["d"] for r in rows if r["inside"]])
    view = np.degrees(np.abs([r["view"] for r in rows if r["inside"]]))
    found = np.array([r["detection"] is not None for r in rows if r["inside"]])
    table = []
    for lo, hi in DIST_BINS:
        m = (d >= lo) & (d < hi)
        table.append({"distance_m": f"{lo:g}-{hi:g}", "in_view": int(m.sum()),
                      "detected": round(float(found[m].mean()), 3) if m.any() else None})
    if plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4))
        centres = (edges[:-1] + edges[1:]) / 2
        for label, a, b in groups:
            rate = []
            for lo, hi in zip(edges[:-1], edges[1:], strict=True):
                m = (d >= lo) & (d < hi) & (view >= a) & (view < b)
                rate.append(found[m].mean() if m.sum() >= 3 else np.nan)
            ax.plot(centres, rate, marker="o", label=label)
        ax.axvline(20.0, color="grey", linestyle="--", linewidth=1)
        ax.text(20.2, 0.5, "range limit", color="grey")
        side_limit = CAM.K[0, 0] * 0.5 / TagSettings().min_side_px
        ax.axvline(side_limit, color="grey", linestyle=":", linewidth=1)
        ax.text(side_limit - 0.2, 0.35, f"{TagSettings().min_side_px:g} px (head-on)",
                color="grey", ha="right")
        ax.set_xlabel("distance camera - tag (m, horizontal)")
        ax.set_ylabel("detection rate (tag fully in view)")
        ax.set_title("0.5 m tag36h11, simulated 1280 x 800 front camera (f = 640 px)")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        plot.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(plot, dpi=110)
        plt.close(fig)
    return table


def nees_of(errors: list[np.ndarray], covs: list[np.ndarray]) -> dict:
    """Mean NEES of 3-vectors with the two-sided 95 % chi-square bounds on it."""
    if not errors:
        return {"n": 0}
    nees = np.array([e @ np.linalg.solve(c, e) for e, c in zip(errors, covs, strict=True)])
    pos = np.array([e[:2] @ np.linalg.solve(c[:2, :2], e[:2])
                    for e, c in zip(errors, covs, strict=True)])
    yaw = np.array([e[2] ** 2 / c[2, 2] for e, c in zip(errors, covs, strict=True)])
    n = len(nees)
    return {"n": n, "mean": round(float(nees.mean()), 3),
            "position_mean": round(float(pos.mean()), 3),
            "position_bounds_95": [round(float(stats.chi2.ppf(0.025, 2 * n)) / n, 3),
                                   round(float(stats.chi2.ppf(0.975, 2 * n)) / n, 3)],
            "yaw_mean": round(float(yaw.mean()), 3),
            "bounds_95": [round(float(stats.chi2.ppf(0.025, 3 * n)) / n, 3),
                          round(float(stats.chi2.ppf(0.975, 3 * n)) / n, 3)],
            "share_above_chi2_95": round(float(np.mean(nees > stats.chi2.ppf(0.95, 3))), 3),
            "median": round(float(np.median(nees)), 3),
            "median_expected": round(float(stats.chi2.ppf(0.5, 3)), 3)}


def sweep_nees(rows: list[dict], settings: TagSettings) -> dict:
    """NEES of the kept sweep observations (vehicle frame), overall and per distance."""
    per_bin: dict[str, tuple[list, list]] = {f"{a:g}-{b:g}": ([], []) for a, b in DIST_BINS}
    errors, covs = [], []
    for r in rows:
        if r["detection"] is None:
            continue
        est = estimate_tag(r["detection"], CAM, settings)
        obs = to_observations([est] if est is not None else [], CAM, settings)
        if not obs:
            continue
        e = obs[0].vTt - r["vTt_true"]
        e[2] = wrap_angle(e[2])
        errors.append(e)
        covs.append(obs[0].covariance)
        for a, b in DIST_BINS:
            if a <= r["d"] < b:
                per_bin[f"{a:g}-{b:g}"][0].append(e)
                per_bin[f"{a:g}-{b:g}"][1].append(obs[0].covariance)
    result = nees_of(errors, covs)
    result["by_distance"] = {k: nees_of(*v) for k, v in per_bin.items() if v[0]}
    return result


# --------------------------------------------------------------------------- drive frames


def drive_frames(n_frames: int, seed: int, settings: TagSettings | None = None
                 ) -> tuple[list[float], list[float], list, list]:
    """Wall and CPU time (ms) of ``estimate_tags`` on frames along a garage drive (drive 0
    of world ``seed``), and the errors and covariances of the tags observed there."""
    sim = simulate_drive("garage", seed, 0, SimulationConfig())
    renderer = FrontRenderer(sim.world, CAM)
    step = max(1, len(sim.frame_poses) // n_frames)
    tags = {t.tag_id: t for t in sim.world.tags}
    times, cpu_times, errors, covs = [], [], [], []
    settings = settings or TagSettings()
    for i in range(0, len(sim.frame_poses), step):
        mTv = sim.frame_poses[i]
        gray = cv2.cvtColor(renderer.render(mTv, frame_seed(seed, 0, i)), cv2.COLOR_BGR2GRAY)
        started, cpu = time.perf_counter(), time.thread_time()
        est = estimate_tags(gray, CAM, settings)
        times.append((time.perf_counter() - started) * 1e3)
        cpu_times.append((time.thread_time() - cpu) * 1e3)
        for obs in to_observations(est, CAM, settings):
            if obs.tag_id in tags:
                e = obs.vTt - true_vTt(tags[obs.tag_id], mTv)
                e[2] = wrap_angle(e[2])
                errors.append(e)
                covs.append(obs.covariance)
    return times, cpu_times, errors, covs


def held_out_drives(seeds: list[int], n_frames: int, settings: TagSettings | None = None
                    ) -> dict:
    """NEES of the tag observations along drive 0 of other worlds, per world and pooled."""
    out: dict = {"per_world": {}}
    errors, covs = [], []
    for seed in seeds:
        _, _, e, c = drive_frames(n_frames, seed, settings)
        out["per_world"][seed] = nees_of(e, c)
        errors += e
        covs += c
    out["pooled"] = nees_of(errors, covs)
    return out


# --------------------------------------------------------------------------- real photos


def duckietown() -> dict:
    folder = REAL / "duckietown"
    if not folder.is_dir():
        return {"skipped": f"{folder} not found"}
    K = np.array([[329.8729619143081, 0.0, 528.0], [0.0, 332.94611303946357, 396.0],
                  [0.0, 0.0, 1.0]])
    camera = Camera("duckietown", CameraModel.PINHOLE, K, np.zeros(5), (1056, 792), np.eye(4))
    angles = np.arange(-70, 71, 10)
    grays = [cv2.imread(str(folder / f"test_image_rotation_{a}.png"), cv2.IMREAD_GRAYSCALE)
             for a in angles]

    def score(positions: list, rotations: list) -> dict:
        if len(positions) != len(angles):
            return {"found": len(positions)}
        p = np.array(positions)
        spread = np.linalg.norm(p - p.mean(axis=0), axis=1).max()
        # turn: heading of the tag normal in the camera's x-z plane
        turn = np.degrees([math.atan2(-R[0, 2], R[2, 2]) for R in rotations])
        residual = turn - angles
        residual -= residual.mean()
        return {"found": len(positions), "position_spread_mm": round(float(spread) * 1000, 2),
                "turn_residual_deg": round(float(np.abs(residual).max()), 3)}

    # AprilTag 3's own estimate, with pupil-apriltags' defaults (pixel centres at +0.5)
    ref: tuple[list, list] = ([], [])
    for gray in grays:
        detector = configured_detector("tag36h11", _APRILTAG3_DEFAULTS)
        dets = detector.detect(gray, True, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), 0.065)
        if len(dets) == 1:
            ref[0].append(dets[0].pose_t.ravel())
            ref[1].append(dets[0].pose_R)
    out = {"images": len(angles), "apriltag3_estimate_tag_pose": score(*ref)}
    for decimate in (2.0, 1.0):
        for v in PositionVariant:
            settings = TagSettings(size=0.065, variant=v,
                                   detector=DetectorSettings(quad_decimate=decimate))
            ests = [e for g in grays for e in estimate_tags(g, camera, settings)]
            out[f"semslam_{v.value}_decimate_{decimate:g}"] = score(
                [e.pose.position for e in ests], [e.pose.rotation for e in ests])
    return out


def regression() -> dict:
    folder = REAL / "apriltag-regression"
    if not folder.is_dir():
        return {"skipped": f"{folder} not found"}
    out = {}
    for name, settings in (("library default (decimate 2)", DetectorSettings()),
                           ("`semslam tags` default (decimate 1)",
                            DetectorSettings(quad_decimate=1.0)),
                           ("reference (decimate 1, no edge refinement)", REFERENCE_SETTINGS)):
        total = found = 0
        worst = 0.0
        for txt in sorted(folder.glob("*.txt")):
            gray = cv2.imread(str(txt.with_suffix(".jpg")), cv2.IMREAD_GRAYSCALE)
            refs = []
            for line in txt.read_text().splitlines():
                nums = [float(x) for x in line.replace("(", " ").replace(")", " ")
                        .replace(",", " ").split()]
                refs.append(np.array(nums[1:9]).reshape(4, 2))
            dets = [d.corners + 0.5 for d in detect_tags(gray, "tag36h11", settings)]
            for r in refs:
                total += 1
                dist = [np.abs(d - r).max() for d in dets]
                if dist and min(dist) <= 1.0:
                    found += 1
                    worst = max(worst, min(dist))
        out[name] = {"reference_tags": total, "found_within_1px": found,
                     "largest_corner_difference_px": round(worst, 3)}
    return out


# --------------------------------------------------------------------------- calibration


def calibration_codes(n: int) -> tuple[int, ...]:
    """``n`` tag36h11 codes for a calibration sweep (seed 2026): read on all four sides of
    the border ring, and none of tag 77, the other-code check sweep or the tags of the
    `garage` worlds 1-7 (the drives the checks use)."""
    from semslam.simulation.world import make_world

    taken = {TAG_ID, *other_codes()}
    taken |= {t.tag_id for seed in range(1, 8) for t in make_world("garage", seed).tags}
    codes: list[int] = []
    for code in np.random.default_rng(2026).permutation(587):
        if int(code) in taken:
            continue
        world = bench_world(1.6, 0.0, int(code))
        image = FrontRenderer(world, CAM).render(pose_seeing(world.tags[0], 4.0, 0.2, 0.0), 1)
        found = [t for t in detect_tags(image) if t.tag_id == code]
        if found and found[0].ring_sides == 4:
            codes.append(int(code))
        if len(codes) == n:
            break
    return tuple(codes)


def other_codes() -> tuple[int, ...]:
    """The 16 codes of the other-code check sweep (seed 7)."""
    others = [i for i in range(587) if i != TAG_ID]
    return tuple(int(v) for v in np.random.default_rng(7).choice(others, 16, replace=False))


def _calibration_features(rows: list[dict], variant: PositionVariant) -> dict[str, np.ndarray]:
    """Per detected view: size (px), range, the errors split as the model splits them
    (range, across the line of sight, rotation about the tag's axes), viewing angles about
    the tag's x and y axes, whether the best IPPE solution was the wrong (flipped) one,
    the ambiguity ratio, and whether the view becomes an observation."""
    keys = ("s", "rho", "e_rho", "e_perp", "e_rot", "th", "flip", "ambiguity", "usable",
            "clipped")
    out: dict[str, list] = {k: [] for k in keys}
    for r in rows:
        if r["detection"] is None:
            continue
        pose = estimate_pose(r["detection"].corners, 0.5, CAM.K, variant)
        p, R, pt, Rt = pose.position, pose.rotation, r["p_true"], r["R_true"]
        rho = float(np.linalg.norm(p))
        u = p / rho
        b1 = np.cross(u, [0.0, 1.0, 0.0])
        b1 /= np.linalg.norm(b1)
        b2 = np.cross(u, b1)
        ut = pt / np.linalg.norm(pt)
        rv = cv2.Rodrigues(Rt @ R.T)[0].ravel()
        v = R.T @ -u
        out["s"].append(side_px(r["detection"].corners))
        out["rho"].append(rho)
        out["e_rho"].append(rho - np.linalg.norm(pt))
        out["e_perp"].append((ut @ b1, ut @ b2))
        out["e_rot"].append((rv @ R[:, 0], rv @ R[:, 1], rv @ R[:, 2]))
        out["th"].append((abs(math.atan2(v[1], -v[2])), abs(math.atan2(v[0], -v[2]))))
        out["flip"].append(_flipped(pose, Rt))
        out["ambiguity"].append(pose.ambiguity)
        out["clipped"].append(r["detection"].clipped > TagNoiseModel().clipped_share)
        # usable but for the flip probability, which the calibration fits itself
        settings = TagSettings(variant=variant, max_flip_probability=1.0)
        est = estimate_tag(r["detection"], CAM, settings)
        out["usable"].append(est is not None and usable(est, settings))
    return {k: np.array(v) for k, v in out.items()}


def _flipped(pose, R_true: np.ndarray) -> bool:
    """Is the other IPPE solution the right one: the chosen one's heading more than 5 deg
    off and further off than the other's?"""
    true_heading = math.atan2(-R_true[0, 2], R_true[2, 2])
    R = pose.rotation
    e_best = abs(wrap_angle(math.atan2(-R[0, 2], R[2, 2]) - true_heading))
    if pose.other is None:
        return False
    e_other = abs(wrap_angle(math.atan2(-pose.other.R[0, 2], pose.other.R[2, 2]) - true_heading))
    return e_best > e_other and e_best > math.radians(5)


def _g(q: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.sqrt(q[0] ** 2 + (q[1] / s) ** 2)


def _fit(sigma, err: np.ndarray, x0: list[float]) -> np.ndarray:
    """Maximum-likelihood constants of a zero-mean Gaussian error model ``sigma(q)``."""
    from scipy.optimize import minimize

    def nll(logq: np.ndarray) -> float:
        sg = sigma(np.exp(logq))
        return float(np.sum(err ** 2 / sg ** 2 + 2 * np.log(sg)))

    return np.exp(minimize(nll, np.log(x0), method="Nelder-Mead",
                           options={"maxiter": 6000, "xatol": 1e-7, "fatol": 1e-9}).x)


def _fit_flip(ambiguity: np.ndarray, size: np.ndarray, flip: np.ndarray) -> np.ndarray:
    """(a, b, c) of P(flip) = 1 / (1 + exp(-(a + b ln ambiguity + c ln s))), maximum
    likelihood."""
    from scipy.optimize import minimize

    X = np.column_stack([np.ones(len(flip)), np.log(np.maximum(ambiguity, 1e-6)), np.log(size)])

    def nll(q: np.ndarray) -> float:
        p = 1 / (1 + np.exp(-np.clip(X @ q, -50, 50)))
        return float(-np.sum(np.where(flip, np.log(p + 1e-12), np.log(1 - p + 1e-12))))

    return minimize(nll, [0.0, 1.0, 0.0], method="Nelder-Mead",
                    options={"maxiter": 4000, "xatol": 1e-6, "fatol": 1e-9}).x


def calibrate(rows: list[dict]) -> dict:
    """Fit the constants by maximum likelihood (see tag_covariance.py): the flip model on
    the views usable but for their flip probability, the covariance on those of them that
    the fitted flip model keeps (at most ``max_flip_probability``): the views that become
    observations; each term of the covariance on its own error (on the views not
    overexposed; the bearing on its horizontal part, the one a 2D observation uses), then
    the terms of the 2D observation together on its vehicle-frame errors
    (:func:`_refine_on_vehicle_errors`). ``model`` holds the constants for
    :class:`TagNoiseModel`."""
    f = float(CAM.K[0, 0])
    out: dict = {}
    x = _calibration_features(rows, PositionVariant.TIEV)
    keep = x["usable"] & ~x["clipped"]
    s, perp = x["s"][keep], x["e_perp"][keep]
    q = _fit(lambda q: np.hypot(_g(q, s) / f, q[2]), perp[:, 0], [0.03, 2.0, 1e-5])
    out["tiev_bearing_floor_px, knee_px2, floor_rad"] = [float(f"{v:.4g}") for v in q]
    x = _calibration_features(rows, PositionVariant.PNP)
    x = {k: v[x["usable"]] for k, v in x.items()}
    q_flip = _fit_flip(x["ambiguity"], x["s"], x["flip"])
    flips_all = int(x["flip"].sum())
    z = (q_flip[0] + q_flip[1] * np.log(np.maximum(x["ambiguity"], 1e-6))
         + q_flip[2] * np.log(x["s"]))
    kept = 1 / (1 + np.exp(-np.clip(z, -50, 50))) <= TagSettings().max_flip_probability
    x = {k: v[kept] for k, v in x.items()}
    clip = x["clipped"]
    # the base model on the views that are not overexposed ...
    b = {k: v[~clip] for k, v in x.items()}
    b = {k: v[~b["flip"]] for k, v in b.items()}  # the covariance given the solution is right
    s, rho, rot, th = b["s"], b["rho"], b["e_rot"], b["th"]
    q_perp = _fit(lambda q: np.hypot(_g(q, s) / f, q[2]), b["e_perp"][:, 0],
                  [0.03, 2.0, 1e-5])
    q_rho = _fit(lambda q: rho * np.hypot(_g(q, s) / s, q[2]), b["e_rho"], [0.05, 2.0, 1e-3])
    tho = th[:, 1]
    q_tilt = _fit(lambda q: _g(q, s) / (s * np.sqrt((q[2] * s / f) ** 2 + np.sin(tho) ** 2)),
                  rot[:, 1], [0.1, 2.0, 1.0])
    q_roll = _fit(lambda q: _g(q, s) / s, rot[:, 2], [0.05, 2.0])
    fitted = {
        ("range_floor_px", "range_knee_px2", "range_rel_floor"): q_rho,
        ("bearing_floor_px", "bearing_knee_px2", "bearing_floor_rad"): q_perp,
        ("tiev_bearing_floor_px", "tiev_bearing_knee_px2", "tiev_bearing_floor_rad"): q,
        ("tilt_floor_px", "tilt_knee_px2", "tilt_perspective"): q_tilt,
        ("roll_floor_px", "roll_knee_px2"): q_roll,
        ("flip_logit_offset", "flip_logit_ambiguity", "flip_logit_size"): q_flip}
    first = replace(TagNoiseModel(), **{k: float(v) for names, values in fitted.items()
                                        for k, v in zip(names, values, strict=True)})
    model = _refine_on_vehicle_errors(rows, first)
    out.update({
        "views_usable_but_for_flips": int(len(kept)), "flips_among_them": flips_all,
        "samples": int(kept.sum()), "overexposed": int(clip.sum()),
        "flips": int(x["flip"].sum()),
        "model": {k: float(f"{v:.4g}") for k, v in vars(model).items()}})
    return out


VEHICLE_FIT = ("range_floor_px", "range_knee_px2", "range_rel_floor", "bearing_floor_px",
               "bearing_knee_px2", "bearing_floor_rad", "tilt_floor_px", "tilt_knee_px2",
               "tilt_perspective", "clipped_knee_px", "clipped_floor", "contrast_power")


def _refine_on_vehicle_errors(rows: list[dict], first: TagNoiseModel) -> TagNoiseModel:
    """The constants that shape the 2D observation (:data:`VEHICLE_FIT`), refitted by
    maximum likelihood of the observations' (x, y, yaw) errors in the vehicle frame, the
    quantity the NEES checks (its terms coupled through the pose, overexposed views
    included), from the per-term fits ``first`` (the overexposure factor from 30 px, 0.5)."""
    from scipy.optimize import minimize

    start = replace(first, clipped_knee_px=30.0, clipped_floor=0.5, contrast_power=0.5)
    settings = TagSettings(noise=start)
    views = []
    for r in rows:
        if r["detection"] is None:
            continue
        est = estimate_tag(r["detection"], CAM, settings)
        if est is None or not usable(est, settings):
            continue
        vTt, _ = vehicle_pose_2d(est.pose.position, est.pose.rotation, CAM.T_vehicle_camera)
        e = vTt - r["vTt_true"]
        e[2] = wrap_angle(e[2])
        if _flipped(est.pose, r["R_true"]):
            continue  # the covariance is the chosen solution's given that it is right
        views.append((est, e, min_side_px(est.corners)))
    f = float(CAM.K[0, 0])

    def nll(log_q: np.ndarray) -> float:
        m = replace(start, **dict(zip(VEHICLE_FIT, np.exp(log_q), strict=True)))
        total = 0.0
        for est, e, s_min in views:
            c6 = camera_covariance(est.pose, est.side_px, f, m, est.detection.clipped, s_min,
                                   est.detection.contrast)
            C = vehicle_covariance(est.pose.rotation, c6, CAM.T_vehicle_camera)
            total += float(e @ np.linalg.solve(C, e)) + float(np.linalg.slogdet(C)[1])
        return total

    x0 = np.log([max(getattr(start, k), 1e-6) for k in VEHICLE_FIT])
    simplex = np.vstack([x0, x0 + 0.3 * np.eye(len(x0))])  # every constant moved by 35 %
    res = minimize(nll, x0, method="Nelder-Mead",
                   options={"maxiter": 3000, "maxfev": 3000, "xatol": 1e-4, "fatol": 1e-3,
                            "initial_simplex": simplex})
    return replace(start, **dict(zip(VEHICLE_FIT, np.exp(res.x), strict=True)))


# --------------------------------------------------------------------------- report


def markdown(result: dict) -> str:
    lines = ["| what | measured | target |", "| --- | --- | --- |"]
    sp = result["speed"]
    lines.append(f"| detection + PnP + covariance, 1280 x 800 frame (median of {sp['frames']}, "
                 f"load average {sp['load_average_1min']}) | {sp['median_ms']} ms wall (p90 "
                 f"{sp['p90_ms']} ms), {sp['cpu_median_ms']} ms CPU | < 15 ms |")
    dt = result["duckietown"]
    if "skipped" not in dt:
        ref = dt["apriltag3_estimate_tag_pose"]
        for key, m in dt.items():
            if not key.startswith("semslam_"):
                continue
            lines.append(f"| duckietown rotation set, {key[8:]}: found, position spread, turn "
                         f"residual | {m.get('found')}/{dt['images']}, "
                         f"{m.get('position_spread_mm')} mm, {m.get('turn_residual_deg')} deg "
                         f"| 15/15, <= {ref.get('position_spread_mm')} mm, "
                         f"<= {ref.get('turn_residual_deg')} deg (AprilTag 3) |")
    rg = result["regression"]
    if "skipped" not in rg:
        for k, v in rg.items():
            lines.append(f"| apriltag-regression, {k} settings | {v['found_within_1px']}/"
                         f"{v['reference_tags']} within 1 px (largest "
                         f"{v['largest_corner_difference_px']} px) | all within 1 px |")
    for row in result["accuracy"]:
        if row["variant"] == "pnp" and row["distance_m"] in ("1.5-5", "5-10", "10-15",
                                                              "15-20"):
            lines.append(f"| simulated range / bearing error, {row['distance_m']} m "
                         f"(n {row['n']}) | range rms {row['range_rms_cm']} cm, max "
                         f"{row['range_max_cm']} cm ({row['range_within_1pct_2cm']:.1%} within "
                         f"1 % + 2 cm; {row['range_within_1pct_2cm_not_overexposed']:.1%} of the "
                         f"{row['n'] - row['overexposed_views']} not overexposed); bearing max "
                         f"{row['bearing_max_deg']} deg "
                         f"| <= 1 % + 2 cm up to 10 m, <= 0.3 deg |")
    nees = result["nees_sweep"]
    lines.append(f"| NEES (x, y, yaw), sweep, {nees['n']} observations | mean {nees.get('mean')} "
                 f"(95 % bounds {nees.get('bounds_95')}); position {nees.get('position_mean')} "
                 f"(bounds {nees.get('position_bounds_95')}), yaw {nees.get('yaw_mean')}; "
                 f"{nees.get('share_above_chi2_95'):.1%} above chi2(3) 95 % | within bounds |")
    for band, v in nees.get("by_distance", {}).items():
        lines.append(f"| NEES, sweep, {band} m ({v['n']}) | mean {v['mean']} (bounds "
                     f"{v['bounds_95']}); position {v['position_mean']}, yaw {v['yaw_mean']} "
                     f"| within bounds |")
    nd = result["nees_drive"]
    lines.append(f"| NEES, tags along a garage drive, {nd['n']} observations | mean "
                 f"{nd.get('mean')} (bounds {nd.get('bounds_95')}); position "
                 f"{nd.get('position_mean')} (bounds {nd.get('position_bounds_95')}), yaw "
                 f"{nd.get('yaw_mean')}; {nd.get('share_above_chi2_95', 0):.1%} above chi2(3) "
                 f"95 % | within bounds |")
    ho = result.get("nees_held_out_drives")
    if ho:
        per = ", ".join(f"{k}: {v.get('mean')} ({v['n']})" for k, v in ho["per_world"].items())
        p = ho["pooled"]
        worlds = ", ".join(map(str, ho["per_world"]))
        lines.append(f"| NEES, tags along the drives of worlds {worlds}, {p['n']} observations "
                     f"| pooled mean {p.get('mean')} (bounds {p.get('bounds_95')}); position "
                     f"{p.get('position_mean')}, yaw {p.get('yaw_mean')}; per world {per} "
                     "| within bounds |")
    cs = result.get("nees_sweep_16_codes")
    if cs:
        lines.append(f"| NEES, sweep over 16 other tag codes, {cs['n']} observations | mean "
                     f"{cs.get('mean')} (bounds {cs.get('bounds_95')}); position "
                     f"{cs.get('position_mean')}, yaw {cs.get('yaw_mean')} | within bounds |")
    rate = ", ".join(f"{r['distance_m']} m: {r['detected']:.0%}" for r in
                     result["detection_rate"] if r["detected"] is not None)
    lines.append(f"| detection rate of tags fully in view (sweep) | {rate} | plotted |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000, help="views in the sweep")
    parser.add_argument("--frames", type=int, default=600,
                        help="frames along the drive (speed and NEES)")
    parser.add_argument("--seed", type=int, default=12)
    parser.add_argument("--calibrate", action="store_true",
                        help="also fit the covariance constants on a sweep with seed 11")
    parser.add_argument("--calibrate-only", action="store_true",
                        help="fit the constants (seed 11 sweep), print them and stop")
    parser.add_argument("--calibration-codes", type=int, default=0,
                        help="calibrate on this many codes instead of tag 77 (0: tag 77)")
    parser.add_argument("--plot", type=Path, default=Path("docs/tag_detection_rate.png"))
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--held-out-drives", default="2,3,4,5,6,7",
                        help="worlds whose drive's tag NEES is also measured ('' for none)")
    parser.add_argument("--code-sweep", type=int, default=2000,
                        help="views of a second sweep over 16 other tag codes (0: skip)")
    parser.add_argument("--speed-only", action="store_true",
                        help="only the per-frame time along the drive (and its NEES)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    result: dict = {}
    settings = TagSettings()
    if args.calibrate or args.calibrate_only:
        codes = calibration_codes(args.calibration_codes) if args.calibration_codes else None
        result["calibration"] = calibrate(sweep(3000, 11, codes))
        result["calibration"]["codes"] = list(codes or (TAG_ID,))
        print(json.dumps(result["calibration"], indent=2), file=sys.stderr)
        if args.calibrate_only:
            return
        if codes:  # check the model just fitted
            settings = TagSettings(noise=TagNoiseModel(**result["calibration"]["model"]))
    times, cpu_times, errors, covs = drive_frames(args.frames, 1, settings)
    result["nees_drive"] = nees_of(errors, covs)
    result["speed"] = {"frames": len(times), "median_ms": round(statistics.median(times), 2),
                       "p90_ms": round(float(np.percentile(times, 90)), 2),
                       "cpu_median_ms": round(statistics.median(cpu_times), 2),
                       "load_average_1min": round(os.getloadavg()[0], 2)}
    if args.speed_only:
        print(json.dumps(result, indent=2))
        return
    result["duckietown"] = duckietown()
    result["regression"] = regression()
    rows = sweep(args.samples, args.seed)
    result["accuracy"] = accuracy_table(rows)
    result["detection_rate"] = detection_rate(rows, args.plot)
    result["nees_sweep"] = sweep_nees(rows, settings)
    if args.held_out_drives:
        result["nees_held_out_drives"] = held_out_drives(
            [int(v) for v in args.held_out_drives.split(",")], args.frames, settings)
    if args.code_sweep:
        codes = other_codes()
        result["nees_sweep_16_codes"] = sweep_nees(sweep(args.code_sweep, args.seed + 1, codes),
                                                   settings)
        result["nees_sweep_16_codes"]["codes"] = list(codes)
    report(markdown(result), result, args.json)


if __name__ == "__main__":
    main()
