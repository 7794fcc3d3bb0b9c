"""`semslam localize`: track a drive against a map; write TUM + per-frame CSV.

Writes ``TRAJ.tum`` (the frames with a pose, for evo), ``TRAJ.csv`` beside it (pose,
3x3 covariance, status, associated and rejected counts per frame; see
:mod:`semslam.io.track_csv`) and ``TRAJ.config.json`` (the configuration used). Frames
before the first pose (``--init auto``) are in neither file; the summary says how long
finding the pose took.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam.config import SemslamConfig, config_to_json
from semslam.errors import DriveError
from semslam.pipeline.mapping import check_observation_times, load_observations
from semslam.progress import progress_bar


@dataclass(frozen=True)
class LocalizeSummary:
    """What ``semslam localize`` did."""

    trajectory: Path
    track: Path
    frames: int
    frames_with_pose: int
    first_pose_after_s: float | None
    status_counts: dict[str, int]
    update_ms_median: float
    elapsed_s: float
    driving_s: float
    odometry_errors: tuple | None = None  # ((scale, bias), (sigmas)) at the end, or None


def output_paths(trajectory: Path) -> tuple[Path, Path]:
    """The per-frame track CSV and the configuration written beside ``trajectory``."""
    return trajectory.with_suffix(".csv"), trajectory.with_name(trajectory.stem + ".config.json")


MAX_INIT_M = 1e6  # metres: no garage is larger; far beyond it, floats overflow
MAX_INIT_YAW = 1e3  # radians, before wrapping
MAX_INIT_FROM_MAP = 1e3  # metres from the map's landmarks: farther, a pose in another frame


def parse_init(text: str | None) -> np.ndarray | None:
    """``"x,y,yaw"`` (m, m, rad) -> pose; ``"auto"`` or None -> None (find it in the map)."""
    if text is None or text == "auto":
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise DriveError(f"--init {text}: expected x,y,yaw (m, m, rad) or auto") from None
    if len(values) != 3 or not np.all(np.isfinite(values)):
        raise DriveError(f"--init {text}: expected three finite numbers x,y,yaw or auto")
    if max(abs(values[0]), abs(values[1])) > MAX_INIT_M:
        raise DriveError(
            f"--init: x and y must be within 1e6 m, got {values[0]:g}, {values[1]:g}"
        )
    if abs(values[2]) > MAX_INIT_YAW:
        raise DriveError(f"--init: yaw must be within {MAX_INIT_YAW:g} rad, got {values[2]:g}")
    return np.array(values)


def distance_from_landmarks(points: np.ndarray, semantic_map) -> tuple[float, str] | None:
    """The least distance (m) of ``points`` (N, 2) from the box around the map's landmarks
    (:meth:`~semslam.analysis.accuracy.MapGeometry.bounds`), and the box as text; None for
    a map without landmarks."""
    from semslam.analysis.accuracy import MapGeometry

    geometry = MapGeometry(semantic_map)
    if not (len(geometry.corners) or len(geometry.tags) or len(geometry.lines)):
        return None
    x0, y0, x1, y1 = geometry.bounds(margin=0.0)
    lo, hi = np.array([x0, y0]), np.array([x1, y1])
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    outside = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    box = f"x {x0:.1f}..{x1:.1f} m, y {y0:.1f}..{y1:.1f} m"
    return float(np.hypot(outside[:, 0], outside[:, 1]).min()), box


def check_init_near_map(pose: np.ndarray, semantic_map, map_path: Path) -> None:
    """Refuse an initial pose more than :data:`MAX_INIT_FROM_MAP` from the box around the
    map's landmarks (a pose given in another frame; the filter would only coast away from
    it). A map without landmarks takes any pose."""
    found = distance_from_landmarks(pose[None, :2], semantic_map)
    if found is not None and found[0] > MAX_INIT_FROM_MAP:
        raise DriveError(
            f"--init: {pose[0]:g}, {pose[1]:g} is {found[0]:.0f} m from the landmarks of "
            f"{map_path} ({found[1]}); give a pose in the map's frame"
        )


def localize_drive(
    drive_folder: Path,
    map_path: Path,
    output: Path,
    observations: str,
    init: str | None,
    config: SemslamConfig,
    show_progress: bool | None = None,
) -> LocalizeSummary:
    """Localize the drive at ``drive_folder`` in the map at ``map_path``.

    ``init``: "x,y,yaw", "auto", or None for the drive's declared start pose."""
    from semslam.io import Drive, load_map, write_tum
    from semslam.io.atomic import atomic_group, atomic_write_text
    from semslam.io.track_csv import Track, write_track_csv
    from semslam.io.tum import MAX_POSITION
    from semslam.localization.localizer import Localizer
    from semslam.localization.relocalize import MAX_SLOTS_PER_LABEL

    given_init = None if init is None else parse_init(init)  # bad --init: fail before any work
    semantic_map = load_map(map_path)
    if given_init is not None:
        check_init_near_map(given_init, semantic_map, map_path)
    drive = Drive.open(drive_folder)
    odometry = drive.odometry()
    frames = load_observations(drive, observations, config, show_progress)
    check_observation_times(drive_folder, frames, odometry.t)
    initial = drive.start_pose if init is None else given_init
    started = time.perf_counter()
    localizer = Localizer(
        semantic_map, config.localization, odometry.t, odometry.speed, odometry.yaw_rate, initial
    )
    estimates = []
    with progress_bar(len(frames), "localizing", show_progress) as bar:
        for frame in frames:
            estimate = localizer.step(frame)
            if np.any(np.abs(estimate.pose[:2]) > MAX_POSITION):  # no trajectory can hold it
                raise DriveError(
                    f"{drive_folder}: at {estimate.t:.3f} s the estimate is over "
                    f"{MAX_POSITION / 1e3:g} km from the map's origin; the odometry drove it "
                    f"there (odometry.csv's speeds reach {np.max(np.abs(odometry.speed)):g} "
                    f"m/s); {output} not written"
                )
            estimates.append(estimate)
            bar.update(1)
    elapsed = time.perf_counter() - started
    posed = [e for e in estimates if np.all(np.isfinite(e.pose))]
    track_path, config_path = output_paths(output)
    if not posed:
        repeated = localizer.relocalizer.repeated_labels
        hint = (f" ({repeated} of its slot labels are on more than {MAX_SLOTS_PER_LABEL} slots "
                "each, too many to tell where the car is)" if repeated else "")
        raise DriveError(
            f"{drive_folder}: no pose was found in any frame ({len(frames)} frames) against "
            f"{map_path}{hint}; {output} not written"
        )
    t = np.array([e.t for e in posed])
    poses = np.array([e.pose for e in posed])
    track = Track(
        t,
        poses,
        np.array([e.covariance for e in posed]),
        tuple(e.status for e in posed),
        np.array([e.associated for e in posed]),
        np.array([e.rejected for e in posed]),
    )
    with atomic_group():  # the trajectory, its track and its settings together, or none
        write_tum(output, t, poses)
        write_track_csv(track_path, track)
        atomic_write_text(config_path, config_to_json(config))
    counts: dict[str, int] = {}
    for e in estimates:
        counts[e.status] = counts.get(e.status, 0) + 1
    tracked = [e.update_ms for e in estimates if e.status != "initializing"]
    return LocalizeSummary(
        output,
        track_path,
        len(frames),
        len(posed),
        (posed[0].t - frames[0].t) if posed else None,
        counts,
        float(np.median(tracked)) if tracked else float("nan"),
        elapsed,
        float(frames[-1].t - frames[0].t) if frames else 0.0,
        localizer.odometry_errors,
    )
