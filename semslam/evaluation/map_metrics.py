"""How well a built map agrees with the true one: slot corners, slot IDs, tags, markings.

Pure computation on two :class:`~semslam.types.SemanticMap` values in the
same map frame (metres); :func:`evaluate_map` optionally first aligns the
estimate to the truth with a rigid SE(2) transform. Metrics that have no
sample (no matched slot, no tag...) are NaN, and ``None`` in
:meth:`MapMetrics.to_dict` so that the result is valid JSON.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from semslam.evaluation.alignment import apply_se2, fit_se2, transform_map
from semslam.evaluation.segments import nearest_segments, sample_segments
from semslam.geometry import FloatArray, compose, inverse, wrap_angle
from semslam.types import SemanticMap, Tag

IntArray = NDArray[np.intp]

REVERSED_ORDER = (2, 3, 0, 1)  # the same slot seen from its rear: entrance and rear swapped
REVERSED_FACTOR = 0.5  # the reversed order counts when its mean corner distance is below half
ICP_ITERATIONS = 20
CONFIDENT_LABEL = 0.9  # label_confidence from which a mapped ID counts as confident
MARKING_MATCH_M = 1.0  # m: a mapped line's middle lies at most this far across its true line
MARKING_PARALLEL_DEG = 10.0  # deg: and the two are within this of parallel


@dataclass(frozen=True)
class MapMetrics:
    """Agreement of a map with the true map; lengths in metres, angles in degrees.

    Slot matching: the cost of an (estimated, true) slot pair is the mean
    distance of their four corners compared in order (entrance-left,
    entrance-right, rear-right, rear-left), or in the 180-degree-rotated
    order (2, 3, 0, 1) when that mean is below half the in-order one (a slot
    mapped with entrance and rear swapped). A one-to-one matching minimising
    the total cost (``linear_sum_assignment``) pairs slots whose cost is at
    most ``match_radius_m``.

    Attributes:
        match_radius_m: gate on the mean corner distance of a matched pair.
        merge_radius_m: gate of the wrong-merge test.
        alignment: ``(x, y, yaw_deg)`` of the transform applied to the estimate
            (truth ≈ T * estimate), or None when not aligned (not asked, or
            too little in common to fit it).
        slots_true: slots in the true map.
        slots_true_seen: size of the ``slots_true_seen`` set given, or None.
        slots_mapped: slots in the estimate.
        slots_matched: one-to-one matched pairs.
        slots_reversed: matched pairs that used the rotated corner order.
        duplicate_slots: unmatched estimated slots whose centre lies within
            ``match_radius_m`` of the centre of a matched true slot (a second
            copy of a slot already mapped).
        wrong_merges: estimated slots that are the best candidate (lowest
            pair cost, cost at most ``merge_radius_m``) of two or more true
            slots: one mapped slot standing for several real ones. Counted
            whether the merged slot is matched or not.
        false_slots: unmatched estimated slots that are neither duplicates
            nor wrong merges.
        missed_slots: true slots left unmatched (only those in
            ``slots_true_seen`` when it is given).
        slot_precision: ``slots_matched / slots_mapped``.
        slot_recall: matched true slots / true slots (those seen, when given).
        corner_rmse_m: RMSE of the corner errors of matched slots (4 per pair).
        corner_p95_m: 95th percentile of those corner errors.
        corner_max_m: largest of them.
        corner_nees_mean: mean over the corners of matched slots of the squared
            error in the metric of the corner covariance the map exports
            (``e^T C^-1 e``, 2 degrees of freedom): 2 when the map knows its own
            error, above when it is too sure. Corners whose covariance is not
            positive definite (a map without covariances) are left out.
        corner_nees_median: median of the same (1.39 for a consistent map).
        corner_nees_corners: how many corners they were computed over.
        id_accuracy: fraction of matched slots whose label equals the true
            label; an estimated label None counts as wrong.
        id_labelled: matched slots whose estimated label is not None.
        id_accuracy_labelled: fraction of ``id_labelled`` slots read right.
        id_brier: mean over the ``id_labelled`` slots of (label_confidence -
            right)^2, right 1 or 0: 0 for labels that are right and sure, 0.25
            for confidences of 0.5 throughout; how well the exported label
            confidences tell right labels from wrong ones.
        id_confident: ``id_labelled`` slots with label_confidence >= 0.9
            (``CONFIDENT_LABEL``).
        id_confident_accuracy: fraction of ``id_confident`` slots read right.
        tags_true, tags_mapped: tags in each map.
        tags_matched: one-to-one pairs with the same family and ID (among
            several with one key, the nearest pairs).
        tags_rmse_m: RMSE of the tag centre positions of matched tags.
        tags_yaw_rmse_deg: RMSE of their wrapped yaw differences.
        markings_true, markings_mapped: markings in each map.
        marking_endpoint_median_m: median over the end points of every mapped
            marking of the distance to the nearest true marking segment.
        marking_endpoint_p95_m: 95th percentile of those distances.
        marking_nees_mean: does the map know its lines' error: over the mapped lines that
            carry an ``across_covariance``, the mean of ``e^T C^-1 e``, ``e`` the offsets of
            the line's two ends across the true line it stands for (of the true lines
            within :data:`MARKING_PARALLEL_DEG` of parallel that pass near its middle, the
            one its middle lies nearest across, at most :data:`MARKING_MATCH_M`; a map
            line further off than that is not counted), ``C`` that covariance; 2 for a map
            that knows its lines' error (two degrees of freedom), larger if too sure.
        marking_nees_median: median of the same (1.39 if right).
        marking_nees_lines: how many lines they were computed over.
        alignment_skipped: why no alignment was applied though one was asked for (fewer
            than two distinct matched points); None otherwise.
    """

    match_radius_m: float
    merge_radius_m: float
    alignment: tuple[float, float, float] | None
    slots_true: int
    slots_true_seen: int | None
    slots_mapped: int
    slots_matched: int
    slots_reversed: int
    duplicate_slots: int
    wrong_merges: int
    false_slots: int
    missed_slots: int
    slot_precision: float
    slot_recall: float
    corner_rmse_m: float
    corner_p95_m: float
    corner_max_m: float
    corner_nees_mean: float
    corner_nees_median: float
    corner_nees_corners: int
    id_accuracy: float
    id_labelled: int
    id_accuracy_labelled: float
    id_brier: float
    id_confident: int
    id_confident_accuracy: float
    tags_true: int
    tags_mapped: int
    tags_matched: int
    tags_rmse_m: float
    tags_yaw_rmse_deg: float
    markings_true: int
    markings_mapped: int
    marking_endpoint_median_m: float
    marking_endpoint_p95_m: float
    marking_nees_mean: float
    marking_nees_median: float
    marking_nees_lines: int
    alignment_skipped: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON values in field order; NaN becomes None, ``alignment`` a list."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, tuple):
                value = [float(v) for v in value]
            elif isinstance(value, float) and not math.isfinite(value):
                value = None
            out[f.name] = value
        return out


# --------------------------------------------------------------------------- helpers


def _rmse(errors: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.square(errors)))) if errors.size else math.nan


def _percentile(values: FloatArray, q: float) -> float:
    return float(np.percentile(values, q)) if values.size else math.nan


def _ratio(num: int, den: int) -> float:
    return num / den if den else math.nan


def _corners(semantic_map: SemanticMap) -> FloatArray:
    """(N, 4, 2) slot corners."""
    if not semantic_map.slots:
        return np.zeros((0, 4, 2))
    return np.array([np.asarray(s.corners, dtype=float) for s in semantic_map.slots])


def _candidate_pairs(est: FloatArray, true: FloatArray, radius: float) -> tuple[IntArray, IntArray]:
    """Pairs (i, j) whose centres are within ``radius``: a superset of the pairs with mean
    corner distance within ``radius`` (the centre distance never exceeds it)."""
    if len(est) == 0 or len(true) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    hits = cKDTree(true.mean(axis=1)).query_ball_point(est.mean(axis=1), radius)
    ei = np.repeat(np.arange(len(est)), [len(h) for h in hits]).astype(np.intp)
    tj = np.fromiter((j for h in hits for j in h), dtype=np.intp, count=len(ei))
    return ei, tj


def _pair_costs(est: FloatArray, true: FloatArray, ei: IntArray, tj: IntArray):
    """Mean corner distance of each pair and whether the rotated corner order was used."""
    direct = np.linalg.norm(est[ei] - true[tj], axis=2).mean(axis=1)
    rotated = np.linalg.norm(est[ei][:, REVERSED_ORDER] - true[tj], axis=2).mean(axis=1)
    use_rotated = rotated < REVERSED_FACTOR * direct
    return np.where(use_rotated, rotated, direct), use_rotated


def _assign(n_est: int, ei: IntArray, tj: IntArray, cost: FloatArray) -> IntArray:
    """Indices into the pairs (ei, tj) of a minimum-cost one-to-one matching of the candidate
    pairs, solved per connected component of the candidate graph (small problems)."""
    if len(ei) == 0:
        return np.zeros(0, dtype=np.intp)
    n = n_est + int(tj.max()) + 1
    graph = coo_matrix((np.ones(len(ei)), (ei, n_est + tj)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    comp = labels[ei]
    order = np.argsort(comp, kind="stable")
    bounds = np.flatnonzero(np.diff(comp[order])) + 1
    chosen: list[IntArray] = []
    big = 1.0 + 2.0 * float(cost.max()) * (len(ei) + 1)
    for group in np.split(order, bounds):
        rows, r_inv = np.unique(ei[group], return_inverse=True)
        cols, c_inv = np.unique(tj[group], return_inverse=True)
        matrix = np.full((len(rows), len(cols)), big)
        matrix[r_inv, c_inv] = cost[group]
        pair_of = np.full((len(rows), len(cols)), -1, dtype=np.intp)
        pair_of[r_inv, c_inv] = group
        r, c = _min_cost_assignment(matrix)
        picked = pair_of[r, c]
        chosen.append(picked[picked >= 0])
    return np.concatenate(chosen)


@dataclass(frozen=True)
class _SlotMatch:
    est: IntArray
    true: IntArray
    reversed: NDArray[np.bool_]
    cost: FloatArray


def _match_slots(est: FloatArray, true: FloatArray, radius: float) -> _SlotMatch:
    ei, tj = _candidate_pairs(est, true, radius)
    cost, rev = _pair_costs(est, true, ei, tj)
    keep = cost <= radius
    ei, tj, cost, rev = ei[keep], tj[keep], cost[keep], rev[keep]
    k = _assign(len(est), ei, tj, cost)
    return _SlotMatch(ei[k], tj[k], rev[k], cost[k])


def _ordered(est: FloatArray, match: _SlotMatch) -> FloatArray:
    """Corners of the matched estimated slots (or any (N, 4, ...) per-corner array of the
    estimate) in the order that corresponds to the truth."""
    corners = est[match.est]
    corners[match.reversed] = corners[match.reversed][:, REVERSED_ORDER]
    return corners


def _corner_nees(errors: FloatArray, covariances: FloatArray) -> FloatArray:
    """``e^T C^-1 e`` of each corner error ``errors`` (N, 2) under its covariance (N, 2, 2),
    for the corners whose covariance is finite and positive definite."""
    a, b, d = covariances[:, 0, 0], covariances[:, 0, 1], covariances[:, 1, 1]
    det = a * d - b * b
    usable = np.isfinite(det) & (a > 0) & (det > 1e-18 * np.maximum(a * d, 1e-300))
    ex, ey = errors[usable, 0], errors[usable, 1]
    return (d[usable] * ex * ex - 2 * b[usable] * ex * ey + a[usable] * ey * ey) / det[usable]


def _match_tags(est: Sequence[Tag], true: Sequence[Tag]) -> list[tuple[int, int]]:
    """One-to-one (estimated, true) index pairs with equal family and ID; among several
    tags with one key, the pairing of least total position distance."""
    groups: dict[tuple[str, int], tuple[list[int], list[int]]] = {}
    for i, t in enumerate(est):
        groups.setdefault((str(t.family), int(t.tag_id)), ([], []))[0].append(i)
    for j, t in enumerate(true):
        key = (str(t.family), int(t.tag_id))
        if key in groups:
            groups[key][1].append(j)
    pairs: list[tuple[int, int]] = []
    for ei, tj in groups.values():
        if not tj:
            continue
        a = np.array([est[i].mTt[:2] for i in ei], dtype=float)
        b = np.array([true[j].mTt[:2] for j in tj], dtype=float)
        r, c = _min_cost_assignment(np.linalg.norm(a[:, None] - b[None], axis=2))
        pairs.extend((ei[x], tj[y]) for x, y in zip(r, c, strict=True))
    return sorted(pairs)


def point_segment_distances(points: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance (metres) from each point to the nearest of the segments ``a[k]``-``b[k]``
    (:func:`~semslam.evaluation.segments.nearest_segments`: near linear in points and
    segments).

    Args:
        points: (P, 2) points.
        a, b: (S, 2) segment end points, S >= 1; a zero-length segment is a point.

    Returns:
        (P,) distances.
    """
    return nearest_segments(points, a, b)[0]


