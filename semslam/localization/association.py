"""Which map landmark each observation of a frame belongs to (the localizer's local map).

The map is indexed once: a KD-tree over slot centres, a table from painted label to slots,
a table from (family, ID) to tags, and a KD-tree over points sampled every metre along the
line markings (the map's own and, with ``slot_sides_as_markings``, its slots' separators
where it holds no line: :mod:`.slot_sides`). For a predicted pose (with its 3x3
covariance) each observation is tried against the landmarks near where it would lie in the
map; its squared Mahalanobis distance
``d2 = r^T (H P H^T + R)^-1 r`` decides:

- tags: by ID (trusted), within the range limit and the tag gate;
- slots: by label when the label is confident and the slot of that label passes the gate;
  otherwise (no label, low confidence, or a confident label that does not fit: a misread)
  the nearest slot by ``d2``, accepted only inside the gate and when the second nearest is
  clearly farther (``d2_second >= ratio * max(d2_best, dof)``);
- markings (Houben's fallback: only in frames where fewer than ``fallback_below`` slots
  and tags associated): candidates within the angle limit, the nearest by ``d2`` of
  Houben's marking measurement (end points across the line; clamped to the marking's
  ends only when ``marking_clamp_reach`` > 0), same gate and ratio test.

Each observation is used once; a slot or tag takes at most one observation per frame.
Everything is in the map frame (metres, radians) except observations (vehicle frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from semslam.chi2 import chi2_quantile
from semslam.config import LocalizationConfig
from semslam.evaluation.segments import nearest_segments, sample_segments
from semslam.geometry import FloatArray, rotate_pose_covariance
from semslam.line_uncertainty import across_variance, end_covariances
from semslam.localization.filter import solve_spd
from semslam.localization.measurements import (
    MarkingMeasurement,
    PointMeasurement,
    TagMeasurement,
)
from semslam.localization.slot_sides import slot_sides
from semslam.types import FrameObservations, SemanticMap

_MARKING_SAMPLE = 1.0  # m between points sampled along map markings for the KD-tree
_MINUS_IDENTITY_8x2 = -np.tile(np.eye(2), (4, 1))  # d(mV - mP)/d(x, y) for four corners
_QUARTER_TURN = np.array([[0.0, -1.0], [1.0, 0.0]])  # (d_x, d_y) @ it = (d_y, -d_x)
_LOCAL_MAP_MARGIN = 4.0  # m: a local map reaches this far beyond a frame's reach
# two map lines this near to parallel, each end of one this near the other's line, are one
# painted line in pieces (a vector map's polyline, or separators back to back): not rivals
# in the second-nearest test, whichever is taken the update is the same within its noise
PIECE_ANGLE_DEG = 2.0
PIECE_OFFSET_M = 0.05


class _LocalBall:
    """The local map of one kind of landmark: the KD-tree's points within a ball around
    the car, asked for with a margin and kept while the car's reach stays inside it.
    ``derive`` turns the ball's point indices into what the association uses (made once
    per ball, not per frame)."""

    def __init__(self, tree: cKDTree, derive) -> None:
        self.tree, self.derive = tree, derive
        self.centre, self.radius, self.held = (0.0, 0.0), -1.0, None

    def around(self, pose: FloatArray, reach: float):
        """``derive`` of the points within (at least) ``reach`` m of the pose."""
        if math.hypot(pose[0] - self.centre[0], pose[1] - self.centre[1]) + reach > self.radius:
            self.centre, self.radius = (float(pose[0]), float(pose[1])), reach + _LOCAL_MAP_MARGIN
            idx = np.array(self.tree.query_ball_point(pose[:2], self.radius), dtype=int)
            self.held = self.derive(np.sort(idx))
        return self.held


@dataclass
class Associations:
    """A frame's associated measurements and what was rejected, per sensor."""

    measurements: list = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)  # "slot" | "tag" | "marking", per measurement
    slots: list[int] = field(default_factory=list)  # associated map slots (one stacked
    # measurement holds all their corners, as one holds all the frame's markings)
    slot_observations: list[int] = field(default_factory=list)  # the frame's slot of each
    rejected: dict[str, int] = field(default_factory=lambda: {"slot": 0, "tag": 0, "marking": 0})
    unmapped: int = 0  # rejected painted lines seen where the map holds none
    accepted_tags: list[tuple] = field(default_factory=list)  # (family, ID) of each tag ...
    rejected_tags: list[tuple] = field(default_factory=list)  # ... accepted, and rejected
    marking_map_var: float = 0.0  # mean map variance across the lines where used, m^2
    count: int = 0  # associated observations

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())


