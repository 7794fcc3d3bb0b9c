"""`semslam plan-tags`: propose where to put K tags, and how accuracy changes with K.

Reads the map and the route (TUM), runs :mod:`semslam.analysis.tag_placement` (tags chosen
for the worst predicted sigma, or for relocalization: a slot or tag in view within
``within`` seconds from anywhere on the route) and writes ``tag_plan.json`` (the proposed
tags in order, the accuracy and the relocalization coverage after each, the evenly spread
and random comparisons) and ``tag_plan.png`` (the route coloured by the predicted sigma
with the proposed tags numbered, and accuracy against K) into the output folder,
atomically. With ``mapping_route`` (the route of the drive that will map the garage), only
candidates that drive sees from at least :data:`MIN_MAPPING_SIGHTINGS` of its poses are
proposed: a tag the mapper never sees is not in the map the localizer reads.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

from semslam.errors import ConfigError, FormatError

MAX_COUNT = 1000  # tags proposed: each costs a pass over every candidate
MAX_RANDOM_TRIALS = 10000
OBJECTIVES = ("accuracy", "relocalization")
MIN_MAPPING_SIGHTINGS = 3
"""Poses of the mapping route (1 m apart) that must see a candidate for it to be proposed."""


def plan_tags(
    map_path: str | os.PathLike[str],
    route: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    count: int,
    grade: str = "automotive",
    keep_existing: bool = True,
    spacing: float = 5.0,
    offset: float = 3.0,
    random_trials: int = 20,
    objective: str = "accuracy",
    within: float = 2.0,
    mapping_route: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Greedy tag placement along ``route``; the JSON-ready result (files written).

    ``objective`` "accuracy" adds, each round, the tag that most lowers the worst filtered
    sigma; "relocalization" the one that lets the most route poses see a slot or tag within
    ``within`` seconds of driving on (:func:`~semslam.analysis.tag_placement.
    coverage_placement`), stopping early once every pose that can be covered is. Each
    step reports both: its sigmas and ``relocalization_coverage``, the share of route poses
    from which a slot or tag comes into view within ``within`` seconds (a slot counts when
    its entrance is in the top view: detectors report whole slots only).

    ``mapping_route`` (TUM): the route of the drive that will map the garage; candidates it
    sees from fewer than :data:`MIN_MAPPING_SIGHTINGS` poses are not proposed (``route``
    may be several drives' routes, ``mapping_route`` one of them).

    For each K in 1..count, ``random_trials`` draws of K candidates at random (seed 0)
    give the median, best and worst of the worst sigma, its 95th percentile and the mean of
    the route's worst 5 % (``random``).

    Raises:
        MapError / FormatError: broken map or route (or mapping route).
        ConfigError: count < 1, random_trials < 1, unknown grade or objective,
            non-positive spacing, offset or within.
    """
    import numpy as np

    from semslam.analysis.accuracy import GRADES, MapGeometry, SensorModel, route_information
    from semslam.analysis.tag_placement import (
        candidate_tags,
        coverage_placement,
        even_placement,
        greedy_placement,
        placement_spread,
        placement_steps,
        random_placement,
        resample_route,
        seen_often_enough,
        starts_covered,
        tag_visibility,
    )
    from semslam.io import load_map
    from semslam.io.atomic import atomic_group, atomic_write_bytes, atomic_write_text
    from semslam.pipeline.localize import MAX_INIT_FROM_MAP, distance_from_landmarks
    from semslam.plots import tag_plan_figure
    from semslam.types import SemanticMap

    if not 1 <= count <= MAX_COUNT:
        raise ConfigError(f"--count: must be between 1 and {MAX_COUNT}, got {count}")
    if not 1 <= random_trials <= MAX_RANDOM_TRIALS:
        raise ConfigError(
            f"--random-trials: must be between 1 and {MAX_RANDOM_TRIALS}, got {random_trials}"
        )
    if grade not in GRADES:
        raise ConfigError(f"--grade: choose one of {', '.join(GRADES)}, got {grade!r}")
    if objective not in OBJECTIVES:
        raise ConfigError(f"--objective: choose one of {', '.join(OBJECTIVES)}, got {objective!r}")
    for name, value, unit in (
        ("--spacing", spacing, "metres"), ("--offset", offset, "metres"),
        ("--within", within, "seconds"),
    ):
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{name}: must be a positive number of {unit}, got {value}")
    t, poses = _read_route(route)
    mapping = None if mapping_route is None else _read_route(mapping_route)
    semantic_map = load_map(map_path)
    mapping_poses = None if mapping is None else mapping[1]
    for name, path, route_poses in (("--route", route, poses),
                                    ("--mapping-route", mapping_route, mapping_poses)):
        if route_poses is None:
            continue
        found = distance_from_landmarks(route_poses[:, :2], semantic_map)
        if found is not None and found[0] > MAX_INIT_FROM_MAP:
            raise ConfigError(
                f"{name} {os.fspath(path)}: comes no nearer than {found[0]:.0f} m to the "
                f"landmarks of {os.fspath(map_path)} ({found[1]}); give it in the map's frame"
            )
    if not keep_existing:
        semantic_map = SemanticMap(semantic_map.slots, (), semantic_map.markings)
    poses, t = resample_route(poses, t, 1.0)
    geometry = MapGeometry(semantic_map)
    infos, _ = route_information(geometry, poses)
    candidates = candidate_tags(poses, spacing, offset)
    # relocalization needs whole slots (the detectors report a slot only with its entrance
    # in view), not corners
    whole_slots = SensorModel(slot_rule="entrance")
    unmapped = 0
    if mapping is not None:
        mapping_poses, _ = resample_route(mapping[1], mapping[0], 1.0)
        mapped = seen_often_enough(mapping_poses, candidates, whole_slots, MIN_MAPPING_SIGHTINGS)
        unmapped = int(np.sum(~mapped))
        candidates = candidates[mapped]
        if not len(candidates):
            raise ConfigError(
                f"--mapping-route: {os.fspath(mapping_route)} sees none of the "
                f"{unmapped} candidate tags beside --route"
            )
    _, counts = route_information(geometry, poses, whole_slots)
    seen = (counts["slots"] > 0) | (counts["tags"] > 0)
    if objective == "accuracy":
        steps = greedy_placement(infos, poses, t, candidates, count, GRADES[grade])
    else:
        visible = tag_visibility(poses, candidates, whole_slots)
        chosen = coverage_placement(seen, t, visible, count, within)
        steps = placement_steps(infos, poses, t, candidates[chosen], GRADES[grade])
    added = tag_visibility(poses, np.array([s.tag for s in steps[1:]]), whole_slots)
    coverage = [
        float(starts_covered(seen | added[:k].any(axis=0), t, within).mean())
        for k in range(len(steps))
    ]
    even = [
        even_placement(infos, poses, t, candidates, k, GRADES[grade]) for k in range(1, count + 1)
    ]
    rng = np.random.default_rng(0)
    random = [
        {
            "count": k,
            **placement_spread(
                [
                    random_placement(infos, poses, t, candidates, k, GRADES[grade], rng)
                    for _ in range(random_trials)
                ]
            ),
        }
        for k in range(1, count + 1)
    ]
    result: dict[str, Any] = {
        "map": os.fspath(map_path),
        "route": os.fspath(route),
        "grade": grade,
        "objective": objective,
        "within_s": within,
        "existing_tags": len(semantic_map.tags),
        "mapping_route": None if mapping_route is None else os.fspath(mapping_route),
        "candidates": len(candidates),
        "candidates_unmapped": unmapped,
        "greedy": [
            _rounded(asdict(s) | {"relocalization_coverage": c})
            for s, c in zip(steps, coverage, strict=True)
        ],
        "evenly_spread": [_rounded(asdict(s)) for s in even],
        "random": {"trials": random_trials, "seed": 0, "steps": [_rounded(r) for r in random]},
        "proposed_tags": [
            {"x": round(s.tag[0], 3), "y": round(s.tag[1], 3), "yaw": round(s.tag[2], 4)}
            for s in steps[1:]
            if s.tag is not None
        ],
    }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    picture = tag_plan_figure(semantic_map, poses, steps, even, random, coverage)
    with atomic_group():  # both files or neither
        atomic_write_bytes(out / "tag_plan.png", picture)
        atomic_write_text(out / "tag_plan.json",
                          json.dumps(result, indent=2, allow_nan=False) + "\n")
    result["files"] = [os.fspath(out / "tag_plan.json"), os.fspath(out / "tag_plan.png")]
    return result


def _read_route(path: str | os.PathLike[str]):
    """Times (N,) and poses (N, 3) of a TUM route with at least two poses and some length."""
    import numpy as np

    from semslam.io.tum import read_tum

    t, poses = read_tum(path)
    poses = np.asarray(poses, dtype=float)
    length = float(np.sum(np.hypot(*np.diff(poses[:, :2], axis=0).T))) if len(t) >= 2 else 0.0
    if not (math.isfinite(length) and length > 0):
        raise FormatError(f"{os.fspath(path)}: the route needs at least two poses and some length")
    return t, poses


def _rounded(d: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in d.items():
        if isinstance(v, float):
            v = round(v, 4) if math.isfinite(v) else None
        elif isinstance(v, tuple):
            v = [round(float(x), 4) for x in v]
        elif isinstance(v, dict):
            v = _rounded(v)
        out[k] = v
    return out


__all__ = ["plan_tags"]
