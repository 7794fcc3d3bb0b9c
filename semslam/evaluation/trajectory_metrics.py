"""How well an estimated trajectory (the localizer's) follows the true one.

Pure computation on arrays: poses ``(x, y, yaw)`` in the map frame (metres,
radians), times in seconds. The truth is interpolated at the estimate times
(linearly on x and y, along the shorter arc on yaw). Reported per
:func:`evaluate_trajectory`:

- absolute errors (ATE on the position, yaw error), optionally after the best
  rigid SE(2) fit of the estimated positions onto the true ones;
- relative pose errors (RPE) over a fixed time step of 1 s;
- Houben's split of the position error into a part parallel and a part
  orthogonal to the nearest painted marking (or, without markings, to the
  true heading: along-track and cross-track);
- the NEES ``e^T P^-1 e`` of the error against the stated covariance: 3 on
  average for a consistent 3-DOF estimator.

Every value is a plain Python float or int, ``None`` where undefined.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from semslam.evaluation.alignment import fit_se2
from semslam.evaluation.segments import nearest_segments
from semslam.geometry import FloatArray, rotation, wrap_angle
from semslam.types import SemanticMap

RPE_DELTA_S = 1.0  # time step of the relative pose error, seconds
CHI2_3DOF_95 = 7.814727903251178  # scipy.stats.chi2.ppf(0.95, 3)
NOT_LOCALIZED = ("lost", "initializing")  # statuses whose frames are not scored
_TIME_EPS_S = 1e-9  # rounding slack on the RPE time step
_MIN_SEGMENT_M = 1e-9  # shorter segments have no direction and are dropped


# --------------------------------------------------------------------------- helpers


def _rmse(values: FloatArray) -> float | None:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else None


def _percentile(values: FloatArray, q: float) -> float | None:
    return float(np.percentile(values, q)) if values.size else None


def _mean(values: FloatArray) -> float | None:
    return float(np.mean(values)) if values.size else None


def _std(values: FloatArray) -> float | None:
    """Population standard deviation (ddof 0)."""
    return float(np.std(values)) if values.size else None


def _relative(aTb: FloatArray, aTc: FloatArray) -> FloatArray:
    """Row-wise ``bTc = inverse(aTb) * aTc`` for (N, 3) pose arrays."""
    d = aTc[:, :2] - aTb[:, :2]
    c, s = np.cos(aTb[:, 2]), np.sin(aTb[:, 2])
    return np.column_stack(
        [c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap_angle(aTc[:, 2] - aTb[:, 2])]
    )


def _check_poses(t: FloatArray, poses: FloatArray, what: str) -> None:
    if t.ndim != 1 or poses.shape != (t.shape[0], 3):
        raise ValueError(
            f"evaluate_trajectory: {what} times must be (N,) and poses (N, 3), "
            f"got {t.shape} and {poses.shape}"
        )
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(poses))):
        raise ValueError(f"evaluate_trajectory: {what} has NaN or infinite values")
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"evaluate_trajectory: {what} times must be strictly increasing")


# --------------------------------------------------------------------------- truth at given times


def interpolate_poses(
    truth_t: ArrayLike, truth_poses: ArrayLike, t: ArrayLike, max_time_gap: float = 0.05
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The true poses at times ``t``, and which times have one.

    Between two true samples x and y are interpolated linearly and yaw along
    the shorter arc. A time has a true pose when it lies within
    ``[truth_t[0], truth_t[-1]]`` and at most ``max_time_gap`` seconds from
    the nearest true sample.

    Args:
        truth_t: (M,) strictly increasing times of the truth, seconds, M >= 1.
        truth_poses: (M, 3) true poses ``(x, y, yaw)``, map frame.
        t: (N,) query times, seconds.
        max_time_gap: largest distance to the nearest true sample, seconds.

    Returns:
        ``(poses, matched)``: (N, 3) interpolated poses (yaw wrapped to
        (-pi, pi]; outside the span, the first or last sample) and (N,)
        booleans, True where the time has a true pose.
    """
    tt = np.asarray(truth_t, dtype=float)
    tp = np.asarray(truth_poses, dtype=float)
    q = np.asarray(t, dtype=float)
    m = tt.shape[0]
    if m == 1:
        matched = q == tt[0]
        return np.repeat(tp, len(q), axis=0), matched
    i1 = np.clip(np.searchsorted(tt, q, side="right"), 1, m - 1)
    i0 = i1 - 1
    s = np.clip((q - tt[i0]) / (tt[i1] - tt[i0]), 0.0, 1.0)
    xy = tp[i0, :2] + s[:, None] * (tp[i1, :2] - tp[i0, :2])
    yaw = np.asarray(wrap_angle(tp[i0, 2] + s * wrap_angle(tp[i1, 2] - tp[i0, 2])), dtype=float)
    gap = np.minimum(np.abs(q - tt[i0]), np.abs(tt[i1] - q))
    matched = (q >= tt[0]) & (q <= tt[-1]) & (gap <= max_time_gap)
    return np.column_stack([xy, yaw]), matched