# --------------------------------------------------------------------------- alignment


def _initial_guess(estimate: SemanticMap, truth: SemanticMap, tag_pairs) -> FloatArray:
    """A first transform from what matches by name: tags by ID, slots by a label unique in
    both maps; one tag alone gives a pose through its yaw; otherwise identity."""
    src = [estimate.tags[i].mTt[:2] for i, _ in tag_pairs]
    dst = [truth.tags[j].mTt[:2] for _, j in tag_pairs]
    if len(tag_pairs) < 2:
        est_labels = _unique_labels(estimate)
        for label, j in _unique_labels(truth).items():
            if label in est_labels:
                src.extend(estimate.slots[est_labels[label]].corners)
                dst.extend(truth.slots[j].corners)
    if len(src) >= 2:
        return fit_se2(np.array(src), np.array(dst))
    if tag_pairs:
        i, j = tag_pairs[0]
        return compose(truth.tags[j].mTt, inverse(estimate.tags[i].mTt))
    return np.zeros(3)


def _unique_labels(semantic_map: SemanticMap) -> dict[str, int]:
    counts: dict[str, int] = {}
    for s in semantic_map.slots:
        if s.label is not None:
            counts[s.label] = counts.get(s.label, 0) + 1
    return {
        s.label: k
        for k, s in enumerate(semantic_map.slots)
        if s.label is not None and counts[s.label] == 1
    }


