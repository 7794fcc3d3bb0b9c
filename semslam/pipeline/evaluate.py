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
        FormatError: a file is missing or broken, or the track CSV does not
            have the trajectory's frames (one line naming the file and line).
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
    return {
        "trajectory": os.fspath(trajectory),
        "truth": os.fspath(truth),
        "track": None if track is None else os.fspath(track_path),
        "map": None if map_path is None else os.fspath(map_path),
        **metrics,
    }
