"""`semslam evaluate`: read a map and the true map, return the metrics as a JSON-ready dict.

Reading is here; the comparison itself is :func:`semslam.evaluation.evaluate_map`.
"""

from __future__ import annotations

import math
import os
from typing import Any

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