def fit_map_alignment(
    estimate: SemanticMap, truth: SemanticMap, radius: float = 3.0
) -> FloatArray | None:
    """The rigid transform ``T`` (x, y, yaw) with truth ≈ T * estimate, or None.

    Starts from tags matched by family and ID (or labels, see
    ``_initial_guess``), then alternates: match slots one-to-one by mean
    corner distance within ``radius`` metres after applying ``T``, refit
    ``T`` by :func:`fit_se2` over the matched corners and tag centres, until
    ``T`` stops changing. None when fewer than two distinct points match.
    """
    est_c, true_c = _corners(estimate), _corners(truth)
    tag_pairs = _match_tags(estimate.tags, truth.tags)
    tag_src = np.array([estimate.tags[i].mTt[:2] for i, _ in tag_pairs]).reshape(-1, 2)
    tag_dst = np.array([truth.tags[j].mTt[:2] for _, j in tag_pairs]).reshape(-1, 2)
    T = _initial_guess(estimate, truth, tag_pairs)
    fitted: FloatArray | None = None
    for _ in range(ICP_ITERATIONS):
        moved = apply_se2(T, est_c.reshape(-1, 2)).reshape(-1, 4, 2)
        match = _match_slots(moved, true_c, radius)
        src = np.concatenate([_ordered(est_c, match).reshape(-1, 2), tag_src])
        dst = np.concatenate([true_c[match.true].reshape(-1, 2), tag_dst])
        if len(src) < 2 or np.ptp(src, axis=0).max() <= 0:
            return fitted
        new = fit_se2(src, dst)
        converged = fitted is not None and np.allclose(new, T, rtol=0.0, atol=1e-12)
        T = fitted = new
        if converged:
            break
    return fitted


