"""Where to put fiducial tags: greedy placement on the predicted accuracy along a route.

Candidates stand beside the route every ``spacing`` metres, ``offset`` metres to either
side, facing the cars that drive toward them (the front camera sees them on approach).
Each round adds the candidate that most lowers the worst filtered position sigma along
the route (ties broken by the mean), with the route's landmark information computed once
and each candidate's tag information once (:mod:`semslam.analysis.accuracy`). For
comparison, the same number of tags spread evenly along the route (TiEV found 10
evenly spread tags best, by trial) or drawn at random from the candidates.

A second objective, for finding the car with no initial pose: from every pose of the route
some slot or tag should come into view within ``within_s`` seconds of driving on
(:func:`starts_covered`); :func:`coverage_placement` adds, each round, the candidate that
covers the most starts still uncovered. A tag helps the localizer only once it is in the
map, so candidates the mapping drive would not see often enough can be set aside first
(:func:`seen_often_enough`). Pure numpy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from semslam.analysis.accuracy import (
    OdometryGrade,
    RouteFilter,
    SensorModel,
    filter_route,
    position_sigmas,
    tag_information,
)
from semslam.geometry import FloatArray


@dataclass(frozen=True)
class PlacementStep:
    """Accuracy along the route with ``count`` added tags: worst, 95th percentile and mean
    filtered position sigma (m), and the mean over the worst 5 % of the route's poses
    (``worst5_mean_m``, m); ``tag`` the pose (x, y, yaw) added at this step."""

    count: int
    worst_m: float
    p95_m: float
    mean_m: float
    worst5_mean_m: float
    tag: tuple[float, float, float] | None = None


def route_distance(poses: FloatArray) -> FloatArray:
    """Arc length (m) along the route's positions."""
    steps = np.hypot(*np.diff(np.asarray(poses, float)[:, :2], axis=0).T)
    return np.concatenate([[0.0], np.cumsum(steps)])


