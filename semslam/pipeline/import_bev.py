"""`semslam import garage-bev`: the real garage drive as a semslam drive folder.

Reads ``../shared/realdata/garage-bev-drive`` (:mod:`semslam.io.garage_bev`) and writes,
atomically (a temporary folder renamed at the end, like ``semslam simulate``)::

    OUT/
      drive.json              start pose, frame rate, the conversion's settings ("source")
      rig.json                no cameras; the masks' grid as the top view
      odometry.csv            speed, yaw rate whose dead reckoning follows the odometry poses
      frames.csv              t,mask  (frames that have a mask; paths through masks/)
      masks -> SRC/masks      symbolic link (the recording is not copied)
      observations/cached.jsonl   marking observations from the slot-line class
      vector_map.json         the hand-made vector map: markings only, semslam map format
      config.json             mapping and localization settings for this drive (``--config``)

The **vehicle frame** of the drive is ISO 8855 with its origin on the point of the car
that does not slide sideways (the rear axle), found from the poses themselves: in the
odometry file the mask centre moves sideways by ``a v + b w`` (``v`` forward speed, ``w``
yaw rate; measured a = 0.048, b = 1.30 m), i.e. the mask centre sits ``b`` ahead of the
rear axle and the recorded heading is turned by ``atan(a)`` (2.8 deg) against the
direction of travel. semslam's odometry model (CTRV: the car moves along its x axis) only
holds for that point and heading, so the poses are turned by ``atan(a)`` and moved
``b cos(atan(a))`` back along the turned axis (recorded in drive.json as
``heading_offset_deg`` and ``vehicle_origin_m``). With the mask centre instead the dead-reckoned
odometry leaves the recorded poses by up to 16.7 m over the 1.3 km drive; with the rear
axle by 5.1 m. The rest is sideways motion the CTRV model cannot represent: the recorded
heading is not exactly the direction of travel (a slowly varying slip of a few tenths of a
degree, not explained by speed, yaw rate, their product, roll or pitch, plus noise; ramps
and timestamps are not the cause: yaw is reproduced to 1e-12 rad and every step uses its
own dt). ``calibrate=False`` keeps the mask centre and the recorded heading.

The masks are drawn in the car's own axes, the direction of travel, not in the recorded
heading's: a car does not crab by 2.8 deg at every speed, and the detections agree.
Placed through the drive's odometry with the recorded heading's turn, the detected lines
met the hand-made vector map at a median angle of -3.7 deg (1,356 lines of 1.5 m or more
within 0.6 m of a vector-map line), on straight stretches the lines along the aisle lay
-4.1 deg off the direction of travel, and the odometry-only map's 95th percentile
distance from the vector map was 6.26 m; in the car's axes -1.0 deg, -1.7 deg and 1.22 m
(2026-11-27, BENCHMARKS.md). So the detections only move to the rear axle
(:func:`to_vehicle`); no turn.

Odometry: one sample per pose of the odometry file (every image time, 10 Hz), sample i
holding from ``t[i]`` to ``t[i+1]`` (semslam's zero-order hold). The open-loop derivation
(:func:`derive_odometry`: ``w = dyaw / dt``, ``v`` the chord's forward component at the
mid heading lengthened to the arc) loses each step's sideways part, which adds up to the
5.1 m. :func:`track_odometry` instead turns the headings by a small, smooth slip angle
(p95 0.5 deg, at most 1.4 deg) chosen so that the dead-reckoned positions stay on the
recorded ones (at most 0.04 m, p95 0.014 m, over the whole drive); the vehicle frame is
turned with it, frame by frame (the detections too), so dead reckoning places every
detection where the recorded pose puts it. The last sample repeats the one before.

Masks: the slot-line class (RGB 128,128,0); ``crop_rows`` rows at the top and bottom
(ahead of and behind the car) are blanked, as the recording's own pipeline did; the rest
goes through :meth:`~semslam.perception.markings.MarkingDetector.detect_mask`.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam import __version__
from semslam.errors import DriveError, FormatError
from semslam.geometry import FloatArray
from semslam.pipeline.drive_output import staged_drive_folder
from semslam.progress import progress_bar

VECTOR_MAP_JSON = "vector_map.json"
CONFIG_JSON = "config.json"
OBSERVATION_SET = "cached"

# track_odometry: the dead-reckoned positions follow the recorded ones within this (m) ...
TRACK_POSITION_SIGMA = 0.02
# ... by turning the headings by a slip angle that changes by about this per sample (rad;
# at 10 Hz 0.001 rad per sample is 0.01 rad/s of yaw rate) ...
TRACK_TURN_SIGMA = 0.001
# ... and stays about this small (rad)
TRACK_SLIP_SIGMA = 0.01

# mapping settings for this drive, written to OUT/config.json (``semslam map --config``).
# Chosen on this drive itself (benchmarks/bench_garage_bev.py; no held-out drive exists):
# - calibrate_odometry off: the odometry is already a fused estimate with no wheel scale or
#   gyro bias to find; with it on, the line factors pull the bias to 0.2 deg/s and the
#   map diverges (or gtsam finds the calibration variable indeterminate);
# - marking_min_support 3: past frame 299 masks come 1 s apart, so a line is seen in 3-4
#   frames only and 5 drops most of them;
# - speed_sigma 0.003 m/s, yaw_rate_sigma 0.0003 rad/s: odometry.csv reproduces the recorded
#   poses (a fused estimate, passes within about a metre after 1.3 km) to 4 cm, far better
#   than the simulator's wheel odometry the defaults (0.03, 0.003) describe; with those the
#   line factors bend the trajectory (median 0.49 / 0.65 m both ways, against 0.17 for the
#   odometry alone); 0.01 / 0.001: 0.21 / 0.26 m; 0.003 / 0.0003: 0.15 / 0.20 m;
# - marking_distance_gate 0.5 m: with that odometry, passes over a row agree within about
#   half a metre; 1.0 m lets slot separators and end lines take wrong detections (map->ref
#   p95 3.5 m against 2.9 m);
# - marking_sigma 0.15 m: detections of a line in consecutive masks share the same
#   segmentation error, so 0.05 m per detection made the lines outweigh the odometry
#   (chosen with the old odometry; 0.3 with the new is worse: map->ref p95 4.0 m).
DRIVE_MAPPING_CONFIG: dict = {
    "calibrate_odometry": False,
    "speed_sigma": 0.003,
    "yaw_rate_sigma": 0.0003,
    "marking_min_support": 3,
    "marking_distance_gate": 0.5,
    "marking_sigma": 0.15,
}

# localization settings for this drive, written beside the mapping ones (``semslam localize
# --config``); the same odometry and masks, so the same reasons; measured with
# benchmarks/bench_garage_bev_localization.py against the vector map (BENCHMARKS.md). With
# the defaults the filter is lost in 550 of 1,253 frames and wanders up to 17 m from the
# odometry; with these, 2 and 0.25 m.
# - speed_sigma, yaw_rate_sigma, estimate_odometry_errors off: as for mapping;
# - marking_endpoint_sigma 0.15 m: the masks' segmentation error, as mapping's marking_sigma;
# - init_position_sigma 0.1 m, init_yaw_sigma_deg 0.5: the start pose is the recording's
#   first pose, which the vector map agrees with to about 0.1 m;
# - map_floor_scale 0: no floor under the position covariance. The floor (the markings'
#   0.05 m) made the heading follow the line directions of the hand-made map, which
#   disagree with the masks by about a degree, instead of the path the lines put the car
#   on: the heading left the odometry's by up to 0.5 deg (3.7 deg with a 0.15 m floor) and
#   the position by up to 1.7 m; without it, 0.2 deg and 0.25 m, and the detections land
#   closer to the vector map than through the odometry.
DRIVE_LOCALIZATION_CONFIG: dict = {
    "speed_sigma": 0.003,
    "yaw_rate_sigma": 0.0003,
    "estimate_odometry_errors": False,
    "marking_endpoint_sigma": 0.15,
    "init_position_sigma": 0.1,
    "init_yaw_sigma_deg": 0.5,
    "map_floor_scale": 0.0,
}


@dataclass(frozen=True)
class ImportSummary:
    """What ``import_garage_bev`` wrote."""

    folder: Path
    frames: int
    odometry_samples: int
    markings: int
    vector_map_lines: int
    duration_s: float
    distance_m: float
    vehicle_origin_m: float  # along the mask frame's x: negative = behind the mask centre
    heading_offset_deg: float  # the direction of travel against the recorded heading
    dead_reckoning_max_m: float  # dead-reckoned odometry.csv against the recorded poses
    dead_reckoning_open_loop_max_m: float  # the same with the recorded headings (no tracking)
    slip_angle_max_deg: float  # the odometry heading's largest turn against the calibrated one
    seconds: float


# --------------------------------------------------------------------------- pure helpers


def odometry_point(t: FloatArray, poses: FloatArray, min_speed: float = 0.3) -> tuple[float, float]:
    """``(offset, heading)``: the car's axis is the poses' x axis turned by ``heading``
    (rad), and the point that moves along it (the rear axle) lies ``offset`` metres along
    it from the poses' position (negative: behind). By least squares on the sideways
    velocity ``s = tan(heading) f - d w`` in the poses' frame of steps faster than
    ``min_speed`` (one pass without residuals beyond 3 sigma): a point ``c`` ahead of the
    axle on the car's axis gives ``d = c / cos(heading)``."""
    dt = np.diff(t)
    dyaw = np.diff(poses[:, 2])
    mid = poses[:-1, 2] + dyaw / 2
    step = np.diff(poses[:, :2], axis=0)
    f = (step[:, 0] * np.cos(mid) + step[:, 1] * np.sin(mid)) / dt
    s = (-step[:, 0] * np.sin(mid) + step[:, 1] * np.cos(mid)) / dt
    w = dyaw / dt
    use = np.abs(f) > min_speed
    if use.sum() < 10:
        return 0.0, 0.0
    A = np.column_stack([f, w])
    coef = np.linalg.lstsq(A[use], s[use], rcond=None)[0]
    r = s - A @ coef
    use &= np.abs(r) < 3 * r[use].std()
    coef = np.linalg.lstsq(A[use], s[use], rcond=None)[0]
    heading = math.atan(coef[0])
    return float(-coef[1] * math.cos(heading)), float(heading)