# --------------------------------------------------------------------------- evaluation


def evaluate_map(
    estimate: SemanticMap,
    truth: SemanticMap,
    match_radius: float = 1.0,
    align: bool = False,
    *,
    merge_radius: float = 2.0,
    align_radius: float = 3.0,
    slots_true_seen: Collection[int] | None = None,
) -> MapMetrics:
    """Compare a built map with the true map (see :class:`MapMetrics` for every metric).

    Args:
        estimate: the map under test, map frame, metres.
        truth: the true map in the same frame (unless ``align``).
        match_radius: largest mean corner distance of a matched slot pair, metres.
        align: first fit a rigid SE(2) transform of the estimate onto the truth
            (:func:`fit_map_alignment` with ``align_radius``) and apply it.
        merge_radius: gate of the wrong-merge test, metres; the default 2.0
            lies above half the smallest slot pitch (2.4 m), so a slot averaged
            from two neighbours counts, and below the pitch, so a correct
            slot is never taken for its missing neighbour.
        align_radius: gate of the slot matching while aligning, metres.
        slots_true_seen: IDs of the true slots the drive saw; when given,
            ``missed_slots`` and ``slot_recall`` count only those.

    Raises:
        ValueError: a radius is not a positive number, or ``slots_true_seen``
            names a slot ID the truth does not have.
    """
    for name, value in (
        ("match_radius", match_radius),
        ("merge_radius", merge_radius),
        ("align_radius", align_radius),
    ):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"evaluate_map: {name} must be a positive number, got {value}")
    seen_mask = np.ones(len(truth.slots), dtype=bool)
    if slots_true_seen is not None:
        ids = np.array([s.id for s in truth.slots], dtype=np.int64)
        seen = {int(i) for i in slots_true_seen}
        unknown = sorted(seen - set(ids.tolist()))
        if unknown:
            raise ValueError(f"evaluate_map: slots_true_seen has IDs not in the truth: {unknown}")
        seen_mask = np.isin(ids, list(seen))

    alignment, skipped = None, None
    if align:
        T = fit_map_alignment(estimate, truth, align_radius)
        if T is not None:
            estimate = transform_map(T, estimate)
            alignment = (float(T[0]), float(T[1]), math.degrees(float(T[2])))
        else:
            skipped = "fewer than two distinct matched points: the map is not aligned"

    slots = _slot_metrics(estimate, truth, match_radius, merge_radius, seen_mask)
    tags = _tag_metrics(estimate, truth)
    markings = _marking_metrics(estimate, truth)
    return MapMetrics(
        match_radius_m=float(match_radius),
        merge_radius_m=float(merge_radius),
        alignment=alignment,
        slots_true_seen=None if slots_true_seen is None else int(seen_mask.sum()),
        **slots,
        **tags,
        **markings,
        alignment_skipped=skipped,
    )