def resample_route(
    poses: FloatArray, times: FloatArray, step: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """Every pose at least ``step`` metres after the previous kept one (first and last
    kept): the planner's working route."""
    d = route_distance(poses)
    keep = [0]
    for k in range(1, len(d)):
        if d[k] - d[keep[-1]] >= step:
            keep.append(k)
    if keep[-1] != len(d) - 1:
        keep.append(len(d) - 1)
    return np.asarray(poses, float)[keep], np.asarray(times, float)[keep]


def candidate_tags(poses: FloatArray, spacing: float = 5.0, offset: float = 3.0) -> FloatArray:
    """Candidate tag poses (C, 3): every ``spacing`` m along the route, ``offset`` m to its
    left and right, the tag's normal against the direction of travel."""
    poses = np.asarray(poses, float)
    d = route_distance(poses)
    out = []
    for s in np.arange(spacing, d[-1], spacing):
        k = int(np.searchsorted(d, s))
        x, y, yaw = poses[min(k, len(poses) - 1)]
        normal = np.array([-np.sin(yaw), np.cos(yaw)])
        for side in (1.0, -1.0):
            p = np.array([x, y]) + side * offset * normal
            out.append([p[0], p[1], np.arctan2(-np.sin(yaw), -np.cos(yaw))])
    return np.array(out, float).reshape(-1, 3)


def starts_covered(seen: np.ndarray, times: FloatArray, within_s: float) -> np.ndarray:
    """(P,) bool: does some pose from ``k`` on, at most ``within_s`` seconds after it, see a
    landmark (``seen`` (P,) bool)? Times ascending, seconds."""
    seen = np.asarray(seen, bool)
    times = np.asarray(times, float)
    count = np.concatenate([[0], np.cumsum(seen)])  # count[k]: seen poses before k
    last = np.searchsorted(times, times + within_s, side="right")  # first pose too late
    return count[last] > count[np.arange(len(seen))]


def tag_visibility(poses: FloatArray, candidates: FloatArray, sensors: SensorModel) -> np.ndarray:
    """(C, P) bool: candidate tag ``c`` is in the front camera's view, in range and facing it
    at route pose ``p`` (:func:`~semslam.analysis.accuracy.tag_information`)."""
    candidates = np.asarray(candidates, float).reshape(-1, 3)
    return np.array(
        [tag_information(poses, c[None], None, sensors)[1] > 0 for c in candidates], bool
    ).reshape(len(candidates), len(poses))


def seen_often_enough(
    poses: FloatArray, candidates: FloatArray, sensors: SensorModel, minimum: int
) -> np.ndarray:
    """(C,) bool: candidate ``c`` is in view (:func:`tag_visibility`) from at least
    ``minimum`` of ``poses`` (P, 3; x, y in m, yaw in rad, map frame), the route of the drive
    that maps the garage: a tag it never sees is never in the map."""
    return tag_visibility(poses, candidates, sensors).sum(axis=1) >= minimum


def coverage_placement(
    seen: np.ndarray, times: FloatArray, visible: np.ndarray, count: int, within_s: float
) -> list[int]:
    """Up to ``count`` candidates (indices into ``visible`` (C, P)), each round the one that
    adds the most covered starts (:func:`starts_covered`; the first such on a tie), until
    every start is covered or no candidate adds one. ``seen`` (P,): what the route sees
    without them."""
    seen = np.asarray(seen, bool).copy()
    chosen: list[int] = []
    covered = starts_covered(seen, times, within_s).sum()
    while len(chosen) < count and covered < len(seen):
        gains = np.array(
            [starts_covered(seen | v, times, within_s).sum() for v in visible]
        ) - covered
        gains[chosen] = 0
        best = int(np.argmax(gains)) if len(gains) else 0
        if not len(gains) or gains[best] <= 0:
            break
        chosen.append(best)
        seen |= visible[best]
        covered += gains[best]
    return chosen


SETTLED = 1e-9
"""A refiltered route is back on the base filter once no entry of its state differs from
the base's by more than this times the base state's largest entry."""


SIGMA_DIGITS = 6
"""Greedy placement compares worst sigmas to the micrometre (decimals of a metre): worst
sigmas closer than that are a tie, broken by the mean (a candidate that leaves the worst
pose alone moves it by rounding noise only)."""


def _sigmas(infos, poses, times, grade) -> FloatArray:
    return position_sigmas(filter_route(infos, poses, times, grade))


def _sigmas_changed(
    route: RouteFilter,
    base_states: FloatArray,
    base_sigma: FloatArray,
    base_infos: FloatArray,
    changed: np.ndarray,
    added: FloatArray,
) -> FloatArray:
    """Position sigmas (N,) along the route when the information ``added`` (M, 3, 3) joins
    ``base_infos`` (N, 3, 3), which gave ``base_states`` (N, n, n) and ``base_sigma``, at
    the poses ``changed`` (M,) (sorted indices). The filter is run from the first changed
    pose on the base's state and, wherever it is back on the base's (:data:`SETTLED`),
    jumps to the next changed pose: a tag costs the stretches that see it and the
    filter's settling after each, not the whole route (refiltering the whole route per
    candidate made greedy placement grow with the square of the route's length)."""
    n = len(base_states)
    added_at = dict(zip(changed.tolist(), added, strict=True))
    upcoming, k, P = 0, int(changed[0]), None
    at, states = [], []
    while k < n:
        info = base_infos[k] + added_at[k] if k in added_at else base_infos[k]
        if P is None:  # (re)start on the base's state
            P = route.start(info) if k == 0 else route.step(base_states[k - 1], k, info)
        else:
            P = route.step(P, k, info)
        at.append(k)
        states.append(P)
        while upcoming < len(changed) and changed[upcoming] <= k:
            upcoming += 1
        base = base_states[k]
        if np.abs(P - base).max() <= SETTLED * np.abs(base).max():
            if upcoming == len(changed):
                break
            k, P = int(changed[upcoming]), None
        else:
            k += 1
    sigma = base_sigma.copy()
    sigma[at] = position_sigmas(np.array(states))
    return sigma


def _step(count: int, sigma: FloatArray, tag=None) -> PlacementStep:
    return PlacementStep(
        count,
        float(sigma.max()),
        float(np.percentile(sigma, 95)),
        float(sigma.mean()),
        float(np.sort(sigma)[-max(1, int(np.ceil(0.05 * len(sigma)))) :].mean()),
        None if tag is None else tuple(float(v) for v in tag),
    )


def greedy_placement(
    base_infos: FloatArray,
    poses: FloatArray,
    times: FloatArray,
    candidates: FloatArray,
    count: int,
    grade: OdometryGrade,
    sensors: SensorModel | None = None,
) -> list[PlacementStep]:
    """Add ``count`` tags one at a time, each the candidate that minimises the worst
    filtered sigma (to :data:`SIGMA_DIGITS`; then the mean). Step 0 is the route without
    added tags. Each candidate is refiltered only where it changes the filter
    (:func:`_sigmas_changed`): sigmas within 1e-9 m of refiltering the whole route."""
    sensors = sensors or SensorModel()
    route = RouteFilter(poses, times, grade)
    infos = np.array(base_infos, float)
    states = route.states(infos)
    sigma = position_sigmas(states)
    steps = [_step(0, sigma)]
    seen_at, cand_infos = [], []  # each candidate's information where it is seen
    for c in candidates:
        info = _expected_tag_information(poses, c[None], sensors)
        seen_at.append(np.flatnonzero(info.reshape(len(info), -1).any(axis=1)))
        cand_infos.append(info[seen_at[-1]])
    free = list(range(len(candidates)))
    for n in range(1, count + 1):
        best = None
        for c in free:
            if not len(seen_at[c]):
                continue
            trial = _sigmas_changed(route, states, sigma, infos, seen_at[c], cand_infos[c])
            key = (round(float(trial.max()), SIGMA_DIGITS), float(trial.mean()))
            if best is None or key < best[0]:
                best = (key, c)
        if best is None:
            break
        _, c = best
        infos = infos.copy()
        infos[seen_at[c]] += cand_infos[c]
        states = route.states(infos)
        sigma = position_sigmas(states)
        free.remove(c)
        steps.append(_step(n, sigma, candidates[c]))
    return steps


def even_placement(
    base_infos: FloatArray,
    poses: FloatArray,
    times: FloatArray,
    candidates: FloatArray,
    count: int,
    grade: OdometryGrade,
    sensors: SensorModel | None = None,
) -> PlacementStep:
    """``count`` tags spread evenly over the candidates (two per row along the route: one
    side of each row, sides alternating, then the other sides spread evenly; at most all of
    them): the accuracy they give together."""
    rows, count = len(candidates) // 2, max(count, 0)
    first = min(count, rows)
    at = np.linspace(0, rows - 1, first + 2)[1:-1] if first < rows else np.arange(rows)
    chosen = [2 * int(round(a)) + (i % 2) for i, a in enumerate(at)]
    second = min(count - first, rows)
    if second:  # the other side of rows spread over the route
        at = np.linspace(0, rows - 1, second + 2)[1:-1] if second < rows else np.arange(rows)
        chosen += [2 * int(round(a)) + 1 - (int(round(a)) % 2) for a in at]
    return _placed(base_infos, poses, times, candidates[chosen], grade, sensors)


def random_placement(
    base_infos: FloatArray,
    poses: FloatArray,
    times: FloatArray,
    candidates: FloatArray,
    count: int,
    grade: OdometryGrade,
    rng: np.random.Generator,
    sensors: SensorModel | None = None,
) -> PlacementStep:
    """``count`` candidates (C, 3; x, y in m, yaw in rad, map frame) drawn at random
    without replacement (at most all of them): the accuracy they give together."""
    n = min(max(count, 0), len(candidates))
    chosen = rng.choice(len(candidates), size=n, replace=False) if n else []
    return _placed(base_infos, poses, times, candidates[chosen], grade, sensors)


def placement_steps(
    base_infos: FloatArray,
    poses: FloatArray,
    times: FloatArray,
    tags: FloatArray,
    grade: OdometryGrade,
    sensors: SensorModel | None = None,
) -> list[PlacementStep]:
    """The route's accuracy with the first 0, 1, ..., T of ``tags`` (T, 3) added, in order
    (as :func:`greedy_placement` reports its own choices)."""
    tags = np.asarray(tags, float).reshape(-1, 3)
    steps = [
        _placed(base_infos, poses, times, tags[:k], grade, sensors) for k in range(len(tags) + 1)
    ]
    return [steps[0]] + [
        replace(step, tag=tuple(float(v) for v in tag))
        for step, tag in zip(steps[1:], tags, strict=True)
    ]


def _placed(base_infos, poses, times, tags: FloatArray, grade, sensors) -> PlacementStep:
    """The route's accuracy with ``tags`` (T, 3) added to the map's information."""
    infos = np.array(base_infos, float)
    if len(tags):
        infos = infos + _expected_tag_information(poses, tags, sensors or SensorModel())
    return _step(len(tags), _sigmas(infos, poses, times, grade))


def _expected_tag_information(poses: FloatArray, tags: FloatArray, sensors: SensorModel):
    """(P, 3, 3) information of new ``tags`` (T, 3) at each route pose, times the chance they
    are detected, as the map's own tags count (:mod:`semslam.analysis.accuracy`)."""
    return sensors.tag_detection_rate * tag_information(poses, tags, None, sensors)[0]


def placement_spread(steps: Sequence[PlacementStep]) -> dict[str, dict[str, float]]:
    """Median, best (lowest) and worst (highest) of ``worst_m``, ``p95_m`` and
    ``worst5_mean_m`` (m) over several placements of the same number of tags (e.g. random
    draws)."""
    out = {}
    for key in ("worst_m", "p95_m", "worst5_mean_m"):
        v = np.array([getattr(s, key) for s in steps], float)
        out[key] = {"median": float(np.median(v)), "best": float(v.min()), "worst": float(v.max())}
    return out


__all__ = [
    "PlacementStep",
    "candidate_tags",
    "coverage_placement",
    "even_placement",
    "greedy_placement",
    "placement_spread",
    "placement_steps",
    "random_placement",
    "resample_route",
    "route_distance",
    "seen_often_enough",
    "starts_covered",
    "tag_visibility",
]
