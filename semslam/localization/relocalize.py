"""Global relocalization: the vehicle's pose in the map from one frame, with no prior pose.

Houben et al. needed a coarse initial pose; semslam finds one from a single frame's
observations (vehicle frame, metres, radians) and the :class:`SemanticMap` (map frame).
A wrong pose is far worse than none, so every step refuses rather than guesses.

1. **Tags** are trusted. Each observed tag whose ``(family, tag_id)`` is in the map (and
   within ``max_tag_range``) gives ``mTv = mTt * inverse(vTt)``, with the observation
   covariance and the map tag covariance propagated through the composition. Several
   tags are fused by information weighting after a consensus: the largest set of tags
   that pass a 3-dof chi-square gate (99.9 %) against one seed wins, members failing it
   against the fused pose are then dropped, and two equally large sets that disagree
   (two tags that disagree, or one tag ID found twice in the map) give no tag pose.
2. **Slots around a tag pose** refine it: each observed slot against its nearest map
   slots, one :func:`fit_se2` of its 4 corners onto the map slot's 4 corners per pair,
   pairs kept when that pose passes a chi-square gate against the tag pose. The pose
   explaining the most observed slots (then the closest to the tags) wins unless a pose
   it does not explain is as well supported and nearly as close (a tie: tags alone).
   One slot is enough here: the tags already say which slot it is. The slot fit is
   fused with the tags (``"tags+slots"``), or the tags stand alone (``"tags"``).
3. **Slots alone** (no usable tag pose): every observed slot with
   ``label_confidence >= min_label_confidence`` whose label is in the map, paired with
   each map slot carrying that label (a duplicated label is several hypotheses; a label on
   more than ``MAX_SLOTS_PER_LABEL`` map slots is not used), gives
   a pose by :func:`fit_se2`. Its support is the number of such labelled slots whose
   corners, moved by it, lie within ``inlier_distance`` of the corners of a map slot with
   their label (once per map slot: frames merged into one may see a slot twice).
   Unlabelled slots do not vote: a garage is periodic, and the typical wrong ID is a
   neighbour's, so a pose one slot pitch off fits unlabelled slots as well as the true
   one does. The best-supported pose is accepted when it has at least
   ``min_slots`` supporters, no distinct pose (more than 1 m or 10 deg away) has as many
   (ambiguous), and the frame does not speak against it: read labels of any confidence
   that fit it, minus read labels that land on a map slot with another label, minus
   slots that land on no map slot, must still be at least ``min_slots`` (two neighbours'
   IDs misread with the same shift fit a pose one pitch off; the frame's other slots
   then contradict it). One labelled slot is enough when its label was read alike in
   at least ``single_slot_reads`` frames (a slot of several recent frames merged into
   one, :mod:`.recent`): misreads that vary from frame to frame do not agree that often;
   the other checks stay (no rival pose as well supported, the frame not against it).
4. An accepted slot pose is refined by :func:`fit_se2` over all corners of the agreeing
   slots (its supporters plus any observed slot lying within ``inlier_distance`` of a map
   slot, found with a k-d tree on the map slot centres, unless a confident label says
   it is another slot), weighted by ``1 / (corner_sigma^2 + map corner variance)``,
   twice. Its covariance is the linearised least-squares ``(J^T W J)^-1`` (at the
   corners' centroid exactly ``sigma^2 / n`` in position and
   ``sigma^2 / sum |c - centroid|^2`` in yaw, moved to the vehicle origin) plus
   :data:`COVARIANCE_FLOOR`.

Corner order: the simulator lists slot corners entrance-left, entrance-right,
rear-right, rear-left as seen from the aisle (``ExactSensor`` moves the world slot's
corners into the vehicle frame unchanged; ghosts are shifted copies or rectangles in
the same order), and the mapper keeps the detector's order, so the order does not
depend on the way the car faces and no 180-degree relabelled order is tried.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from semslam.evaluation.alignment import fit_se2
from semslam.geometry import FloatArray, compose, inverse, wrap_angle
from semslam.types import FrameObservations, SemanticMap, TagFamily

CHI2_3DOF_999 = 16.266  # 99.9 % quantile of chi-square, 3 dof: tags against each other
TAG_SLOT_GATE = 25.0  # chi-square (3 dof, ~5 sigma) of slot poses against the tag pose
TAG_TIE_MARGIN = 9.0  # around a tag pose, a rival this much less likely (chi-square) is a tie
DISTINCT_DISTANCE = 1.0  # slot hypotheses farther apart than this (m) ...
DISTINCT_YAW = math.radians(10.0)  # ... or this (rad) are different poses
COVARIANCE_FLOOR = np.diag([0.01**2, 0.01**2, math.radians(0.1) ** 2])  # added to slot fits
NEAREST_MAP_SLOTS = 3  # map slots tried per observed slot around a tag pose
MAX_SLOTS_PER_LABEL = 4  # a label painted on more map slots (a row letter, repeated per floor)
# does not relocalize: it says little where the car is, and its pairs grow with the square


@dataclass(frozen=True, eq=False)
class Relocalization:
    """A pose found without a prior.

    Attributes:
        mTv: (3,) pose of the vehicle in the map frame ``(x, y, yaw)``: m, m, rad.
        covariance: (3, 3) covariance of ``mTv`` (m^2, m*rad, rad^2).
        source: ``"tags"``, ``"slots"`` or ``"tags+slots"``.
        tags_used: observed tags fused into the pose.
        slots_used: observed slots whose corners entered the final fit.
        slots_agreeing: observed slots that vote for the pose: label agreements
            (slots only) or slots matched around the tag pose (with tags); 0 for tags alone.
        residual_rms_m: RMS corner residual of the slot fit, or RMS tag position
            residual for tags alone, metres.
    """

    mTv: FloatArray
    covariance: FloatArray
    source: str
    tags_used: int
    slots_used: int
    slots_agreeing: int
    residual_rms_m: float


@dataclass
class _Gaussian:
    mean: FloatArray
    cov: FloatArray


@dataclass
class _SlotFit:
    pose: FloatArray
    cov: FloatArray
    used: int
    agreeing: int
    rms: float


# --------------------------------------------------------------------------- batch SE(2)


def _rotations(yaw: FloatArray) -> FloatArray:
    """(H, 2, 2) rotation matrices of (H,) yaws."""
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.empty((len(yaw), 2, 2))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = c, -s, s, c
    return R


def _fit_batch(src: FloatArray, dst: FloatArray) -> FloatArray:
    """(H, 3) least-squares ``T_h`` with ``dst[h] ≈ T_h * src[h]`` for (H, N, 2) point sets
    (the closed form of :func:`fit_se2`, unweighted, for many sets at once)."""
    sm, dm = src.mean(axis=1), dst.mean(axis=1)
    s, d = src - sm[:, None], dst - dm[:, None]
    cos_t = np.sum(d[..., 0] * s[..., 0] + d[..., 1] * s[..., 1], axis=1)
    sin_t = np.sum(d[..., 1] * s[..., 0] - d[..., 0] * s[..., 1], axis=1)
    yaw = np.arctan2(sin_t, cos_t)
    t = dm - np.einsum("hij,hj->hi", _rotations(yaw), sm)
    return np.column_stack([t, yaw])


def _move(poses: FloatArray, pts: FloatArray) -> FloatArray:
    """Points (P, 4, 2) moved by each of (H, 3) poses -> (H, P, 4, 2)."""
    R = _rotations(poses[:, 2])
    return np.einsum("hij,pkj->hpki", R, pts) + poses[:, None, None, :2]


def _pose_delta(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a - b`` for poses, yaw wrapped (broadcasts over leading axes)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    d[..., 2] = wrap_angle(d[..., 2])
    return d


def _mahalanobis2(delta: FloatArray, cov: FloatArray) -> float:
    return float(delta @ np.linalg.solve(cov, delta))


def _fuse(items: list[_Gaussian]) -> _Gaussian:
    """Information-weighted mean of pose Gaussians, linearised about the first one."""
    ref = items[0].mean
    info = np.zeros((3, 3))
    vec = np.zeros(3)
    for g in items:
        L = np.linalg.inv(g.cov)
        info += L
        vec += L @ _pose_delta(g.mean, ref)
    cov = np.linalg.inv(info)
    mean = ref + cov @ vec
    mean[2] = wrap_angle(mean[2])
    return _Gaussian(mean, 0.5 * (cov + cov.T))


# --------------------------------------------------------------------------- relocalizer


class Relocalizer:
    """Finds the vehicle in ``semantic_map`` from one frame; build once per map.

    Args:
        semantic_map: the map (map frame).
        min_label_confidence: observed slot labels below this are treated as unread.
        min_slots: labelled slots that must agree with a pose found from slots alone
            (and its net evidence, see the module docstring).
        inlier_distance: largest corner distance (m) of an agreeing slot.
        max_tag_range: tags farther than this from the vehicle (m) are ignored.
        single_slot_reads: a labelled slot read alike in this many merged frames fixes
            the pose alone (0: never; ``min_slots`` agreeing slots are needed).
    """

    def __init__(
        self,
        semantic_map: SemanticMap,
        *,
        min_label_confidence: float = 0.8,
        min_slots: int = 2,
        inlier_distance: float = 0.35,
        max_tag_range: float = 20.0,
        single_slot_reads: int = 0,
    ) -> None:
        self.min_label_confidence = float(min_label_confidence)
        self.single_slot_reads = int(single_slot_reads)
        self.min_slots = max(1, int(min_slots))
        self.inlier_distance = float(inlier_distance)
        self.max_tag_range = float(max_tag_range)

        slots = semantic_map.slots
        self._corners = np.array([s.corners for s in slots], dtype=float).reshape(-1, 4, 2)
        covs = np.array([s.corner_covariances for s in slots], dtype=float).reshape(-1, 4, 2, 2)
        # isotropic variance per corner (half the trace), m^2
        self._corner_var = 0.5 * (covs[..., 0, 0] + covs[..., 1, 1])
        self._centres = self._corners.mean(axis=1)
        self._tree = cKDTree(self._centres) if len(slots) else None
        self._label_code: dict[str, int] = {}
        self._map_code = np.full(len(slots), -1, dtype=int)
        by_label: dict[int, list[int]] = {}
        for i, s in enumerate(slots):
            if s.label is None:
                continue
            code = self._label_code.setdefault(s.label, len(self._label_code))
            self._map_code[i] = code
            by_label.setdefault(code, []).append(i)
        self._slots_of_label = {  # a label on many slots says little and costs pairs^2
            k: np.array(v, dtype=int) for k, v in by_label.items() if len(v) <= MAX_SLOTS_PER_LABEL
        }
        # labels left out for being on more than MAX_SLOTS_PER_LABEL slots (said when lost)
        self.repeated_labels = len(by_label) - len(self._slots_of_label)
        self._tags: dict[tuple[TagFamily, int], list] = {}
        for t in semantic_map.tags:
            self._tags.setdefault((TagFamily(t.family), int(t.tag_id)), []).append(t)

    # ------------------------------------------------------------------ public

    def locate(self, frame: FrameObservations) -> Relocalization | None:
        """The pose of the vehicle at ``frame`` in the map frame, or None when the frame
        gives no usable or no unambiguous evidence."""
        tag = self._tag_pose(frame)
        obs = self._observed_slots(frame)
        if tag is not None:
            pose, n_tags, tag_rms = tag
            fit = self._slots_around(pose, obs) if obs is not None else None
            if fit is not None:
                slot_g = _Gaussian(fit.pose, fit.cov)
                d2 = _mahalanobis2(_pose_delta(fit.pose, pose.mean), fit.cov + pose.cov)
                if d2 <= TAG_SLOT_GATE:
                    fused = _fuse([pose, slot_g])
                    return Relocalization(
                        fused.mean,
                        fused.cov,
                        "tags+slots",
                        n_tags,
                        fit.used,
                        fit.agreeing,
                        fit.rms,
                    )
            return Relocalization(pose.mean, pose.cov, "tags", n_tags, 0, 0, tag_rms)
        if obs is None:
            return None
        fit = self._slots_global(obs)
        if fit is None:
            return None
        return Relocalization(fit.pose, fit.cov, "slots", 0, fit.used, fit.agreeing, fit.rms)

    # ------------------------------------------------------------------ tags

    def _tag_pose(self, frame: FrameObservations) -> tuple[_Gaussian, int, float] | None:
        """Fused pose from the consistent map tags seen, tags used, RMS position residual."""
        cands: list[tuple[int, _Gaussian, FloatArray, FloatArray]] = []
        for k, obs in enumerate(frame.tags):
            vTt = np.asarray(obs.vTt, dtype=float)
            if math.hypot(vTt[0], vTt[1]) > self.max_tag_range:
                continue
            for mt in self._tags.get((TagFamily(obs.family), int(obs.tag_id)), ()):
                mTt = np.asarray(mt.mTt, dtype=float)
                g = _tag_candidate(
                    mTt,
                    np.asarray(mt.covariance, dtype=float),
                    vTt,
                    np.asarray(obs.covariance, dtype=float),
                )
                cands.append((k, g, mTt, vTt))
        if not cands:
            return None
        n = len(cands)
        ok = np.zeros((n, n), dtype=bool)
        d2 = np.full((n, n), np.inf)
        for i in range(n):
            for j in range(i, n):
                gi, gj = cands[i][1], cands[j][1]
                d2[i, j] = d2[j, i] = _mahalanobis2(_pose_delta(gi.mean, gj.mean), gi.cov + gj.cov)
                ok[i, j] = ok[j, i] = d2[i, j] <= CHI2_3DOF_999
        # consensus: for each seed, the closest candidate of every other observed tag
        # consistent with it; the seed with the most tags wins, a rival seed with as many
        # tags but an inconsistent pose makes the tags ambiguous
        sets = []
        for i in range(n):
            best: dict[int, int] = {cands[i][0]: i}
            for j in np.flatnonzero(ok[i]):
                k = cands[j][0]
                if k not in best or d2[i, j] < d2[i, best[k]]:
                    best[k] = int(j)
            sets.append(sorted(best.values()))
        sizes = np.array([len(m) for m in sets])
        spread = np.array([d2[i, sets[i]].sum() for i in range(n)])
        order = np.lexsort((spread, -sizes))
        seed = int(order[0])
        if any(sizes[j] == sizes[seed] and not ok[seed, j] for j in order[1:]):
            return None
        members_l = list(sets[seed])
        # drop members that fail the gate against the fused pose, worst first
        while True:
            fused = _fuse([cands[j][1] for j in members_l])
            if len(members_l) <= 2:
                break
            worst, worst_d2 = -1, CHI2_3DOF_999
            for j in members_l:
                g = cands[j][1]
                dd = _mahalanobis2(_pose_delta(g.mean, fused.mean), g.cov)
                if dd > worst_d2:
                    worst, worst_d2 = j, dd
            if worst < 0:
                break
            members_l.remove(worst)
        res = []
        for j in members_l:
            _, _, mTt, vTt = cands[j]
            res.append(compose(fused.mean, vTt)[:2] - mTt[:2])
        rms = float(np.sqrt(np.mean(np.sum(np.square(res), axis=1))))
        return fused, len(members_l), rms

    # ------------------------------------------------------------------ slots

    def _observed_slots(self, frame: FrameObservations):
        """Stacked observed slots: corners (S, 4, 2), variance (S,), confident map label
        code (S,) (-1: unread, not confident or not in the map)."""
        if not frame.slots or self._tree is None:
            return None
        V = np.array([s.vCorners for s in frame.slots], dtype=float).reshape(-1, 4, 2)
        var = np.array([max(float(s.corner_sigma), 1e-3) ** 2 for s in frame.slots])
        code_any = np.array(
            [self._label_code.get(s.label, -1) if s.label else -1 for s in frame.slots], int
        )
        confident = np.array([s.label_confidence >= self.min_label_confidence for s in frame.slots])
        code = np.where(confident, code_any, -1)
        reads = np.array([s.label_reads for s in frame.slots], dtype=int)
        return V, var, code, code_any, reads

    def _hypotheses(self, V: FloatArray, ps: FloatArray, pm: FloatArray):
        """Poses of the pairs (observed ps[i], map pm[i]) and, per pose, which pairs agree
        (all 4 corners within ``inlier_distance``): (H, 3), (H, H) bool."""
        H = _fit_batch(V[ps], self._corners[pm])
        moved = _move(H, V[ps])  # (H, P, 4, 2)
        err = np.linalg.norm(moved - self._corners[pm][None], axis=-1).max(axis=-1)
        return H, err <= self.inlier_distance

    @staticmethod
    def _support(agree: FloatArray, ps: FloatArray, pm: FloatArray) -> FloatArray:
        """Per hypothesis, the agreeing pairs counted once per observed slot and once per
        map slot (several frames merged into one may see a slot twice) -> (H,)."""
        _, obs_i = np.unique(ps, return_inverse=True)
        _, map_i = np.unique(pm, return_inverse=True)
        rows, cols = np.nonzero(agree)
        by_obs = np.zeros((agree.shape[0], obs_i.max() + 1), dtype=bool)
        by_map = np.zeros((agree.shape[0], map_i.max() + 1), dtype=bool)
        by_obs[rows, obs_i[cols]] = True
        by_map[rows, map_i[cols]] = True
        return np.minimum(by_obs.sum(axis=1), by_map.sum(axis=1))

    def _slots_global(self, obs) -> _SlotFit | None:
        V, var, code, code_any, reads = obs
        idx = np.array([i for i in np.flatnonzero(code >= 0) if code[i] in self._slots_of_label],
                       dtype=int)
        needed = self.min_slots
        if self.single_slot_reads > 0 and np.any(reads[idx] >= self.single_slot_reads):
            needed = 1
        if len(idx) < needed:
            return None
        ps = np.concatenate([np.full(len(self._slots_of_label[code[i]]), i) for i in idx])
        pm = np.concatenate([self._slots_of_label[code[i]] for i in idx])
        H, agree = self._hypotheses(V, ps, pm)
        support = self._support(agree, ps, pm)
        best = int(np.argmax(support))
        if support[best] < needed:
            return None
        far = _distinct(H, H[best])
        if np.any(far & (support >= support[best])):
            return None
        pairs = {int(ps[j]): int(pm[j]) for j in np.flatnonzero(agree[best])}
        fit = self._refine(H[best], V, var, code, pairs, int(support[best]))
        if fit is None:
            return None
        # net evidence: read labels that fit minus read labels that contradict and slots
        # that land on no map slot (two neighbours' IDs misread with the same shift fit a
        # pose one pitch off; the frame's other slots then speak against it)
        agree, contra, miss = self._explain(fit.pose, V, code_any)
        if agree - contra - miss < needed:
            return None
        return fit

    def _explain(
        self, pose: FloatArray, V: FloatArray, code_any: FloatArray
    ) -> tuple[int, int, int]:
        """How the observed slots sit under ``pose``: labelled slots on a map slot with their
        label, labelled slots on a map slot with another label, slots on no map slot."""
        moved = _move(pose[None], V)[0]
        k = min(3, len(self._centres))
        _, nn = self._tree.query(moved.mean(axis=1), k=k)
        nn = np.asarray(nn).reshape(len(V), k)
        valid = nn < len(self._centres)
        nn_c = np.where(valid, nn, 0)
        err = np.linalg.norm(moved[:, None] - self._corners[nn_c], axis=-1).max(axis=-1)
        on = valid & (err <= self.inlier_distance)
        same = on & (self._map_code[nn_c] == code_any[:, None])
        labelled = code_any >= 0
        agree = labelled & same.any(axis=1)
        contra = labelled & ~agree & on.any(axis=1)
        miss = ~on.any(axis=1)
        return int(agree.sum()), int(contra.sum()), int(miss.sum())

    def _slots_around(self, prior: _Gaussian, obs) -> _SlotFit | None:
        """Slots matched around a tag pose: each observed slot against its nearest map
        slots, pairs gated against the prior, the best-supported pose that has no rival."""
        V, var, code, code_any, _ = obs
        k = min(NEAREST_MAP_SLOTS, len(self._centres))
        centres = _move(prior.mean[None], V.mean(axis=1)[:, None, :])[0, :, 0]
        _, nn = self._tree.query(centres, k=k)
        ps = np.repeat(np.arange(len(V)), k)
        pm = np.asarray(nn).reshape(-1)
        valid = pm < len(self._centres)
        ps, pm = ps[valid], pm[valid]
        if len(ps) == 0:
            return None
        H, agree = self._hypotheses(V, ps, pm)
        fit_cov = _fit_covariance_batch(H, V[ps], var[ps, None] + self._corner_var[pm])
        delta = _pose_delta(H, prior.mean[None])
        S = fit_cov + prior.cov[None]
        d2 = np.einsum("hi,hi->h", delta, np.linalg.solve(S, delta[..., None])[..., 0])
        keep = d2 <= TAG_SLOT_GATE
        if not np.any(keep):
            return None
        H, agree, d2 = H[keep], agree[np.ix_(keep, keep)], d2[keep]
        ps, pm = ps[keep], pm[keep]
        support = self._support(agree, ps, pm)
        best = int(np.lexsort((d2, -support))[0])
        # a rival: a pose the best one does not explain, as well supported and nearly as
        # close to the tags
        rivals = ~agree[best] & (support >= support[best]) & (d2 - d2[best] < TAG_TIE_MARGIN)
        if np.any(rivals):
            return None
        pairs = {int(ps[j]): int(pm[j]) for j in np.flatnonzero(agree[best])}
        return self._refine(H[best], V, var, np.full_like(code, -1), pairs, int(support[best]))

    def _refine(
        self,
        pose: FloatArray,
        V: FloatArray,
        var: FloatArray,
        code: FloatArray,
        pairs: dict[int, int],
        agreeing: int,
    ) -> _SlotFit | None:
        """Fit over all agreeing slots (the voting pairs plus any observed slot lying on a
        map slot whose label does not contradict its own), re-associating once."""
        for _ in range(2):
            matched = self._associate(pose, V, code, pairs)
            if not matched:
                return None
            s_idx = np.array(list(matched.keys()))
            m_idx = np.array(list(matched.values()))
            src = V[s_idx].reshape(-1, 2)
            dst = self._corners[m_idx].reshape(-1, 2)
            w = 1.0 / (np.repeat(var[s_idx], 4) + self._corner_var[m_idx].reshape(-1))
            pose = fit_se2(src, dst, w)
        moved = _move(pose[None], V[s_idx])[0].reshape(-1, 2)
        res = moved - dst
        rms = float(np.sqrt(np.mean(np.sum(res * res, axis=1))))
        cov = _fit_covariance(pose, src, 1.0 / w) + COVARIANCE_FLOOR
        return _SlotFit(pose, cov, len(s_idx), agreeing, rms)

    def _associate(
        self, pose: FloatArray, V: FloatArray, code: FloatArray, pairs: dict[int, int]
    ) -> dict[int, int]:
        """Observed slot -> map slot for every observed slot within ``inlier_distance`` of a
        map slot under ``pose`` (one observed slot per map slot, the closest)."""
        moved = _move(pose[None], V)[0]  # (S, 4, 2)
        k = min(2, len(self._centres))
        _, nn = self._tree.query(moved.mean(axis=1), k=k)
        nn = np.asarray(nn).reshape(len(V), k)
        cand_s = np.concatenate([np.repeat(np.arange(len(V)), k), np.array(list(pairs), int)])
        cand_m = np.concatenate([nn.reshape(-1), np.array(list(pairs.values()), int)])
        ok = cand_m < len(self._centres)
        cand_s, cand_m = cand_s[ok], cand_m[ok]
        err = np.linalg.norm(moved[cand_s] - self._corners[cand_m], axis=-1).max(axis=-1)
        ok = err <= self.inlier_distance
        ok &= (code[cand_s] < 0) | (self._map_code[cand_m] == code[cand_s])
        best_for_map: dict[int, tuple[float, int]] = {}
        for s, m, e in zip(cand_s[ok], cand_m[ok], err[ok], strict=True):
            if int(m) not in best_for_map or e < best_for_map[int(m)][0]:
                best_for_map[int(m)] = (float(e), int(s))
        out: dict[int, int] = {}
        out_err: dict[int, float] = {}
        for m, (e, s) in best_for_map.items():
            if s not in out or e < out_err[s]:
                out[s], out_err[s] = m, e
        return out


# --------------------------------------------------------------------------- helpers


def _distinct(H: FloatArray, ref: FloatArray) -> FloatArray:
    """(H,) bool: poses more than 1 m or 10 deg from ``ref``."""
    d = _pose_delta(H, ref[None])
    return (np.hypot(d[:, 0], d[:, 1]) > DISTINCT_DISTANCE) | (np.abs(d[:, 2]) > DISTINCT_YAW)


def _fit_covariance(pose: FloatArray, src: FloatArray, var: FloatArray | float) -> FloatArray:
    """Linearised covariance of the least-squares fit ``dst ≈ T * src``: ``(J^T W J)^-1``
    with ``W = 1 / var`` per point (isotropic), ``src`` (N, 2) (or (4, 2) with a scalar)."""
    src = np.asarray(src, dtype=float).reshape(-1, 2)
    w = 1.0 / np.broadcast_to(np.asarray(var, dtype=float), (len(src),))
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rx = c * src[:, 0] - s * src[:, 1]
    ry = s * src[:, 0] + c * src[:, 1]
    sw = w.sum()
    info = np.array(
        [
            [sw, 0.0, -(w @ ry)],
            [0.0, sw, w @ rx],
            [-(w @ ry), w @ rx, w @ (rx * rx + ry * ry)],
        ]
    )
    return np.linalg.inv(info)


def _fit_covariance_batch(H: FloatArray, src: FloatArray, var: FloatArray) -> FloatArray:
    """:func:`_fit_covariance` of (H,) poses, (H, 4, 2) points, (H, 4) variances -> (H, 3, 3)."""
    w = 1.0 / var
    c, s = np.cos(H[:, 2])[:, None], np.sin(H[:, 2])[:, None]
    rx = c * src[..., 0] - s * src[..., 1]
    ry = s * src[..., 0] + c * src[..., 1]
    sw = w.sum(axis=1)
    a, b = -(w * ry).sum(axis=1), (w * rx).sum(axis=1)
    info = np.zeros((len(H), 3, 3))
    info[:, 0, 0] = info[:, 1, 1] = sw
    info[:, 0, 2] = info[:, 2, 0] = a
    info[:, 1, 2] = info[:, 2, 1] = b
    info[:, 2, 2] = (w * (rx * rx + ry * ry)).sum(axis=1)
    return np.linalg.inv(info)


def _tag_candidate(
    mTt: FloatArray, map_cov: FloatArray, vTt: FloatArray, obs_cov: FloatArray
) -> _Gaussian:
    """``mTv = mTt * inverse(vTt)`` with both covariances propagated to first order."""
    q = inverse(vTt)
    mTv = compose(mTt, q)
    x, y, th = vTt
    c, s = math.cos(th), math.sin(th)
    J_inv = np.array([[-c, -s, s * x - c * y], [s, -c, c * x + s * y], [0.0, 0.0, -1.0]])
    ca, sa = math.cos(mTt[2]), math.sin(mTt[2])
    J_a = np.array(
        [[1.0, 0.0, -sa * q[0] - ca * q[1]], [0.0, 1.0, ca * q[0] - sa * q[1]], [0.0, 0.0, 1.0]]
    )
    J_b = np.array([[ca, -sa, 0.0], [sa, ca, 0.0], [0.0, 0.0, 1.0]])
    J_o = J_b @ J_inv
    cov = J_a @ map_cov @ J_a.T + J_o @ obs_cov @ J_o.T
    cov = 0.5 * (cov + cov.T) + np.eye(3) * 1e-12
    return _Gaussian(mTv, cov)