def _slot_metrics(estimate, truth, match_radius, merge_radius, seen_mask) -> dict[str, Any]:
    est_c, true_c = _corners(estimate), _corners(truth)
    match = _match_slots(est_c, true_c, match_radius)
    offsets = _ordered(est_c, match) - true_c[match.true]
    errors = np.linalg.norm(offsets, axis=2).ravel()
    covariances = np.array([np.asarray(s.corner_covariances, dtype=float)
                            for s in estimate.slots]).reshape(len(est_c), 4, 2, 2)
    nees = _corner_nees(offsets.reshape(-1, 2), _ordered(covariances, match).reshape(-1, 2, 2))

    matched_est = np.zeros(len(est_c), dtype=bool)
    matched_est[match.est] = True
    matched_true = np.zeros(len(true_c), dtype=bool)
    matched_true[match.true] = True

    duplicate = np.zeros(len(est_c), dtype=bool)
    unmatched = np.flatnonzero(~matched_est)
    if len(match.true) and len(unmatched):
        tree = cKDTree(true_c[match.true].mean(axis=1))
        dist, _ = tree.query(est_c[unmatched].mean(axis=1))
        duplicate[unmatched] = dist <= match_radius

    # Wrong merges: the best estimated candidate of each true slot, within merge_radius.
    ei, tj = _candidate_pairs(est_c, true_c, merge_radius)
    cost, _ = _pair_costs(est_c, true_c, ei, tj)
    keep = cost <= merge_radius
    ei, tj, cost = ei[keep], tj[keep], cost[keep]
    order = np.lexsort((cost, tj))
    first = order[np.r_[True, tj[order][1:] != tj[order][:-1]]] if len(order) else order
    best_est, n_best = np.unique(ei[first], return_counts=True)
    merged = np.zeros(len(est_c), dtype=bool)
    merged[best_est[n_best >= 2]] = True

    correct = [
        estimate.slots[i].label is not None and estimate.slots[i].label == truth.slots[j].label
        for i, j in zip(match.est, match.true, strict=True)
    ]
    labelled = [estimate.slots[i].label is not None for i in match.est]
    confidence = np.array([estimate.slots[i].label_confidence for i in match.est], dtype=float)
    mask = np.array(labelled, dtype=bool)
    right, confidence = np.array(correct, dtype=float)[mask], confidence[mask]
    confident = confidence >= CONFIDENT_LABEL
    n_matched = len(match.est)
    return {
        "slots_true": len(true_c),
        "slots_mapped": len(est_c),
        "slots_matched": n_matched,
        "slots_reversed": int(match.reversed.sum()),
        "duplicate_slots": int(duplicate.sum()),
        "wrong_merges": int(merged.sum()),
        "false_slots": int((~matched_est & ~duplicate & ~merged).sum()),
        "missed_slots": int((seen_mask & ~matched_true).sum()),
        "slot_precision": _ratio(n_matched, len(est_c)),
        "slot_recall": _ratio(int((seen_mask & matched_true).sum()), int(seen_mask.sum())),
        "corner_rmse_m": _rmse(errors),
        "corner_p95_m": _percentile(errors, 95.0),
        "corner_max_m": float(errors.max()) if errors.size else math.nan,
        "corner_nees_mean": float(nees.mean()) if nees.size else math.nan,
        "corner_nees_median": float(np.median(nees)) if nees.size else math.nan,
        "corner_nees_corners": int(nees.size),
        "id_accuracy": _ratio(sum(correct), n_matched),
        "id_labelled": sum(labelled),
        "id_accuracy_labelled": _ratio(sum(correct), sum(labelled)),
        "id_brier": float(np.mean((confidence - right) ** 2)) if right.size else math.nan,
        "id_confident": int(confident.sum()),
        "id_confident_accuracy": _ratio(int(right[confident].sum()), int(confident.sum())),
    }


