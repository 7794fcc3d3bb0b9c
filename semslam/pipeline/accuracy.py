"""`semslam accuracy`: predicted positioning accuracy of a map, along a route or on a grid.

Reads the map (and the route, TUM), runs :mod:`semslam.analysis.accuracy`, writes
``accuracy.json`` (the figures, the worst stretches of the route) and
``accuracy_map.png`` (the map with the grid's single-frame sigma as a heat map and the
route coloured by the filtered sigma) into the output folder, atomically; with the
``localizer`` grade also ``config.json``, the configuration it was predicted for.

Grades: Hofmann's ``automotive`` and ``precise`` (an ideal filter that uses every landmark
in view in every frame), or ``localizer``: semslam's own localizer as configured
(``localization`` section: its process noise, the kinds it uses, painted lines and the
slots' separators as a fallback, corner sigma floor, map covariance scale and floor) on
the simulator's detectors (``simulation.observation_noise``: their miss rates, whole slots
by their entrance) at the simulator's odometry rate.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from semslam.errors import ConfigError

if TYPE_CHECKING:
    from semslam.config import SemslamConfig

TARGET_SIGMA_M = 0.20
"""The industry target for automated valet parking (DESIGN.md): 0.20 m."""

GRADE_NAMES = ("automotive", "precise", "localizer")
"""``semslam accuracy --grade``: Hofmann's two grades and semslam's localizer."""


def prediction_model(grade: str, cfg: SemslamConfig | None = None) -> tuple[Any, Any, Any]:
    """(OdometryGrade, SensorModel, LocalizerModel) of a grade name; the ``localizer`` grade
    reads ``cfg`` (default: :func:`semslam.config.load_config` with no file).

    Raises:
        ConfigError: unknown grade.
    """
    from semslam.analysis.accuracy import (
        GRADES,
        IDEAL,
        SensorModel,
        localizer_grade,
        localizer_model,
        simulated_sensors,
    )

    if grade not in GRADE_NAMES:
        raise ConfigError(f"--grade: choose one of {', '.join(GRADE_NAMES)}, got {grade!r}")
    if grade != "localizer":
        return GRADES[grade], SensorModel(), IDEAL
    if cfg is None:
        from semslam.config import load_config

        cfg = load_config(None)
    sim = cfg.simulation
    return (
        localizer_grade(cfg.localization, sim.drive.odometry_rate),
        simulated_sensors(sim.observation_noise),
        localizer_model(cfg.localization),
    )


def _finite(values: np.ndarray) -> list[float | None]:
    return [None if not math.isfinite(v) else round(float(v), 4) for v in values]


def _stat(values: np.ndarray, q: float) -> float | None:
    """The q-th percentile (an element of ``values``: infinities stay infinite), None when
    it is infinite (unobservable) or there are no values."""
    v = np.asarray(values, float).ravel()
    if not len(v):
        return None
    out = float(np.percentile(v, q, method="higher"))
    return round(out, 4) if math.isfinite(out) else None


def predicted_accuracy(
    map_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    route: str | os.PathLike[str] | None = None,
    grade: str = "automotive",
    grid_step: float = 1.0,
    threshold: float = TARGET_SIGMA_M,
    cfg: SemslamConfig | None = None,
) -> dict[str, Any]:
    """Predict the accuracy the map allows and write the JSON and the picture; ``cfg``
    (default: the configuration in force) for the ``localizer`` grade.

    Raises:
        MapError / FormatError: a broken map or route file.
        ConfigError: unknown grade or a non-positive grid step / threshold.
    """
    from dataclasses import asdict

    from semslam.analysis.accuracy import (
        MapGeometry,
        predicted_along_route,
        predicted_on_grid,
        worst_stretches,
    )
    from semslam.io import load_map
    from semslam.io.atomic import atomic_group, atomic_write_bytes, atomic_write_text
    from semslam.io.tum import read_tum
    from semslam.plots import accuracy_figure

    if grade == "localizer" and cfg is None:
        from semslam.config import load_config

        cfg = load_config(None)
    odometry, sensors, model = prediction_model(grade, cfg)
    for name, value in (("--grid-step", grid_step), ("--threshold", threshold)):
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{name}: must be a positive number of metres, got {value}")
    semantic_map = load_map(map_path)
    geometry = MapGeometry.for_model(semantic_map, model)
    bounds = geometry.bounds()
    if route is not None:
        t, poses = read_tum(route)
        lo = np.minimum(poses[:, :2].min(axis=0) - 2.0, bounds[:2])
        hi = np.maximum(poses[:, :2].max(axis=0) + 2.0, bounds[2:])
        bounds = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    xs, ys, grid = predicted_on_grid(
        geometry, step=grid_step, sensors=sensors, bounds=bounds, model=model
    )
    result: dict[str, Any] = {
        "map": os.fspath(map_path),
        "grade": grade,
        "odometry": asdict(odometry),
        "threshold_m": threshold,
        "grid": {
            "step_m": grid_step,
            "cells": int(grid.size),
            "single_sigma_median_m": _stat(grid.ravel(), 50),
            "single_sigma_p95_m": _stat(grid.ravel(), 95),
            "unobservable_share": round(float(np.mean(~np.isfinite(grid))), 4),
        },
    }
    route_xy = route_sigma = None
    if route is not None:
        along = predicted_along_route(geometry, poses, t, odometry, sensors, model)
        distance = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))])
        route_xy, route_sigma = poses[:, :2], along["filtered_sigma"]
        result["route"] = {
            "file": os.fspath(route),
            "poses": len(t),
            "length_m": round(float(distance[-1]), 2),
            "single_sigma_median_m": _stat(along["single_sigma"], 50),
            "filtered_sigma_median_m": _stat(along["filtered_sigma"], 50),
            "filtered_sigma_p95_m": _stat(along["filtered_sigma"], 95),
            "filtered_sigma_max_m": _stat(along["filtered_sigma"], 100),
            "filtered_yaw_median_deg": _stat(along["filtered_yaw_deg"], 50),
            "share_within_threshold": round(
                float(np.mean(along["filtered_sigma"] <= threshold)), 4
            ),
            "worst_stretches": worst_stretches(distance, along["filtered_sigma"], threshold),
            "per_pose": {
                "t": [round(float(v), 3) for v in t],
                "single_sigma_m": _finite(along["single_sigma"]),
                "filtered_sigma_m": _finite(along["filtered_sigma"]),
            },
        }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    picture = accuracy_figure(semantic_map, xs, ys, grid, route_xy, route_sigma, threshold)
    files = [out / "accuracy.json", out / "accuracy_map.png"]
    with atomic_group():  # every file or none
        atomic_write_bytes(out / "accuracy_map.png", picture)
        atomic_write_text(out / "accuracy.json",
                          json.dumps(result, indent=2, allow_nan=False) + "\n")
        if grade == "localizer":  # the settings it was predicted for (loaded above)
            from semslam.config import config_to_json

            atomic_write_text(out / "config.json", config_to_json(cfg))
            files.append(out / "config.json")
    result["files"] = [os.fspath(f) for f in files]
    return result


__all__ = ["GRADE_NAMES", "TARGET_SIGMA_M", "predicted_accuracy", "prediction_model"]
