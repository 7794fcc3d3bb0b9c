"""Slot corner covariances when every sighting of a slot shares part of its error.

A detector can misplace one slot's corners in the same way in every frame that sees it (the
marking-point CNN's bias for that slot's paint; the depth prior at its rear), and more frames
do not average that away. The mapper therefore weights such detections with a large
``corner_sigma`` ``w``, so that fifty frames taken as independent do not pull the map about;
but the marginals of the graph it solves then say so too, and the map claims corners about
twice as uncertain as they are (the images demo: corner NEES 0.4 where 2 is honest).

Where the detections declare their error model (:class:`~semslam.types.SlotObservation`:
each frame's own error ``o`` per corner, and an error ``s`` per corner that every sighting
of the slot shares), this module gives the covariance of the estimate the mapper actually
made, under that model: the sandwich ``H^-1 M H^-1`` of a weighted least-squares estimate,
with ``H = A^T W A`` the information the estimate was solved with and ``M = A^T W Sigma W
A`` the spread of the weighted residuals it would see, where ``Sigma`` couples the sightings
of one slot by ``s^2`` (M-estimation's "sandwich"; the marginals of the graph are the case
``Sigma = W^-1``). Every other factor (odometry, tags, lines, slot shapes) enters both with
its own declared noise. A sighting on the null hypothesis at the solution weighs nothing in
the estimate and is left out.

Only slot corners get these covariances; tags and lines keep the graph's marginals.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from semslam.mapping.factors import slot_observation_residual
from semslam.types import SlotObservation

MAX_UNKNOWNS = 12_000
"""The largest graph (tangent dimensions) whose slot covariances are computed here: the
information matrix is factored sparse (a minimum-degree order keeps the factor near the
matrix's own size), and each mapped slot then costs eight solves with it (`garage`: 4,500
unknowns and 184 slots, about 2 s on the 2-core machine). A larger map keeps the graph's
marginals."""


@dataclass(frozen=True)
class SlotSightingFactor:
    """One slot-observation factor of the mapper's graph.

    Attributes:
        index: the factor's index in the graph.
        keyframe: the keyframe that saw the slot.
        landmark: the slot landmark whose corners it observes at the solution (None: on the
            null hypothesis, or not attached).
        observation: the (fused) detection.
        sigma: the corner sigma the factor was weighted with, m (``corner_sigma`` floored and
            divided by the square root of the detection's confidence).
    """

    index: int
    keyframe: int
    landmark: int | None
    observation: SlotObservation
    sigma: float


def has_shared_error(observation: SlotObservation) -> bool:
    """Whether a detection declares an error model apart from its ``corner_sigma``."""
    return observation.corner_sigma_shared is not None or observation.corner_sigma_own is not None


def own_sigma(factor: SlotSightingFactor) -> np.ndarray:
    """Per corner (4,), the sigma of a sighting's own error, m: as the detection declares it
    (measured over detections of every confidence, so not scaled by this one's, as its
    weight is), or, undeclared, its weight."""
    own = factor.observation.corner_sigma_own
    return np.full(4, factor.sigma) if own is None else np.asarray(own, float)


def shared_sigma(factor: SlotSightingFactor) -> np.ndarray:
    """Per corner (4,), the sigma of the error all sightings of the slot share (0: none)."""
    shared = factor.observation.corner_sigma_shared
    return np.zeros(4) if shared is None else np.asarray(shared, float)


def sparse_cholesky_like(H: sp.spmatrix):
    """A sparse factorization of the symmetric positive definite ``H`` for many solves:
    SuperLU with a minimum-degree order on ``H``'s own pattern and no pivoting (which a
    positive definite matrix does not need), so ``L`` is the Cholesky factor's pattern. On
    `garage`'s 4,500 unknowns the factor holds 0.46 M numbers against the 20 M of a dense
    one, and the solves for its 184 slots take half the time of the dense ones."""
    return splu(sp.csc_matrix(H), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                options={"SymmetricMode": True})


def sandwich_covariances(
    sightings: Sequence[SlotSightingFactor],
    other: sp.csr_matrix,
    columns: dict[int, int],
    values,
    pose_key: Callable[[int], int],
    corner_key: Callable[[int], int],
    resolve: Callable[[int], int],
    landmarks: Sequence[int],
    chunk: int = 8,
) -> dict[int, np.ndarray] | None:
    """The joint (8, 8) covariance of each landmark's four corners (x0, y0, ..., y3); None
    for a graph of more than :data:`MAX_UNKNOWNS` unknowns.

    Args:
        sightings: every slot-observation factor (those with no landmark weigh nothing).
        other: the whitened Jacobian (rows x unknowns) of every other factor at the
            solution, vague priors included so that every unknown is determined.
        columns: the first column of each key in ``other`` (the unknowns' tangent spaces).
        values: the solution (gtsam Values).
        pose_key, corner_key: keyframe index -> pose key; ``4 * landmark + k`` -> corner key.
        resolve: landmark index -> the landmark it was merged into: one shared error per
            mapped slot.
        landmarks: the landmarks to return.
        chunk: landmarks solved for at once (unknowns x 8 x chunk floats; a few at a time
            keep the solves in cache).
    """
    n = other.shape[1]
    if n > MAX_UNKNOWNS:
        return None
    rows, cols, vals = [], [], []
    inv_w2, own2 = [], []  # per row: 1 / w^2, own^2
    turns, group = [], []  # per corner seen: vehicle -> map rotation (2, 2), (slot, corner)
    groups: dict[tuple[int, int], int] = {}
    shared2: dict[int, float] = defaultdict(float)  # per group: the largest declared, m^2
    row = 0
    for f in sightings:
        if f.landmark is None:
            continue
        pose = pose_key(f.keyframe)
        corners = [corner_key(4 * f.landmark + k) for k in range(4)]
        _, H = slot_observation_residual(pose, corners, f.observation.vCorners)(values, True)
        r = np.arange(row, row + 8)
        for key in (pose, *corners):
            block = H[key]
            nz = np.nonzero(block)
            rows.append(r[nz[0]])
            cols.append(columns[key] + nz[1])
            vals.append(block[nz])
        own, shared, slot = own_sigma(f), shared_sigma(f), resolve(f.landmark)
        for k in range(4):
            inv_w2 += [1.0 / f.sigma**2] * 2
            own2 += [own[k] ** 2] * 2
            turns.append(H[corners[k]][2 * k : 2 * k + 2].T)  # the corner's rows: R^T
            g = groups.setdefault((slot, k), len(groups))
            shared2[g] = max(shared2[g], shared[k] ** 2)
            group.append(g)
        row += 8
    A = sp.csr_matrix(
        (np.concatenate(vals) if vals else [], (np.concatenate(rows) if rows else [],
                                                np.concatenate(cols) if cols else [])),
        shape=(row, n),
    )
    inv_w2_, own2_ = np.array(inv_w2), np.array(own2)
    base = (other.T @ other).tocsc()
    WA = sp.diags(inv_w2_) @ A
    H = (base + A.T @ WA).tocsc()
    # the shared error is the same map-frame vector in every sighting of a slot's corner:
    # each corner's two rows turned into the map frame, then summed over the slot's sightings
    first = 2 * np.arange(len(turns))[:, None]
    to_map = sp.csr_matrix((np.ravel(turns), (np.ravel(first + [0, 0, 1, 1]),
                                               np.ravel(first + [0, 1, 0, 1]))),
                           shape=(row, row))
    rows_of = np.repeat(2 * np.array(group, int), 2) + np.tile([0, 1], len(group))
    G = sp.csr_matrix((np.ones(row), (rows_of, np.arange(row))),
                      shape=(2 * len(groups), row)) @ to_map @ WA
    M = (base + WA.T @ sp.diags(own2_) @ WA
         + G.T @ sp.diags(np.repeat([shared2[g] for g in range(len(groups))], 2)) @ G).tocsr()
    factor = sparse_cholesky_like(H)
    out: dict[int, np.ndarray] = {}
    for start in range(0, len(landmarks), chunk):
        part = landmarks[start : start + chunk]
        picked = np.array([columns[corner_key(4 * i + k)] + axis
                           for i in part for k in range(4) for axis in range(2)])
        E = np.zeros((n, len(picked)))
        E[picked, np.arange(len(picked))] = 1.0
        X = factor.solve(E)
        MX = M @ X
        for j, i in enumerate(part):
            s = slice(8 * j, 8 * j + 8)
            cov = X[:, s].T @ MX[:, s]
            out[i] = (cov + cov.T) / 2.0
    return out