def _tag_metrics(estimate: SemanticMap, truth: SemanticMap) -> dict[str, Any]:
    pairs = _match_tags(estimate.tags, truth.tags)
    est = np.array([estimate.tags[i].mTt for i, _ in pairs], dtype=float).reshape(-1, 3)
    true = np.array([truth.tags[j].mTt for _, j in pairs], dtype=float).reshape(-1, 3)
    yaw_err = np.degrees(np.asarray(wrap_angle(est[:, 2] - true[:, 2]), dtype=float))
    return {
        "tags_true": len(truth.tags),
        "tags_mapped": len(estimate.tags),
        "tags_matched": len(pairs),
        "tags_rmse_m": _rmse(np.linalg.norm(est[:, :2] - true[:, :2], axis=1)),
        "tags_yaw_rmse_deg": _rmse(yaw_err),
    }


def _marking_metrics(estimate: SemanticMap, truth: SemanticMap) -> dict[str, Any]:
    dist = np.zeros(0)
    if estimate.markings and truth.markings:
        ends = np.array([p for m in estimate.markings for p in (m.a, m.b)], dtype=float)
        a = np.array([m.a for m in truth.markings], dtype=float)
        b = np.array([m.b for m in truth.markings], dtype=float)
        dist = point_segment_distances(ends, a, b)
    nees = _marking_nees(estimate, truth)
    return {
        "markings_true": len(truth.markings),
        "markings_mapped": len(estimate.markings),
        "marking_endpoint_median_m": _percentile(dist, 50.0),
        "marking_endpoint_p95_m": _percentile(dist, 95.0),
        "marking_nees_mean": float(nees.mean()) if nees.size else math.nan,
        "marking_nees_median": float(np.median(nees)) if nees.size else math.nan,
        "marking_nees_lines": int(nees.size),
    }