class LocalMap:
    """The map, indexed for association around a predicted pose."""

    def __init__(self, semantic_map: SemanticMap, cfg: LocalizationConfig) -> None:
        self.cfg = cfg
        self.slots = semantic_map.slots
        self.corners = np.array([s.corners for s in self.slots]).reshape(-1, 4, 2)
        self.corner_cov = np.array([s.corner_covariances for s in self.slots]).reshape(-1, 4, 2, 2)
        self.heading_var = np.array([s.orientation_variance for s in self.slots], dtype=float)
        self.centres = self.corners.mean(axis=1)  # (S, 2)
        self._corner_blocks = np.zeros((len(self.slots), 8, 8))  # (S, 8, 8): as R uses them
        for k in range(4):
            self._corner_blocks[:, 2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = (
                cfg.map_covariance_scale * self.corner_cov[:, k]
            )
        mean_cov = self.corner_cov.mean(axis=1)  # (S, 2, 2) over the four corners
        self.floor_terms = [  # per slot: mean corner covariance xx, xy, yy; heading variance
            (float(c[0, 0]), float(c[0, 1]), float(c[1, 1]), float(h))
            for c, h in zip(mean_cov, self.heading_var, strict=True)
        ]
        self._label_codes = {label: i for i, label in enumerate(sorted(
            {s.label for s in self.slots if s.label is not None}))}  # a label read: its code
        self._slot_codes = np.array([self._label_codes.get(s.label, -1) for s in self.slots],
                                    dtype=int)  # -1: a slot with no label (codes read: >= -2)
        self._slot_tree = cKDTree(self.centres) if len(self.slots) else None
        if self._slot_tree is not None:  # slot indices (ascending), centres, label codes
            self._local_slots = _LocalBall(
                self._slot_tree, lambda idx: (idx, self.centres[idx], self._slot_codes[idx])
            )
        self.tags = {(t.family, t.tag_id): t for t in semantic_map.tags}
        self.markings = semantic_map.markings
        if cfg.slot_sides_as_markings:  # separators the slots imply, where no line is mapped
            self.markings = self.markings + slot_sides(semantic_map)
        # each line's uncertainty across itself where it is seen (:meth:`marking_map_var`)
        self.marking_end_cov = end_covariances(self.markings)  # (M, 2, 2) m^2, at a and b
        self.marking_a = np.array([m.a for m in self.markings]).reshape(-1, 2)
        self.marking_b = np.array([m.b for m in self.markings]).reshape(-1, 2)
        samples, self._marking_owner = sample_segments(
            self.marking_a, self.marking_b, _MARKING_SAMPLE)
        self._marking_tree = cKDTree(samples) if len(samples) else None
        self._marking_len = np.hypot(*(self.marking_b - self.marking_a).T)
        self._marking_u = (self.marking_b - self.marking_a) / np.maximum(
            self._marking_len, 1e-9
        )[:, None]  # (M, 2) unit direction a -> b
        self._marking_n = self._marking_u @ np.array([[0.0, 1.0], [-1.0, 0.0]])  # (-u_y, u_x)
        if self._marking_tree is not None:  # marking indices (ascending)
            self._local_markings = _LocalBall(
                self._marking_tree, lambda samples: np.unique(self._marking_owner[samples])
            )
        self._slot_gate = chi2_quantile(cfg.slot_gate, 8)
        self._tag_gate = chi2_quantile(cfg.tag_gate, 3)
        self._marking_gates = {n: chi2_quantile(cfg.marking_gate, n) for n in range(1, 5)}

    def marking_map_var(self, lines: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Variance across map lines ``lines`` (index array) at shares ``lam`` of the way
        from their ``a`` to their ``b`` (broadcast against ``lines``), m^2: the line's own
        there (the mapper's marginal, the map's drift; :mod:`semslam.line_uncertainty`) where
        that exceeds ``marking_map_sigma`` squared, which stands for what a line's marginal
        leaves out (BENCHMARKS.md, Localizer, "Map lines' own uncertainty")."""
        own = across_variance(self.marking_end_cov[lines], lam)
        return np.maximum(own, self.cfg.marking_map_sigma**2)

    # ------------------------------------------------------------------ frame
    def heading_variance_near(self, xy: FloatArray, radius: float) -> float | None:
        """The mean orientation variance (rad^2) of the map slots whose centre lies within
        ``radius`` m of ``xy`` (map frame, m): the map's own heading error there; None when
        no slot is that near."""
        if self._slot_tree is None or radius <= 0:
            return None
        near = self._slot_tree.query_ball_point(np.asarray(xy, dtype=float)[:2], radius)
        return float(self.heading_var[near].mean()) if near else None

    def associate(self, frame: FrameObservations, pose: FloatArray, P: FloatArray) -> Associations:
        """Associate the observations of ``frame`` at the predicted ``pose`` (3,) with pose
        covariance ``P`` (3, 3)."""
        out = Associations()
        if self.cfg.use_tags:
            self._tags(frame, pose, P, out)
        if self.cfg.use_slots:
            self._slots(frame, pose, P, out)
        if self.cfg.use_markings and (
            not self.cfg.markings_as_fallback or out.count < self.cfg.fallback_below
        ):  # Houben's lines keep the filter on track where slots and tags are scarce
            self._markings(frame, pose, P, out)
        return out

    def _tags(self, frame, pose, P, out: Associations) -> None:
        for obs in frame.tags:
            if math.hypot(obs.vTt[0], obs.vTt[1]) > self.cfg.tag_range_limit:
                continue
            tag = self.tags.get((obs.family, obs.tag_id))
            if tag is None:
                continue
            k = self.cfg.map_covariance_scale
            # the map tag's covariance along the vehicle's axes, cross terms and all
            R = np.array(obs.covariance, dtype=float) + k * rotate_pose_covariance(
                tag.covariance, -pose[2]
            )
            m = TagMeasurement(np.asarray(obs.vTt, float), R, np.asarray(tag.mTt, float))
            if _d2(m, pose, P) <= self._tag_gate:
                self._accept(out, "tag", m)
                out.accepted_tags.append((obs.family, obs.tag_id))
            else:
                out.rejected["tag"] += 1
                out.rejected_tags.append((obs.family, obs.tag_id))

    def _slots(self, frame, pose, P, out: Associations) -> None:
        """The Mahalanobis distances of all (observation, nearby map slot) pairs that can
        be chosen (the slot is near, or carries the label read) at once; then the choices
        (:meth:`_choose_slots`); then one measurement of all the accepted slots.

        Everything is on the map's axes: turning every corner's residual and Jacobian rows
        by the predicted heading is an orthogonal change of the measurement's frame, which
        leaves ``r^T S^-1 r`` and the filter's update as they are, and there the map's corner
        covariances need no turning (they are indexed once, as (S, 8, 8) blocks)."""
        if self._slot_tree is None or not frame.slots:
            return
        V = np.array([o.vCorners for o in frame.slots], dtype=float)  # (O, 4, 2)
        reach = self.cfg.search_radius + float(np.abs(V).max()) + 3.0
        J, centres, codes = self._local_slots.around(pose, reach)
        if not len(J):
            out.rejected["slot"] += len(V)
            return
        c, s = math.cos(pose[2]), math.sin(pose[2])
        mV = V @ np.array([[c, s], [-s, c]]) + pose[:2]  # observed corners in the map
        gap = centres[None] - np.vstack([mV.sum(axis=1) * 0.25, pose[:2]])[:, None]
        dist2 = np.einsum("olk,olk->ol", gap, gap)  # (O + 1, L): observed centres, the car
        near = dist2[:-1] < self.cfg.search_radius**2  # (O, L)
        read = np.array([self._label_codes.get(o.label, -2) for o in frame.slots])
        same_label = (codes[None] == read[:, None]) & (dist2[-1] <= reach**2)
        # Mahalanobis distances only for the pairs that can be chosen (near, or same label)
        po, pl = np.nonzero(near | same_label)
        if not len(po):
            out.rejected["slot"] += len(V)
            return
        sigma2 = np.array([max(o.corner_sigma, self.cfg.slot_corner_sigma_min) ** 2
                           for o in frame.slots])
        slot = J[pl]
        mP = self.corners[slot]  # (p, 4, 2) the pairs' map corners
        d = mP - pose[:2]  # from the car, map frame
        H = np.empty((len(po), 8, 3))  # of the map-frame residual mV - mP
        H[:, :, :2] = _MINUS_IDENTITY_8x2
        H[:, :, 2] = (d @ _QUARTER_TURN).reshape(-1, 8)  # (d_y, -d_x) per corner
        D = self._corner_blocks[slot]  # (p, 8, 8) the pair's R: the map's corner blocks ...
        D.reshape(-1, 64)[:, ::9] += sigma2[po][:, None]  # ... and the detector's noise
        S = H @ P @ H.transpose(0, 2, 1) + D
        r = (mV[po] - mP).reshape(-1, 8)
        d2 = (r[:, None, :] @ np.linalg.solve(S, r[..., None]))[:, 0, 0]
        near_pairs: list[list[tuple[float, int, int]]] = [[] for _ in frame.slots]
        label_pairs: list[list[tuple[float, int, int]]] = [[] for _ in frame.slots]
        for q, (o, j, dist, is_near, is_label) in enumerate(zip(
            po.tolist(), slot.tolist(), d2.tolist(), near[po, pl].tolist(),
            same_label[po, pl].tolist(), strict=True,
        )):  # per observation: (d2, map slot, pair)
            if is_near:
                near_pairs[o].append((dist, j, q))
            if is_label:
                label_pairs[o].append((dist, j, q))
        accepted = self._choose_slots(frame.slots, near_pairs, label_pairs)
        out.rejected["slot"] += len(frame.slots) - len(accepted)
        if not accepted:
            return
        obs_idx, map_idx, pair_idx = (list(column) for column in zip(*accepted, strict=True))
        # all the frame's slots: one measurement, turned onto the map's axes by the predicted
        # heading (z = R(yaw) vP); R block-diagonal: the map's corner blocks plus the
        # detector's isotropic noise, which no turn changes
        R = np.zeros((8 * len(accepted), 8 * len(accepted)))
        for i, block in enumerate(D[pair_idx]):
            R[8 * i : 8 * i + 8, 8 * i : 8 * i + 8] = block
        z = (mV[obs_idx] - pose[:2]).ravel()
        # at this pose the turned model's residual and Jacobian are the gate's
        linearised = (tuple(pose), r[pair_idx].ravel(), H[pair_idx].reshape(-1, 3))
        m = PointMeasurement(z, R, self.corners[map_idx].reshape(-1, 2), turn=float(pose[2]),
                             linearised=linearised)
        out.slots.extend(map_idx)
        out.slot_observations.extend(obs_idx)
        self._accept(out, "slot", m, observations=len(accepted))

    def _choose_slots(self, observed, near_pairs, label_pairs) -> list[tuple[int, int, int]]:
        """The choices, one observation at a time (a frame has a few): the slot of a
        confident label when it passes the gate, else the nearest slot by Mahalanobis
        distance when it passes the gate and the second-nearest test. ``near_pairs`` and
        ``label_pairs`` hold per observation its (d2, map slot, pair) candidates. Returns
        the accepted (observation, map slot, pair); a slot takes one observation."""
        used: set[int] = set()
        gate, ratio = self._slot_gate, self.cfg.second_nearest_ratio
        accepted: list[tuple[int, int, int]] = []
        for o, obs in enumerate(observed):
            chosen = None
            if obs.label_confidence >= self.cfg.id_confidence_high:
                mine = [pair for pair in label_pairs[o] if pair[1] not in used]
                if mine:  # the nearest slot of that label (pairs sort by d2, then index)
                    nearest = min(mine)
                    chosen = nearest if nearest[0] <= gate else None
                # else: a misread (or a lost filter): the geometry decides below
            if chosen is None:
                cand = sorted(pair for pair in near_pairs[o] if pair[1] not in used)
                if cand:
                    best = cand[0][0]
                    second = cand[1][0] if len(cand) > 1 else math.inf
                    if best <= gate and second >= ratio * max(best, 8):
                        chosen = cand[0]
            if chosen is not None:
                used.add(chosen[1])
                accepted.append((o, chosen[1], chosen[2]))
        return accepted

    def _accept(self, out: Associations, kind: str, measurement, observations: int = 1) -> None:
        out.measurements.append(measurement)
        out.kinds.append(kind)
        out.count += observations

    def _markings(self, frame, pose, P, out: Associations) -> None:
        """Houben's association, vectorised over all (detection, candidate marking) pairs of
        the frame: the gate and the ratio test use the distances of both end points across
        each candidate line; the winners become one stacked measurement that also clamps
        end points at their marking's ends, and each winner is gated again with it."""
        if self._marking_tree is None or not frame.markings:
            return
        cfg = self.cfg
        vE = np.array([[m.vA, m.vB] for m in frame.markings], dtype=float)  # (D, 2, 2)
        sigma = np.array([  # end point across the line: as declared, else configured
            cfg.marking_endpoint_sigma if m.sigma is None else m.sigma for m in frame.markings
        ])
        length = np.hypot(*(vE[:, 1] - vE[:, 0]).T)
        long_enough = length >= cfg.marking_min_length
        vE, sigma, length = vE[long_enough], sigma[long_enough], length[long_enough]
        if not len(vE):
            return
        c, s = math.cos(pose[2]), math.sin(pose[2])
        Rm = np.array([[c, -s], [s, c]])
        mE = vE @ Rm.T + pose[:2]  # (D, 2, 2) map frame
        reach = float(np.abs(vE).max()) + cfg.search_radius / 2 + _MARKING_SAMPLE
        # every (detection, local marking) pair is a candidate; the tests below sort them
        local = self._local_markings.around(pose, reach)
        # where the map holds no line within the detections' range of the car (a stretch the
        # mapping drive did not see well), the lines rejected are paint the map does not
        # hold: no evidence against the pose, as lines that fit none of the map's lines in
        # view are (counted at the end, when the rejections are known)
        seen_to = float(np.hypot(*vE.reshape(-1, 2).T).max())
        unheld = not len(local) or nearest_segments(
            pose[None, :2], self.marking_a[local], self.marking_b[local])[0][0] > seen_to
        rejected_before = out.rejected["marking"]
        self._match_markings(out, pose, P, vE, mE, sigma, length, local, s, c)
        if unheld:
            out.unmapped += out.rejected["marking"] - rejected_before

    def _same_line(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Are map lines ``j`` pieces of map lines ``i``'s painted line (elementwise):
        within :data:`PIECE_ANGLE_DEG` of parallel, both ends of ``j`` within
        :data:`PIECE_OFFSET_M` of ``i``'s line (the infinite line: pieces end to end)?"""
        n = self._marking_n[i]
        parallel = np.abs((self._marking_u[j] * n).sum(axis=1)) < math.sin(
            math.radians(PIECE_ANGLE_DEG))
        off_a = np.abs(((self.marking_a[j] - self.marking_a[i]) * n).sum(axis=1))
        off_b = np.abs(((self.marking_b[j] - self.marking_a[i]) * n).sum(axis=1))
        return parallel & (off_a < PIECE_OFFSET_M) & (off_b < PIECE_OFFSET_M)

    def _match_markings(self, out, pose, P, vE, mE, sigma, length, local, s, c) -> None:
        """Houben's tests on every (detection, local marking) pair, then the winners'
        stacked measurement (see :meth:`_markings`)."""
        cfg = self.cfg
        det = np.arange(len(vE)).repeat(len(local))
        own = np.broadcast_to(local, (len(vE), len(local))).reshape(-1)
        u, n = self._marking_u[own], self._marking_n[own]  # (pairs, 2): along, across
        d_obs = (mE[det, 1] - mE[det, 0]) / length[det, None]
        from_a = mE[det] - self.marking_a[own][:, None, :]  # (pairs, 2 ends, 2)
        along = (from_a @ u[:, :, None])[..., 0]  # (pairs, 2 ends)
        across = (from_a @ n[:, :, None])[..., 0]
        keep = (np.abs((n * d_obs).sum(axis=1)) < math.sin(
            math.radians(cfg.marking_max_angle_deg)
        )) & (along.max(axis=1) > -0.5) & (along.min(axis=1) < self._marking_len[own] + 0.5)
        det, own, n, r = det[keep], own[keep], n[keep], -across[keep]  # r: 0 - across
        # the map line's variance where each end point falls on it
        map_var = self.marking_map_var(
            own[:, None], along[keep] / np.maximum(self._marking_len[own], 1e-9)[:, None])
        R2 = sigma[det, None] ** 2 + map_var  # (pairs, 2 ends)
        # the residuals' rows [n, n . dR/dyaw e] for both end points
        dE = vE[det] @ np.array([[-s, c], [-c, -s]])  # (pairs, 2, 2): dR/dyaw e
        H = np.empty((len(det), 2, 3))
        H[..., :2] = n[:, None, :]
        H[..., 2] = (dE @ n[:, :, None])[..., 0]
        S = H @ P @ H.transpose(0, 2, 1)
        S[:, 0, 0] += R2[:, 0]
        S[:, 1, 1] += R2[:, 1]
        det_S = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        d2 = (S[:, 1, 1] * r[:, 0] ** 2 - 2 * S[:, 0, 1] * r[:, 0] * r[:, 1]
              + S[:, 0, 0] * r[:, 1] ** 2) / det_S
        if not len(det):
            out.rejected["marking"] += len(vE)
            return
        order = np.lexsort((d2, det))
        det, own, d2, map_var = det[order], own[order], d2[order], map_var[order]
        starts = np.flatnonzero(np.r_[True, det[1:] != det[:-1]])
        first = starts.tolist()
        # a candidate that is the best one's own painted line, in another piece, is no rival
        best_of = np.repeat(own[starts], np.diff(np.r_[starts, len(det)]))
        rival = ~self._same_line(best_of, own)
        d2_list, rival_list = d2.tolist(), rival.tolist()
        winners = []
        for i, f in enumerate(first):
            nxt = first[i + 1] if i + 1 < len(first) else len(det)
            runner_up = next((d2_list[g] for g in range(f + 1, nxt) if rival_list[g]), math.inf)
            best = d2_list[f]
            if best <= self._marking_gates[2] and runner_up >= cfg.second_nearest_ratio * max(
                best, 2.0
            ):
                winners.append(f)
        out.rejected["marking"] += len(vE) - len(winners)
        if not winners:
            return
        w = np.array(winners)
        k = np.repeat(own[w], 2)
        end_sigma = np.repeat(sigma[det[w]], 2)  # per end point
        m = MarkingMeasurement.build(
            pose, vE[det[w]].reshape(-1, 2), self.marking_a[k], self.marking_b[k],
            np.sqrt(end_sigma**2 + map_var[w].reshape(-1)), margin=2 * end_sigma,
            reach=cfg.marking_clamp_reach,
        )
        # gate again the winners that got clamped rows (the others passed with these rows)
        clamped = m.clamped.reshape(-1, 2).any(axis=1)
        if clamped.any():
            rm, Hm = m.linearise(pose)
        bounds = np.append(m.rows[0::2], len(m.z))
        good = []
        for i in range(len(w)):
            if not clamped[i]:
                good.append(i)
                continue
            sl = slice(bounds[i], bounds[i + 1])
            Sb = Hm[sl] @ P @ Hm[sl].T + m.R[sl, sl]
            if rm[sl] @ solve_spd(Sb, rm[sl]) <= self._marking_gates[sl.stop - sl.start]:
                good.append(i)
        out.rejected["marking"] += len(w) - len(good)
        if not good:
            return
        if len(good) < len(w):
            g = np.array(good)
            k = np.repeat(own[w[g]], 2)
            end_sigma = np.repeat(sigma[det[w[g]]], 2)
            m = MarkingMeasurement.build(
                pose, vE[det[w[g]]].reshape(-1, 2), self.marking_a[k], self.marking_b[k],
                np.sqrt(end_sigma**2 + map_var[w[g]].reshape(-1)), margin=2 * end_sigma,
                reach=cfg.marking_clamp_reach,
            )
        out.marking_map_var = float(map_var[w[good]].mean())
        self._accept(out, "marking", m, observations=len(good))


def _d2(m, pose: FloatArray, P: FloatArray) -> float:
    """Squared Mahalanobis distance of measurement ``m`` at ``pose`` (linearised)."""
    r, H = m.linearise(pose)
    return float(r @ solve_spd(H @ P @ H.T + m.R, r))
