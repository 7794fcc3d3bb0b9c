"""`semslam evaluate`: read an output and its ground truth, return JSON-ready metrics.

Reading is here; the comparisons themselves are :func:`semslam.evaluation.evaluate_map`
(maps) and :func:`semslam.evaluation.trajectory_metrics.evaluate_trajectory` (trajectories).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from semslam.errors import ConfigError


def evaluate_map_files(
    map_path: str | os.PathLike[str],
    truth_path: str | os.PathLike[str],
    align: bool = False,
    match_radius: float = 1.0,
) -> dict[str, Any]:
    """Evaluate the map file ``map_path`` against the true map file ``truth_path``.

    Args:
        map_path: the built map (semslam map JSON).
        truth_path: the true map, e.g. a simulated drive's ``world.json``.
        align: fit and apply a rigid SE(2) transform of the map onto the truth first.
        match_radius: largest mean corner distance of a matched slot pair, metres.

    Returns:
        ``{"map": ..., "truth": ...}`` followed by
        :meth:`semslam.evaluation.MapMetrics.to_dict`: plain JSON values, None
        for metrics without samples (never NaN).

    Raises:
        MapError: a file is missing, unreadable or not a valid map (one line
            naming the file and field).
        ConfigError: ``match_radius`` is not a positive number.
    """
    from semslam.evaluation import evaluate_map
    from semslam.io import load_map

    if not (isinstance(match_radius, int | float) and math.isfinite(match_radius)):
        raise ConfigError(f"match_radius: must be a positive number of metres, got {match_radius}")
    if match_radius <= 0:
        raise ConfigError(f"match_radius: must be a positive number of metres, got {match_radius}")
    estimate = load_map(map_path)
    truth = load_map(truth_path)
    metrics = evaluate_map(estimate, truth, match_radius=match_radius, align=align)
    return {"map": os.fspath(map_path), "truth": os.fspath(truth_path), **metrics.to_dict()}


TRACK_TIME_TOLERANCE_S = 1e-6  # the TUM file keeps 6 decimals of the time stamps


def evaluate_trajectory_files(
    trajectory: str | os.PathLike[str],
    truth: str | os.PathLike[str],
    map_path: str | os.PathLike[str] | None = None,
    align: bool = False,
) -> dict[str, Any]:
    """Evaluate the TUM trajectory ``trajectory`` against the true TUM trajectory ``truth``.

    When the localizer's track CSV (:mod:`semslam.io.track_csv`) lies beside
    the trajectory (same name, suffix ``.csv``: ``run.tum`` -> ``run.csv``)
    its covariances and statuses are used: NEES, and lost or initializing
    frames left out of the errors. The poses are the TUM file's.

    Args:
        trajectory: the estimate, TUM (map frame).
        truth: the true trajectory, TUM (e.g. a simulated drive's groundtruth.tum).
        map_path: a semslam map JSON whose markings (or slot sides) are the
            reference of the parallel / orthogonal error split; None to
            split along the true heading.
        align: fit and apply the best SE(2) transform of the estimate onto
            the truth first.

    Returns:
        ``{"trajectory": ..., "truth": ..., "track": path or None, "map":
        path or None}`` followed by
        :func:`semslam.evaluation.trajectory_metrics.evaluate_trajectory`'s
        dict: plain JSON values, None for metrics without samples.

    Raises:
        FormatError: a file is missing or broken, the track CSV does not have the
            trajectory's frames (one line naming the file and line), or no estimate
            time meets the truth's (both time spans named).
        MapError: the map file is missing or not a valid map.
    """
    from semslam.errors import FormatError
    from semslam.evaluation.trajectory_metrics import evaluate_trajectory, map_segments
    from semslam.io import load_map, read_track_csv, read_tum

    t, poses = read_tum(trajectory)
    truth_t, truth_poses = read_tum(truth)
    track_path = Path(trajectory).with_suffix(".csv")
    track = read_track_csv(track_path) if track_path.is_file() else None
    if track is not None:
        name = os.fspath(track_path)
        if len(track) != len(t):
            raise FormatError(
                f"{name}: {len(track)} frames, but {os.fspath(trajectory)} has {len(t)} poses"
            )
        off = np.flatnonzero(np.abs(track.t - t) > TRACK_TIME_TOLERANCE_S)
        if off.size:
            k = int(off[0])
            raise FormatError(
                f"{name} line {k + 2}: t {float(track.t[k])!r} differs from "
                f"{os.fspath(trajectory)}'s pose {k} ({t[k]:.6f})"
            )
    segments = map_segments(load_map(map_path)) if map_path is not None else None
    metrics = evaluate_trajectory(
        t,
        poses,
        truth_t,
        truth_poses,
        covariances=None if track is None else track.covariances,
        status=None if track is None else track.status,
        markings=segments,
        align=align,
    )
    if len(t) and metrics["frames_unmatched"] == len(t):  # the wrong truth file, most likely
        raise FormatError(
            f"{os.fspath(trajectory)}: no pose lies within {metrics['max_time_gap_s']:g} s of "
            f"a true one (estimate {t[0]:.3f}-{t[-1]:.3f} s, {os.fspath(truth)} "
            f"{truth_t[0]:.3f}-{truth_t[-1]:.3f} s)"
        )
    return {
        "trajectory": os.fspath(trajectory),
        "truth": os.fspath(truth),
        "track": None if track is None else os.fspath(track_path),
        "map": None if map_path is None else os.fspath(map_path),
        **metrics,
    }


def evaluate_markings_files(
    map_path: str | os.PathLike[str],
    vector_map: str | os.PathLike[str],
    trajectory: str | os.PathLike[str] | None = None,
    radius: float = 5.0,
    tolerance: float = 0.3,
) -> dict[str, Any]:
    """Compare the painted lines of the map file ``map_path`` with a reference vector map,
    both ways, over the area within ``radius`` m of the drive
    (:func:`semslam.evaluation.line_map.compare_line_maps`).

    Args:
        map_path: the built map (semslam map JSON); its markings are compared.
        vector_map: the reference: a garage-bev ``vector_map/`` folder (point.csv,
            line.csv) or the recording holding it, or a semslam map JSON whose
            markings are the reference (``semslam import garage-bev`` writes one).
        trajectory: where the drive went (TUM, map frame); None: the keyframe trajectory
            ``semslam map`` writes beside the map (``MAP.trajectory.tum``).
        radius: the area compared, metres from the trajectory's positions.
        tolerance: distance under which an end point counts as matched, metres.

    Returns:
        ``{"map", "vector_map", "trajectory"}`` paths, then the vector map to the map
        (``median_m``, ``p95_m``, ``matched``: vector-map end points within
        ``tolerance``, ``vector_points``: those in the area, ``within_share``,
        ``max_m``), the map to the vector map (``precision_median_m``,
        ``precision_p95_m``, ``precision_matched``, ``mapped_points``,
        ``precision_within_share``, ``precision_max_m``), the segment counts in the
        area and ``radius_m``, ``tolerance_m``; None where a direction has no point.

    Raises:
        ConfigError: ``radius`` or ``tolerance`` is not a positive number (named as the
            command's options), or there
            is no trajectory.
        MapError, FormatError, DriveError: a file is missing or broken (one line naming
            the file and line).
    """
    from semslam.evaluation.line_map import compare_line_maps
    from semslam.io import load_map, read_tum
    from semslam.io.garage_bev import read_vector_map

    for name, value in (("--radius", radius), ("--tolerance", tolerance)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ConfigError(f"{name}: must be a positive number of metres, got {value}")
    map_path = Path(map_path)
    if trajectory is None:
        trajectory = map_path.with_name(map_path.stem + ".trajectory.tum")
        if not trajectory.is_file():
            raise ConfigError(
                f"{os.fspath(trajectory)}: missing (the area compared is the drive's: "
                "pass --trajectory TRAJ.tum)"
            )
    mapped = _marking_segments(load_map(map_path))
    reference_path = Path(vector_map)
    if reference_path.is_file():
        reference = _marking_segments(load_map(reference_path))
    else:
        reference = read_vector_map(reference_path)
    _, poses = read_tum(trajectory)
    c = compare_line_maps(mapped, reference, poses[:, :2], radius=radius, tolerance=tolerance)
    ref, got = c.reference_to_map, c.map_to_reference

    def plain(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        "map": os.fspath(map_path),
        "vector_map": os.fspath(vector_map),
        "trajectory": os.fspath(trajectory),
        "median_m": plain(ref.median_m),
        "p95_m": plain(ref.p95_m),
        "matched": int(round(ref.within_share * ref.points)) if ref.points else 0,
        "vector_points": ref.points,
        "within_share": plain(ref.within_share),
        "max_m": plain(ref.max_m),
        "precision_median_m": plain(got.median_m),
        "precision_p95_m": plain(got.p95_m),
        "precision_matched": int(round(got.within_share * got.points)) if got.points else 0,
        "mapped_points": got.points,
        "precision_within_share": plain(got.within_share),
        "precision_max_m": plain(got.max_m),
        "vector_segments": c.reference_segments,
        "mapped_segments": c.mapped_segments,
        "radius_m": c.radius_m,
        "tolerance_m": c.tolerance_m,
    }


def _marking_segments(semantic_map) -> np.ndarray:
    """(M, 2, 2) end points of a map's painted lines."""
    return np.array([[m.a, m.b] for m in semantic_map.markings], dtype=float).reshape(-1, 2, 2)