def _marking_nees(estimate: SemanticMap, truth: SemanticMap) -> FloatArray:
    """``e^T C^-1 e`` of each mapped line with an ``across_covariance`` ``C`` that has a true
    line to stand for (see :class:`MapMetrics`), ``e`` its ends' offsets across that line."""
    lines = [m for m in estimate.markings if m.across_covariance is not None]
    if not lines or not truth.markings:
        return np.zeros(0)
    a = np.array([m.a for m in truth.markings], dtype=float)
    b = np.array([m.b for m in truth.markings], dtype=float)
    u = (b - a) / np.maximum(np.hypot(*(b - a).T), 1e-12)[:, None]
    n = u @ np.array([[0.0, 1.0], [-1.0, 0.0]])  # (T, 2): (-u_y, u_x)
    samples, owner = sample_segments(a, b, MARKING_MATCH_M)
    tree = cKDTree(samples)
    ends = np.array([[m.a, m.b] for m in lines], dtype=float)  # (L, 2, 2)
    own_u = ends[:, 1] - ends[:, 0]
    own_u /= np.maximum(np.hypot(*own_u.T), 1e-12)[:, None]
    near = tree.query_ball_point(ends.mean(axis=1), 1.5 * MARKING_MATCH_M)
    sin_parallel = math.sin(math.radians(MARKING_PARALLEL_DEG))
    out = []
    for i, found in enumerate(near):
        candidates = np.unique(owner[np.asarray(found, dtype=np.intp)])
        candidates = candidates[np.abs(n[candidates] @ own_u[i]) < sin_parallel]
        if not len(candidates):
            continue
        offsets = (ends[i][None] - a[candidates][:, None]) @ n[candidates][..., None]  # (C, 2, 1)
        middle = np.abs(offsets[:, :, 0].mean(axis=1))
        j = int(np.argmin(middle))
        if middle[j] > MARKING_MATCH_M:
            continue
        e = offsets[j, :, 0]
        C = np.asarray(lines[i].across_covariance, dtype=float)
        if np.linalg.det(C) <= 0.0:
            continue  # no spread to measure against
        out.append(float(e @ np.linalg.solve(C, e)))
    return np.array(out)


def _min_cost_assignment(cost: FloatArray) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Rows and columns of the minimum-cost assignment (scipy's ``linear_sum_assignment``).

    Imported here, not at the top: ``scipy.optimize`` takes about half a second to
    import, and the mapper and localizer, which load this package for ``fit_se2``, never
    assign."""
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment(cost)