def move_poses(poses: FloatArray, offset: float, heading: float) -> FloatArray:
    """Poses turned by ``heading`` and then moved ``offset`` metres along their turned x
    axis (yaw kept unwrapped)."""
    out = np.array(poses, dtype=float)
    out[:, 2] += heading
    out[:, 0] += offset * np.cos(out[:, 2])
    out[:, 1] += offset * np.sin(out[:, 2])
    return out


def derive_odometry(
    t: FloatArray, poses: FloatArray, yaw: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Speed and yaw rate (N,) from consecutive poses (N, 3) with unwrapped yaw: sample i
    holds from t[i] to t[i+1]; the arc through both positions along the mid heading.

    ``yaw`` (N,), unwrapped, replaces the poses' own headings (see :func:`track_odometry`).
    Open loop: whatever part of a step runs sideways to the mid heading is lost, so dead
    reckoning drifts away from the poses wherever they slide sideways."""
    if len(t) == 1:
        return np.zeros(1), np.zeros(1)
    psi = poses[:, 2] if yaw is None else np.asarray(yaw, dtype=float)
    dt = np.diff(t)
    dyaw = np.diff(psi)
    mid = psi[:-1] + dyaw / 2
    step = np.diff(poses[:, :2], axis=0)
    forward = step[:, 0] * np.cos(mid) + step[:, 1] * np.sin(mid)
    half = dyaw / 2
    small = np.abs(half) < 1e-9
    arc = np.where(small, 1.0, half / np.sin(np.where(small, 1.0, half)))
    speed = forward * arc / dt
    yaw_rate = dyaw / dt
    return np.append(speed, speed[-1]), np.append(yaw_rate, yaw_rate[-1])


def track_odometry(
    t: FloatArray,
    poses: FloatArray,
    position_sigma: float = TRACK_POSITION_SIGMA,
    turn_sigma: float = TRACK_TURN_SIGMA,
    slip_sigma: float = TRACK_SLIP_SIGMA,
    iterations: int = 3,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Speed, yaw rate and the headings ``yaw`` (each (N,)) whose CTRV dead reckoning from
    ``poses[0]`` follows the positions of ``poses`` (N, 3, unwrapped yaw) without drifting.

    A CTRV step moves along the mid heading only, so a pose sequence that slides sideways
    (``a v`` of side slip left after :func:`odometry_point`, noise) cannot be reproduced
    with its own headings: the lost sideways part adds up (5 m over the real drive). Here
    the headings are turned by small corrections ``delta`` (the slip angle: course minus
    heading) chosen by least squares: every dead-reckoned position within
    ``position_sigma`` of the pose's (exact constraint: the reckoned path is the sum of the
    chords projected on the corrected mid headings), the change of ``delta`` per sample
    ``turn_sigma`` (it becomes yaw-rate noise) and ``delta`` itself ``slip_sigma``.
    Gauss-Newton on a sparse KKT system; speed and yaw rate then come from
    :func:`derive_odometry` with the corrected headings.
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    t = np.asarray(t, dtype=float)
    poses = np.asarray(poses, dtype=float)
    n = len(t)
    psi = poses[:, 2].copy()
    if n < 3:
        speed, yaw_rate = derive_odometry(t, poses)
        return speed, yaw_rate, psi
    step = np.diff(poses[:, :2], axis=0)
    k = np.arange(n - 1)
    nx, ne = n, 2 * n  # unknowns: delta increments x (n), position errors E (n, 2)
    for _ in range(iterations):
        mid = psi[:-1] + np.diff(psi) / 2
        c, s = np.cos(mid), np.sin(mid)
        forward = step[:, 0] * c + step[:, 1] * s
        side = -step[:, 0] * s + step[:, 1] * c
        # reckoned step = forward * (c, s); its error against the chord = -side * (-s, c);
        # d(step)/d(mid) = forward * (-s, c) + side * (c, s)
        error_step = np.column_stack([side * s, -side * c])
        J = np.column_stack([-s * forward + c * side, c * forward + s * side])
        dev = psi - poses[:, 2]
        # soft residuals (rows of W): turn, slip, position
        r_rows = [k, k, n - 1 + np.arange(n), 2 * n - 1 + np.arange(2 * n)]
        r_cols = [k + 1, k, np.arange(n), nx + np.arange(ne)]
        r_vals = [
            np.full(n - 1, 1 / turn_sigma),
            np.full(n - 1, -1 / turn_sigma),
            np.full(n, 1 / slip_sigma),
            np.full(ne, 1 / position_sigma),
        ]
        W = sp.csr_matrix(
            (np.concatenate(r_vals), (np.concatenate(r_rows), np.concatenate(r_cols))),
            shape=(4 * n - 1, nx + ne),
        )
        # residuals = W z + w_fixed for the unknowns z = (x, E): x the heading increments,
        # E the position errors themselves (so nothing fixed on their rows)
        w_fixed = np.concatenate([np.diff(dev) / turn_sigma, dev / slip_sigma, np.zeros(ne)])
        # hard constraints (linearised dead reckoning): E[k+1] - E[k] - J_k (x_k + x_k+1) / 2
        # = error_step_k, E[0] = 0,
        # x[0] = 0 (the start pose is the recording's)
        rows, cols, vals = [], [], []
        for j in range(2):
            row = 2 * k + j
            rows += [row, row, row, row]
            cols += [nx + 2 * (k + 1) + j, nx + 2 * k + j, k, k + 1]
            vals += [np.ones(n - 1), -np.ones(n - 1), -J[:, j] / 2, -J[:, j] / 2]
        m = 2 * (n - 1)
        rows += [np.array([m, m + 1, m + 2])]
        cols += [np.array([nx, nx + 1, 0])]
        vals += [np.ones(3)]
        C = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(m + 3, nx + ne),
        )
        d = np.concatenate([error_step.ravel(), np.zeros(3)])
        H = (W.T @ W).tocsc()
        g = -(W.T @ w_fixed)
        kkt = sp.bmat([[H, C.T], [C, None]], format="csc")
        z = spl.spsolve(kkt, np.concatenate([g, d]))
        psi = psi + z[:nx]
    speed, yaw_rate = derive_odometry(t, poses, psi)
    return speed, yaw_rate, psi


def to_vehicle(points: FloatArray, offset: float) -> FloatArray:
    """Points (N, 2) of a mask (metres, ISO axes, origin the mask centre) in the vehicle
    frame, whose origin lies ``offset`` metres along x from the mask centre (negative:
    behind it). The mask's axes are the car's, so nothing turns."""
    return np.asarray(points, dtype=float) - [offset, 0.0]


# --------------------------------------------------------------------------- the import


def mask_observations(
    rec, every: int, crop_rows: int, offset: float, show_progress: bool | None
) -> tuple[list, list[str], tuple[int, int] | None]:
    """The painted lines of every ``every``-th slot-line mask of the recording ``rec``
    (:func:`semslam.io.garage_bev.open_garage_bev`), ``crop_rows`` blanked at the top and
    bottom, in the vehicle frame whose origin lies ``offset`` m ahead of the mask centre
    (:func:`to_vehicle`).

    Returns:
        One ``FrameObservations`` per mask used, its path inside the drive folder
        (``masks/NAME``), and the masks' (rows, columns); None when no mask was read.

    Raises:
        DriveError: ``crop_rows`` would blank every row. FormatError: a broken mask, or
            one whose size differs from the first's.
    """
    from semslam.io.garage_bev import METRES_PER_PX, SLOT_LINE_RGB, class_mask
    from semslam.io.images import read_image
    from semslam.perception.markings import MarkingDetector
    from semslam.types import FrameObservations, MarkingObservation

    detector = MarkingDetector()
    pick = np.arange(0, len(rec.mask_frames), every)
    frames: list[FrameObservations] = []
    paths: list[str] = []
    shape = None
    with progress_bar(len(pick), "masks", show_progress) as bar:
        for i in pick:
            path = rec.mask_paths[i]
            mask = class_mask(read_image(path), SLOT_LINE_RGB, os.fspath(path))
            if shape is None:
                shape = mask.shape
                if 2 * crop_rows >= shape[0]:
                    raise DriveError(
                        f"{os.fspath(path)}: --crop-rows {crop_rows} blanks all "
                        f"{shape[0]} rows of the mask (at most {(shape[0] - 1) // 2})"
                    )
            elif mask.shape != shape:
                raise FormatError(
                    f"{os.fspath(path)}: {mask.shape[1]} x {mask.shape[0]} px, the first "
                    f"mask was {shape[1]} x {shape[0]}"
                )
            if crop_rows:
                mask[:crop_rows] = False
                mask[max(mask.shape[0] - crop_rows, 0) :] = False
            h, w = mask.shape
            observations = []
            for o in detector.detect_mask(mask, METRES_PER_PX, (w / 2, h / 2)):
                vE = to_vehicle(np.array([o.vA, o.vB]), offset)
                observations.append(MarkingObservation(vE[0], vE[1], o.width, o.confidence))
            frames.append(
                FrameObservations(t=float(rec.mask_times[i]), markings=tuple(observations))
            )
            paths.append(f"masks/{path.name}")
            bar.update(1)
    return frames, paths, shape


def import_garage_bev(
    src: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    crop_rows: int = 300,
    calibrate: bool = True,
    every: int = 1,
    show_progress: bool | None = None,
) -> ImportSummary:
    """Write the garage-bev-drive recording at ``src`` as a drive folder at ``out_dir``.

    Args:
        src: the recording (``../shared/realdata/garage-bev-drive``).
        out_dir: the drive folder to write (replaced if it holds a drive).
        crop_rows: mask rows blanked at the top and at the bottom (their pipeline: 300).
        calibrate: put the vehicle frame on the rear axle and the direction of travel
            (measured from the poses); False keeps the mask centre and the body axes.
        every: use every n-th mask frame only (quick looks; odometry is always complete).
        show_progress: tqdm bar on stderr (None: when stderr is a terminal).

    Raises:
        DriveError, FormatError: a missing or broken input file (one line naming it), or
            an output folder that exists and holds something other than a drive.
    """
    from semslam.io import (
        DriveInfo,
        FrameIndex,
        Odometry,
        save_map,
        save_rig,
        write_drive_info,
        write_frames,
        write_observations,
        write_odometry,
    )
    from semslam.io._text import path_text
    from semslam.io.atomic import atomic_write_text
    from semslam.io.garage_bev import (
        METRES_PER_PX,
        SLOT_LINE_RGB,
        open_garage_bev,
        read_vector_map,
    )
    from semslam.motion import integrate_odometry
    from semslam.rig import Rig, TopviewSpec
    from semslam.types import Marking, SemanticMap

    started = time.perf_counter()
    src, out_dir = Path(src), Path(out_dir)
    if crop_rows < 0:
        raise DriveError(f"--crop-rows: must be >= 0, got {crop_rows}")
    if every < 1:
        raise DriveError(f"--every: must be >= 1, got {every}")
    rec = open_garage_bev(src)
    segments = read_vector_map(src)
    offset, heading = odometry_point(rec.odometry_t, rec.odometry_poses) if calibrate else (0, 0)
    poses = move_poses(rec.odometry_poses, offset, heading)
    speed, yaw_rate = derive_odometry(rec.odometry_t, poses)
    reckoned = integrate_odometry(poses[0], rec.odometry_t, speed, yaw_rate)
    open_loop_drift = float(np.hypot(*(reckoned[:, :2] - poses[:, :2]).T).max())
    speed, yaw_rate, yaw = track_odometry(rec.odometry_t, poses)
    slip = yaw - poses[:, 2]  # per pose: the odometry heading's turn against the calibrated one
    reckoned = integrate_odometry(poses[0], rec.odometry_t, speed, yaw_rate)
    deviation = np.hypot(*(reckoned[:, :2] - poses[:, :2]).T)
    drift = float(deviation.max())

    with staged_drive_folder(out_dir, DriveError) as tmp:
        frames, paths, shape = mask_observations(rec, every, crop_rows, offset, show_progress)
        masks_link = tmp / "masks"
        try:
            masks_link.symlink_to((src / "masks").resolve(), target_is_directory=True)
        except OSError:
            paths = []  # no link possible: frames.csv lists times only
        write_odometry(tmp / "odometry.csv", Odometry(rec.odometry_t, speed, yaw_rate))
        write_frames(
            tmp / "frames.csv",
            FrameIndex(np.array([f.t for f in frames]), {"mask": paths} if paths else {}),
        )
        write_observations(tmp / "observations" / f"{OBSERVATION_SET}.jsonl", frames)
        h, w = shape if shape is not None else (0, 0)
        save_rig(
            tmp / "rig.json",
            Rig(cameras={}, topview=TopviewSpec(max(h, w, 16), METRES_PER_PX, 0.0, 0.0)),
        )
        save_map(
            tmp / VECTOR_MAP_JSON,
            SemanticMap(
                markings=tuple(Marking(s[0].copy(), s[1].copy(), 0.1) for s in segments),
                metadata={
                    "generator": f"semslam {__version__}",
                    "source": path_text(src.resolve() / "vector_map"),
                    "frame": "map x = Ly, map y = Bx",
                },
            ),
        )
        start = poses[0].copy()
        start[2] = math.remainder(start[2], 2 * math.pi)
        write_drive_info(
            tmp / "drive.json",
            DriveInfo(
                name="garage-bev-drive",
                start_pose=start,
                frame_rate=10.0,
                source={
                    "generator": f"semslam {__version__}",
                    "recording": path_text(src.resolve()),
                    "origin": "zhaojinlong-123/3D-SMLoc commit d4c8b26",
                    "map_frame": "the odometry file's x-y plane; vector map x = Ly, y = Bx",
                    "vehicle_frame": "ISO 8855, origin vehicle_origin_m along x from the "
                    "mask centre, axes the mask's (the direction of travel); the odometry's "
                    "heading is the recorded one turned by heading_offset_deg and a slip "
                    "angle per pose from track_odometry (dead reckoning follows the "
                    "recorded positions)",
                    "vehicle_origin_m": offset,
                    "heading_offset_deg": math.degrees(heading),
                    "mask_class_rgb": list(SLOT_LINE_RGB),
                    "crop_rows": crop_rows,
                    "every": every,
                    "dead_reckoning_max_m": round(drift, 3),
                    "dead_reckoning_p95_m": round(float(np.percentile(deviation, 95)), 3),
                    "dead_reckoning_open_loop_max_m": round(open_loop_drift, 3),
                    "slip_angle_max_deg": round(math.degrees(float(np.abs(slip).max())), 3),
                    "slip_angle_p95_deg": round(
                        math.degrees(float(np.percentile(np.abs(slip), 95))), 3
                    ),
                },
                observations=(OBSERVATION_SET,),
            ),
        )
        atomic_write_text(
            tmp / CONFIG_JSON, json.dumps(
                {"mapping": DRIVE_MAPPING_CONFIG, "localization": DRIVE_LOCALIZATION_CONFIG},
                indent=2,
            ) + "\n"
        )
    steps = np.hypot(*np.diff(rec.odometry_poses[:, :2], axis=0).T)
    return ImportSummary(
        folder=out_dir,
        frames=len(frames),
        odometry_samples=len(rec.odometry_t),
        markings=sum(len(f.markings) for f in frames),
        vector_map_lines=len(segments),
        duration_s=float(rec.odometry_t[-1] - rec.odometry_t[0]),
        distance_m=float(steps.sum()),
        vehicle_origin_m=offset,
        heading_offset_deg=math.degrees(heading),
        dead_reckoning_max_m=drift,
        dead_reckoning_open_loop_max_m=open_loop_drift,
        slip_angle_max_deg=math.degrees(float(np.abs(slip).max())),
        seconds=time.perf_counter() - started,
    )