# --------------------------------------------------------------------------- segments


def map_segments(semantic_map: SemanticMap) -> FloatArray:
    """The painted lines of a map as (M, 2, 2) segments ``(a, b)``, map frame, metres.

    The map's markings when it has any; otherwise the four sides of every
    slot (corner k to corner k+1; the entrance side is included although it
    is often not painted). (0, 2, 2) for a map with neither.
    """
    if semantic_map.markings:
        return np.array(
            [
                [np.asarray(m.a, dtype=float), np.asarray(m.b, dtype=float)]
                for m in semantic_map.markings
            ]
        ).reshape(-1, 2, 2)
    if semantic_map.slots:
        corners = np.array([np.asarray(s.corners, dtype=float) for s in semantic_map.slots])
        return np.stack([corners, np.roll(corners, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    return np.zeros((0, 2, 2))


def nearest_segment(points: ArrayLike, segments: ArrayLike) -> NDArray[np.intp]:
    """Index of the segment nearest to each point (exact; near linear in points and
    segments, :func:`~semslam.evaluation.segments.nearest_segments`).

    Args:
        points: (P, 2) points, metres.
        segments: (S, 2, 2) segments ``(a, b)``, S >= 1.

    Returns:
        (P,) indices into ``segments``.
    """
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    return nearest_segments(points, seg[:, 0], seg[:, 1])[1]


# --------------------------------------------------------------------------- evaluation


def evaluate_trajectory(
    t: ArrayLike,
    poses: ArrayLike,
    truth_t: ArrayLike,
    truth_poses: ArrayLike,
    covariances: ArrayLike | None = None,
    status: Sequence[str] | None = None,
    markings: ArrayLike | None = None,
    align: bool = False,
    max_time_gap: float = 0.05,
) -> dict[str, Any]:
    """Score an estimated trajectory against the true one.

    Frames: ``frames`` counts every estimate; ``frames_unmatched`` those with
    no true pose (outside the truth's time span or farther than
    ``max_time_gap`` from every true sample); ``frames_lost`` those whose
    status is ``lost`` or ``initializing`` (whether matched or not: the two
    counts may overlap); ``frames_evaluated`` those that are neither, the
    only ones in the statistics below.

    The error of a frame is ``e = (dx, dy, dyaw)``: estimate minus truth in
    the map frame, ``dyaw`` wrapped to (-pi, pi].

    Args:
        t: (N,) strictly increasing estimate times, seconds.
        poses: (N, 3) estimated ``(x, y, yaw)`` in the map frame, metres, radians.
        truth_t: (M,) strictly increasing true times, seconds, M >= 1.
        truth_poses: (M, 3) true poses in the map frame.
        covariances: (N, 3, 3) covariance of each estimate (m^2, m*rad,
            rad^2), or None (NEES is then None).
        status: N localizer statuses (:data:`semslam.io.TRACK_STATUSES`), or
            None for all scored.
        markings: (K, 2, 2) painted segments ``(a, b)`` in the map frame
            (see :func:`map_segments`), or None / empty to split the error
            along the true heading instead.
        align: first move the estimate by the least-squares SE(2) transform
            of its evaluated positions onto the true ones (:func:`fit_se2`);
            covariances are rotated with it.
        max_time_gap: largest distance, seconds, from an estimate time to
            the nearest true sample.

    Returns:
        A JSON-ready dict:

        - ``frames``, ``frames_evaluated``, ``frames_lost``,
          ``frames_unmatched``: counts as above; ``status_counts``: frames
          per status (absent without ``status``).
        - ``alignment``: ``[x, y, yaw_deg]`` of the transform applied (truth
          ≈ T * estimate), or None (not asked, or fewer than two distinct
          evaluated positions: then ``alignment_skipped`` says so).
        - ``ate_rmse_m``, ``ate_mean_m``, ``ate_median_m``, ``ate_p95_m``,
          ``ate_max_m``: of the position error ``|(dx, dy)|``.
        - ``yaw_rmse_deg``, ``yaw_p95_deg``, ``yaw_max_deg``: of ``|dyaw|``.
        - ``rpe_delta_s`` (1.0), ``rpe_pairs``, ``rpe_trans_rmse_m``,
          ``rpe_yaw_rmse_deg``: relative pose error ``inverse(G_i^-1 G_j) *
          (E_i^-1 E_j)`` over pairs of evaluated frames i < j whose time
          step is within ``max_time_gap`` of 1 s (j: the evaluated frame
          nearest to ``t_i + 1``); a rigid offset of the whole estimate
          leaves it unchanged.
        - ``split_reference``: ``"markings"`` or ``"heading"``;
          ``parallel_mean_m``, ``parallel_std_m``, ``orthogonal_mean_m``,
          ``orthogonal_std_m``: mean and population std of ``|e·d|`` and
          ``|e·n|``, ``d`` the unit direction of the segment nearest to the
          TRUE position (or the true heading), ``n`` its normal.
        - ``nees_mean``: mean of ``e^T P^-1 e`` over evaluated frames whose
          covariance is positive definite (``nees_frames`` of them);
          ``nees_within_95``: the fraction below the chi-square(3) 95%
          quantile (7.81; 0.95 when consistent); ``nees_position_mean`` and
          ``nees_heading_mean``: the same of the position alone (its 2 x 2 block;
          2 when consistent) and the heading alone (1), to tell which part of the
          covariance is too small or too large. None without covariances.

    Raises:
        ValueError: shapes disagree, times are not strictly increasing, a
            pose is not finite, the truth is empty or ``max_time_gap`` < 0.
    """
    t = np.asarray(t, dtype=float)
    est = np.asarray(poses, dtype=float).copy()
    truth_t = np.asarray(truth_t, dtype=float)
    truth_poses = np.asarray(truth_poses, dtype=float)
    _check_poses(t, est, "estimate")
    _check_poses(truth_t, truth_poses, "truth")
    if truth_t.shape[0] == 0:
        raise ValueError("evaluate_trajectory: the truth has no poses")
    if not max_time_gap >= 0:
        raise ValueError(f"evaluate_trajectory: max_time_gap must be >= 0, got {max_time_gap}")
    n = t.shape[0]
    covs = None if covariances is None else np.asarray(covariances, dtype=float)
    if covs is not None and covs.shape != (n, 3, 3):
        raise ValueError(f"evaluate_trajectory: covariances must be ({n}, 3, 3), got {covs.shape}")
    if status is not None and len(status) != n:
        raise ValueError(f"evaluate_trajectory: {len(status)} statuses for {n} poses")

    truth, matched = interpolate_poses(truth_t, truth_poses, t, max_time_gap)
    lost = np.zeros(n, dtype=bool) if status is None else np.isin(np.asarray(status), NOT_LOCALIZED)
    keep = matched & ~lost

    alignment = None
    if align and keep.sum() >= 2 and np.ptp(est[keep, :2], axis=0).max() > 0:
        T = fit_se2(est[keep, :2], truth[keep, :2])
        R = rotation(float(T[2]))
        est[:, :2] = est[:, :2] @ R.T + T[:2]
        est[:, 2] = np.asarray(wrap_angle(est[:, 2] + T[2]), dtype=float)
        if covs is not None:
            R3 = np.eye(3)
            R3[:2, :2] = R
            covs = np.einsum("ij,njk,lk->nil", R3, covs, R3)
        alignment = [float(T[0]), float(T[1]), math.degrees(float(T[2]))]

    E, G = est[keep], truth[keep]
    e = np.column_stack([E[:, :2] - G[:, :2], wrap_angle(E[:, 2] - G[:, 2])]).reshape(-1, 3)
    ate = np.hypot(e[:, 0], e[:, 1])
    yaw_deg = np.degrees(np.abs(e[:, 2]))

    out: dict[str, Any] = {
        "frames": int(n),
        "frames_evaluated": int(keep.sum()),
        "frames_lost": int(lost.sum()),
        "frames_unmatched": int((~matched).sum()),
    }
    if status is not None:
        names, counts = np.unique(np.asarray(status, dtype=str), return_counts=True)
        out["status_counts"] = {str(k): int(c) for k, c in zip(names, counts, strict=True)}
    out["alignment"] = alignment
    if align and alignment is None:  # asked for, but nothing to fit a rotation to
        out["alignment_skipped"] = (
            "fewer than two distinct evaluated positions: the errors are not aligned"
        )
    out |= {
        "max_time_gap_s": float(max_time_gap),
        "ate_rmse_m": _rmse(ate),
        "ate_mean_m": _mean(ate),
        "ate_median_m": _percentile(ate, 50.0),
        "ate_p95_m": _percentile(ate, 95.0),
        "ate_max_m": float(ate.max()) if ate.size else None,
        "yaw_rmse_deg": _rmse(yaw_deg),
        "yaw_p95_deg": _percentile(yaw_deg, 95.0),
        "yaw_max_deg": float(yaw_deg.max()) if yaw_deg.size else None,
    }
    out |= _rpe(t[keep], E, G, max_time_gap)
    out |= _split(e[:, :2], G, markings)
    out |= _nees(e, None if covs is None else covs[keep])
    return out


def _rpe(t: FloatArray, E: FloatArray, G: FloatArray, tolerance: float) -> dict[str, Any]:
    """Relative pose errors over pairs (i, j), j the frame nearest to ``t_i + RPE_DELTA_S``."""
    if len(t) >= 2:
        target = t + RPE_DELTA_S
        j1 = np.clip(np.searchsorted(t, target), 1, len(t) - 1)
        j0 = j1 - 1
        j = np.where(np.abs(t[j0] - target) <= np.abs(t[j1] - target), j0, j1)
        i = np.arange(len(t))
        ok = (j > i) & (np.abs(t[j] - target) <= tolerance + _TIME_EPS_S)
        i, j = i[ok], j[ok]
    else:
        i = j = np.zeros(0, dtype=np.intp)
    rel = _relative(_relative(G[i], G[j]), _relative(E[i], E[j])).reshape(-1, 3)
    return {
        "rpe_delta_s": RPE_DELTA_S,
        "rpe_pairs": int(len(i)),
        "rpe_trans_rmse_m": _rmse(np.hypot(rel[:, 0], rel[:, 1])),
        "rpe_yaw_rmse_deg": _rmse(np.degrees(rel[:, 2])),
    }


def _split(exy: FloatArray, G: FloatArray, markings: ArrayLike | None) -> dict[str, Any]:
    """Houben's parallel / orthogonal split of the position errors ``exy`` (K, 2)."""
    seg = np.zeros((0, 2, 2)) if markings is None else np.asarray(markings, dtype=float)
    seg = seg.reshape(-1, 2, 2)
    direction = seg[:, 1] - seg[:, 0]
    length = np.hypot(direction[:, 0], direction[:, 1])
    usable = length > _MIN_SEGMENT_M
    if usable.any():
        reference = "markings"
        unit = direction[usable] / length[usable, None]
        d = unit[nearest_segment(G[:, :2], seg[usable])] if len(G) else np.zeros((0, 2))
    else:
        reference = "heading"
        d = np.column_stack([np.cos(G[:, 2]), np.sin(G[:, 2])]).reshape(-1, 2)
    parallel = np.abs(np.einsum("ij,ij->i", exy, d))
    orthogonal = np.abs(exy[:, 1] * d[:, 0] - exy[:, 0] * d[:, 1])  # e · (-d_y, d_x)
    return {
        "split_reference": reference,
        "parallel_mean_m": _mean(parallel),
        "parallel_std_m": _std(parallel),
        "orthogonal_mean_m": _mean(orthogonal),
        "orthogonal_std_m": _std(orthogonal),
    }


def _nees(e: FloatArray, covs: FloatArray | None) -> dict[str, Any]:
    """Normalised estimation error squared against positive definite covariances."""
    keys = ("nees_mean", "nees_within_95", "nees_frames", "nees_position_mean",
            "nees_heading_mean")
    if covs is None:
        return dict.fromkeys(keys)
    sym = 0.5 * covs + 0.5 * np.swapaxes(covs, 1, 2)  # halves first: 1.7e308 + 1.7e308 overflows
    finite = np.all(np.isfinite(sym), axis=(1, 2))
    pd = np.zeros(len(sym), dtype=bool)
    if finite.any():
        pd[finite] = np.linalg.eigvalsh(sym[finite]).min(axis=1) > 0
    e, sym = e[pd], sym[pd]
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(sym, e[..., None])[..., 0])
    position = np.einsum("ni,ni->n", e[:, :2], np.linalg.solve(sym[:, :2, :2],
                                                               e[:, :2, None])[..., 0])
    heading = e[:, 2] ** 2 / sym[:, 2, 2]
    return dict(zip(keys, (
        _mean(nees),
        float(np.mean(nees < CHI2_3DOF_95)) if nees.size else None,
        int(pd.sum()),
        _mean(position),
        _mean(heading),
    ), strict=True))
