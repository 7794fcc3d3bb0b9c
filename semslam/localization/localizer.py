"""The online localizer: one filter step per camera frame, with health and recovery.

Per frame (observations in the vehicle frame, time ``t``):

1. the odometry samples up to ``t`` are applied (predict to each sample, update ``v`` and
   ``yaw_rate`` with it), then the state is predicted to ``t``;
2. the observations are associated against the local map (:mod:`.association`);
3. all associated measurements are stacked into one update (EKF or sigma points) and the
   whole frame is dropped if its normalised innovation exceeds the frame gate (Houben);
4. health: ``tracking`` when an update was applied, ``coasting`` when nothing was
   applied, ``lost`` when the position uncertainty exceeds its limit, several frames in
   a row had at least two observations of which none could be used (painted lines seen
   where the map holds no line within their range are paint the map does not hold, not
   counted), or the slot IDs read confidently on the associated slots contradict the
   map's (at least ``label_contradiction`` of the last ``label_check_window``: a wrong
   map, or a pose the geometry alone keeps on the wrong slots; misreads are far rarer);
   ``relocalized`` on
   the frame the pose came from global relocalization (:mod:`.relocalize`: tags, or
   several confidently read slot IDs that agree); the position covariance is floored at
   the associated map landmarks' own covariance and the heading variance at the
   associated slots' orientation variance (map errors do not average out); the heading
   variance reported is at least the orientation variance of the map's slots near the car
   (painted lines carry no covariance, so frames updated by lines alone would not hold it);
5. recovery: while lost, and every ``check_every`` frames while tracking, the last
   seconds of frames (:mod:`.recent`) are relocalized globally; a global pose that
   contradicts the filter (outside the gate) twice in a row, or any global pose while
   lost, resets the filter there. Once tracking has begun, a far jump backed by one tag
   alone is refused while slots or tags keep the car on track (a moved tag must not
   teleport it), and allowed once none has been applied for ``lone_tag_after`` s (a kidnap
   that one tag sees); a tag rejected in frames whose slots or tags were applied, or whose
   jump left the car lost before slots agreed, is suspect and kept out of global fixes
   until the filter takes it again. So a wrong start, a
   kidnap or a divergence is repaired from the map alone, and ``--init auto`` is the same
   mechanism started in the ``initializing`` state.

Poses and covariances are in the map frame (m, rad); times in seconds.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict, deque
from dataclasses import dataclass, replace

import numpy as np

from semslam.chi2 import chi2_quantile
from semslam.config import LocalizationConfig
from semslam.errors import DriveError
from semslam.geometry import FloatArray, wrap_angle
from semslam.io.odometry import check_covered, odometry_span
from semslam.localization.association import LocalMap
from semslam.localization.filter import (
    CALIBRATED_STATES,
    CTRV_STATES,
    CtrvFilter,
    ProcessNoise,
)
from semslam.localization.measurements import stack
from semslam.localization.recent import RecentFrames
from semslam.localization.relocalize import Relocalizer
from semslam.motion import ctrv_predict
from semslam.types import FrameObservations, SemanticMap

_PLAUSIBLE_CHI2 = chi2_quantile(0.99999, 3)  # a global fix this far from the filter: a jump
SUSPECT_AFTER = 3  # frames in a row a tag is rejected, slots or tags applied: suspect

INITIALIZING, TRACKING, COASTING, LOST, RELOCALIZED = (
    "initializing", "tracking", "coasting", "lost", "relocalized"
)


def unsure_labels_dropped(semantic_map: SemanticMap, minimum: float) -> SemanticMap:
    """The map with every slot label less likely than ``minimum`` to be right removed (the
    slot stays, unlabelled): an ID the mapper read once, unsurely, must not pull a
    confidently read ID onto the wrong slot, nor place the car by it."""
    slots = tuple(
        replace(s, label=None, label_confidence=0.0)
        if s.label is not None and s.label_confidence < minimum
        else s
        for s in semantic_map.slots
    )
    return replace(semantic_map, slots=slots)


@dataclass(frozen=True)
class FrameEstimate:
    """The localizer's answer for one frame."""

    t: float
    pose: FloatArray  # (3,) x, y, yaw in the map frame; NaN while initializing
    covariance: FloatArray  # (3, 3)
    status: str
    associated: int
    rejected: int
    update_ms: float  # association + update (the filter's work for the frame's observations)


class Localizer:
    """Track a vehicle in ``semantic_map`` from odometry and per-frame observations.

    Args:
        semantic_map: the map (from ``semslam map``).
        cfg: the ``localization`` configuration section.
        odometry_t, odometry_speed, odometry_yaw_rate: (N,) samples (s, m/s, rad/s), each
            holding until the next one.
        initial_pose: (3,) known start pose, or None to find it from the map (auto).
    """

    def __init__(
        self,
        semantic_map: SemanticMap,
        cfg: LocalizationConfig,
        odometry_t: FloatArray,
        odometry_speed: FloatArray,
        odometry_yaw_rate: FloatArray,
        initial_pose: FloatArray | None = None,
    ) -> None:
        self.cfg = cfg
        semantic_map = unsure_labels_dropped(semantic_map, cfg.map_label_confidence_min)
        self.local_map = LocalMap(semantic_map, cfg)
        self.relocalizer = Relocalizer(
            semantic_map,
            min_label_confidence=cfg.relocalize_label_confidence,
            min_slots=cfg.relocalize_min_slots,
            max_tag_range=cfg.tag_range_limit,
            single_slot_reads=cfg.relocalize_single_slot_reads,
        )
        self.odo_t = np.asarray(odometry_t, dtype=float)
        self.odo_v = np.asarray(odometry_speed, dtype=float)
        self.odo_w = np.asarray(odometry_yaw_rate, dtype=float)
        self._span = odometry_span(self.odo_t)  # frames after its end are refused
        noise = ProcessNoise(
            cfg.acceleration_sigma, cfg.yaw_acceleration_sigma, cfg.position_walk, cfg.yaw_walk,
            cfg.speed_scale_walk, cfg.gyro_bias_walk,
        )
        n = CALIBRATED_STATES if cfg.estimate_odometry_errors else CTRV_STATES
        self.filter = CtrvFilter(np.zeros(n), np.eye(n), noise, cfg.sigma_alpha)
        self.initialized = False
        self.t: float | None = None
        self._next_odometry = 0
        self._failures = 0  # frames in a row with observations and nothing applied
        self._landmark_t: float | None = None  # last slot or tag update applied (or reset)
        self._suspect_tags: set[tuple] = set()  # (family, ID): no longer in global fixes
        self._tag_misfits: dict[tuple, int] = defaultdict(int)  # rejections in a row
        self._jump_tags: set[tuple] = set()  # the tags of the last far jump on one tag alone
        self._disagreements = 0
        self._label_checks: deque[bool] = deque(maxlen=cfg.label_check_window)  # True: differs
        self._labels_contradict = False
        self._frames = 0
        self._frame_gates: dict[int, float] = {}
        self._odometry_pose = np.zeros(5)  # dead reckoning in its own frame: x, y, yaw, v, w
        self.recent = RecentFrames(cfg.relocalize_window)
        if initial_pose is not None:
            sp, sy = cfg.init_position_sigma, math.radians(cfg.init_yaw_sigma_deg)
            self._reset(np.asarray(initial_pose, dtype=float), np.diag([sp**2, sp**2, sy**2]))

    # ------------------------------------------------------------------ public
    def step(self, frame: FrameObservations) -> FrameEstimate:
        """Process one frame; frames must come in time order.

        Raises:
            DriveError: the frame's time is not a number, time went back, or the frame is
                before the first odometry sample (where the drive's start pose is) or more
                than one odometry period after the last (odometry.csv cut short).
        """
        if not math.isfinite(frame.t):
            raise DriveError(f"frame time {frame.t}: not a finite number of seconds")
        if self.t is not None and frame.t < self.t:
            raise DriveError(f"frame at {frame.t:.3f} s comes after {self.t:.3f} s: time went back")
        check_covered(frame.t, self._span, start=True)
        if not (self.cfg.use_slots and self.cfg.use_tags):  # switched-off sensors: unseen
            frame = replace(
                frame,
                slots=frame.slots if self.cfg.use_slots else (),
                tags=frame.tags if self.cfg.use_tags else (),
            )
        self._advance(frame.t)
        if self._landmark_t is None:
            self._landmark_t = self.t
        self._frames += 1
        self.recent.add(self._odometry_pose[:3], frame)
        if not self.initialized:
            return self._try_relocalize(frame, INITIALIZING)
        started = time.perf_counter()
        assoc = self.local_map.associate(frame, self.filter.pose, self.filter.pose_covariance)
        applied = 0
        rejected = assoc.rejected_total
        if assoc.count:
            z, R, measurements = stack(assoc.measurements)
            innovation = self.filter.innovation(measurements, R, self.cfg.update)
            if innovation.nis <= self._frame_gate(len(z)):
                self.filter.apply(innovation)
                self._floor_to_map(assoc)
                applied = assoc.count
                if assoc.slots or "tag" in assoc.kinds:
                    self._landmark_t = self.t
                    self._count_tag_misfits(assoc)
                if assoc.slots:
                    self._jump_tags = set()  # slots agree with where the tag put the car
            else:
                rejected += assoc.count
        update_ms = (time.perf_counter() - started) * 1e3
        # one odd observation is no failure, nor paint seen where the map holds none
        considered = assoc.count + assoc.rejected_total - assoc.unmapped
        self._failures = 0 if applied or considered < 2 else self._failures + 1
        self._check_labels(frame, assoc)
        sigma = math.sqrt(max(np.linalg.eigvalsh(self.filter.P[:2, :2])))
        lost = (
            sigma > self.cfg.lost_position_sigma
            or self._failures >= self.cfg.lost_rejections
            or self._labels_contradict
        )
        if lost:
            self._suspect_tags |= self._jump_tags
            self._jump_tags = set()
            return self._try_relocalize(frame, LOST, applied, rejected, update_ms)
        if self._frames % self.cfg.check_every == 0 and self._contradicted(frame):
            return self._try_relocalize(frame, LOST, applied, rejected, update_ms)
        status = TRACKING if applied else COASTING
        return self._estimate(status, applied, rejected, update_ms)

    @property
    def odometry_errors(self) -> tuple[FloatArray, FloatArray] | None:
        """The estimated wheel-speed scale error (relative) and gyro bias (rad/s), and their
        1-sigma, once a pose is known and while the filter estimates them; else None."""
        if not (self.initialized and self.filter.calibrated):
            return None
        return self.filter.x[5:].copy(), np.sqrt(np.diag(self.filter.P)[5:])

    # ------------------------------------------------------------------ internals
    def _advance(self, t: float) -> None:
        """Apply odometry samples up to ``t`` and predict to ``t``."""
        f = self.filter
        while self._next_odometry < len(self.odo_t) and self.odo_t[self._next_odometry] <= t:
            i = self._next_odometry
            if self.t is not None:
                f.predict(self.odo_t[i] - self.t)
                self._odometry_pose = ctrv_predict(self._odometry_pose, self.odo_t[i] - self.t)
            self._odometry_pose[3:] = self.odo_v[i], self.odo_w[i]
            self.t = float(self.odo_t[i])
            f.update_odometry(self.odo_v[i], self.odo_w[i], self.cfg.speed_sigma,
                              self.cfg.yaw_rate_sigma)
            self._next_odometry += 1
        if self.t is not None:
            f.predict(t - self.t)
            self._odometry_pose = ctrv_predict(self._odometry_pose, t - self.t)
        self.t = t

    def _floor_to_map(self, assoc) -> None:
        """The pose cannot be known better than the map it was measured against: map
        errors are shared by every frame that sees the same landmarks, so they do not
        average out. The position covariance is raised (in the PSD sense) to the mean
        covariance of the associated slot corners (or, with markings only, the mean map
        variance across the associated lines, ``marking_map_sigma`` squared at least) times
        ``map_floor_scale``, and the heading variance to the mean orientation variance of
        the associated slots times the same."""
        slots = assoc.slots
        if self.cfg.map_floor_scale <= 0 or not (slots or "marking" in assoc.kinds):
            return
        k = self.cfg.map_floor_scale
        if slots:  # a frame has a few slots: Python floats beat array calls here
            terms = zip(*(self.local_map.floor_terms[i] for i in slots), strict=True)
            xx, xy, yy, heading = (k * sum(column) / len(slots) for column in terms)
        else:  # markings only: the lines' own map variance (the configured one at least)
            xx = yy = k * assoc.marking_map_var
            xy = heading = 0.0
        P = self.filter.P
        a, b, c = _positive_part(
            xx - float(P[0, 0]), xy - 0.5 * float(P[0, 1] + P[1, 0]), yy - float(P[1, 1])
        )
        P[0, 0] += a
        P[0, 1] += b
        P[1, 0] += b
        P[1, 1] += c
        P[2, 2] = max(P[2, 2], k * heading)

    def _frame_gate(self, dof: int) -> float:
        if dof not in self._frame_gates:
            self._frame_gates[dof] = chi2_quantile(self.cfg.frame_gate, dof)
        return self._frame_gates[dof]

    def _check_labels(self, frame: FrameObservations, assoc) -> None:
        """Compare the IDs read confidently (``id_confidence_high``) on the associated slots
        with the map's labels; the map is contradicted when at least ``label_contradiction``
        of the last ``label_check_window`` differ, and no longer when under half of that."""
        for o, j in zip(assoc.slot_observations, assoc.slots, strict=True):
            read, mapped = frame.slots[o], self.local_map.slots[j]
            if (read.label is not None and mapped.label is not None
                    and read.label_confidence >= self.cfg.id_confidence_high):
                self._label_checks.append(read.label != mapped.label)
        window = self._label_checks
        if len(window) == window.maxlen:
            share = sum(window) / len(window)
            if share >= self.cfg.label_contradiction:
                self._labels_contradict = True
            elif share < 0.5 * self.cfg.label_contradiction:
                self._labels_contradict = False

    def _count_tag_misfits(self, assoc) -> None:
        """A tag rejected in ``SUSPECT_AFTER`` frames in a row where slots or tags were
        applied is suspect (moved, or a misdetection; one rejection now and then is the
        gate's own false alarm) until the filter takes it again."""
        for key in assoc.accepted_tags:
            self._tag_misfits[key] = 0
            self._suspect_tags.discard(key)
        for key in assoc.rejected_tags:
            self._tag_misfits[key] += 1
            if self._tag_misfits[key] >= SUSPECT_AFTER:
                self._suspect_tags.add(key)

    def _contradicted(self, frame: FrameObservations) -> bool:
        """Does a global relocalization of this frame contradict the filter (twice in a row)?"""
        found, _, lone_tag_may_move = self._locate(frame)
        if found is None or (_one_tag(found) and self._failures == 0 and not lone_tag_may_move):
            # a tag alone does not overrule a filter whose updates pass: a tag that moved,
            # or a misdetection, must not teleport a car that is tracking well
            return False
        self._disagreements = 0 if self._plausible(found) else self._disagreements + 1
        return self._disagreements >= 2

    def _try_relocalize(self, frame, status_if_not, applied=0, rejected=0, update_ms=0.0):
        found, seen, lone_tag_may_move = self._locate(frame)
        if found is None:
            return self._estimate(status_if_not, applied, rejected, update_ms)
        tag_jump = self.initialized and _one_tag(found) and not self._plausible(found)
        if tag_jump and not lone_tag_may_move:
            # once tracking has begun, a far jump needs slots or tags to back it, not one tag
            return self._estimate(status_if_not, applied, rejected, update_ms)
        self._reset(found.mTv, found.covariance)
        if tag_jump:  # should the car be lost again before slots agree, the tag lied
            self._jump_tags = {(t.family, t.tag_id) for t in seen.tags}
        return self._estimate(RELOCALIZED, applied, rejected, update_ms)

    def _locate(self, frame: FrameObservations):
        """A global fix from the recent frames (or this one) without the suspect tags (None
        if none), the frame it was sought in, and whether one tag alone may move the car far.

        One tag alone may move it only once no slot or tag has been applied for
        ``lone_tag_after`` seconds: the car then holds its pose by dead reckoning, or by
        painted lines, which repeat from aisle to aisle, and a tag that keeps contradicting
        it is more likely right (a kidnap, a divergence) than moved. A car that slots or tags
        keep on track is not moved by one tag. A tag rejected while slots or tags were
        applied, or one whose jump left the car lost before slots agreed, is suspect (moved,
        or a misdetection): it no longer takes part in global fixes."""
        seen = self.recent.merged() or frame
        if self._suspect_tags:
            seen = replace(seen, tags=tuple(
                t for t in seen.tags if (t.family, t.tag_id) not in self._suspect_tags
            ))
        after = self.cfg.lone_tag_after
        may_move = after > 0 and self.t - self._landmark_t >= after
        return self.relocalizer.locate(seen), seen, may_move

    def _plausible(self, found) -> bool:
        """Is a global fix within the gate of the filter's own (perhaps inflated) belief?"""
        e = found.mTv - self.filter.pose
        e[2] = wrap_angle(e[2])
        S = found.covariance + self.filter.pose_covariance
        return float(e @ np.linalg.solve(S, e)) <= _PLAUSIBLE_CHI2

    def _reset(self, pose: FloatArray, covariance: FloatArray) -> None:
        i = max(self._next_odometry - 1, 0)
        v = self.odo_v[i] if len(self.odo_v) else 0.0
        w = self.odo_w[i] if len(self.odo_w) else 0.0
        f, cfg = self.filter, self.cfg
        x = np.zeros(len(f.x))
        P = np.zeros((len(f.x), len(f.x)))
        x[:5] = *pose, v, w
        P[:3, :3] = covariance
        P[3, 3], P[4, 4] = cfg.speed_sigma**2, cfg.yaw_rate_sigma**2
        if f.calibrated:  # the odometry's errors survive a jump of the pose
            if self.initialized:
                x[5:], P[5:, 5:] = f.x[5:], f.P[5:, 5:]
            else:
                P[5, 5], P[6, 6] = cfg.speed_scale_prior_sigma**2, cfg.gyro_bias_prior_sigma**2
            x[3] = v / (1.0 + x[5])
            x[4] = w - x[6]
        f.reset(x, P)
        self.initialized = True
        self._failures = 0
        self._disagreements = 0
        self._landmark_t = self.t
        self._jump_tags = set()
        self._label_checks.clear()
        self._labels_contradict = False

    def _estimate(self, status, associated, rejected, update_ms) -> FrameEstimate:
        if not self.initialized:
            pose, cov = np.full(3, np.nan), np.full((3, 3), np.nan)
        else:
            pose, cov = self.filter.pose, self._reported_covariance()
        return FrameEstimate(float(self.t), pose, cov, status, associated, rejected, update_ms)

    def _reported_covariance(self) -> FloatArray:
        """The filter's pose covariance with its heading variance raised to the map's own
        heading error where the car is (``map_floor_scale`` times the mean orientation
        variance of the map's slots within ``map_heading_radius``). The filter measures its
        heading against the map; a frame updated with slots is floored at their heading error
        inside the filter (:meth:`_floor_to_map`), but painted lines carry no covariance of
        their own, and a filter that follows lines alone grows surer of its heading than the
        map is. Only the report is raised: a heading floor inside the filter lets each next
        line turn it (BENCHMARKS.md, "The markings-only filter is too sure of itself")."""
        cov = self.filter.pose_covariance
        k, radius = self.cfg.map_floor_scale, self.cfg.map_heading_radius
        if k <= 0 or radius <= 0:
            return cov
        heading = self.local_map.heading_variance_near(self.filter.pose, radius)
        if heading is not None and cov[2, 2] < k * heading:
            cov[2, 2] = k * heading  # pose_covariance is a copy
        return cov


def positive_part_2x2(A: FloatArray) -> FloatArray:
    """The positive semi-definite part of a symmetric 2x2 matrix (its negative eigenvalue,
    if any, set to 0), in closed form."""
    a, b, c = _positive_part(float(A[0, 0]), 0.5 * float(A[0, 1] + A[1, 0]), float(A[1, 1]))
    return np.array([[a, b], [b, c]])


def _positive_part(a: float, b: float, c: float) -> tuple[float, float, float]:
    """:func:`positive_part_2x2` of ``[[a, b], [b, c]]``, as its entries ``a, b, c``."""
    mean, radius = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    high, low = mean + radius, mean - radius
    if low >= 0.0:
        return a, b, c
    if high <= 0.0:
        return 0.0, 0.0, 0.0
    # high * v v^T, with v v^T = (A - low I) / (high - low)
    scale = high / (high - low)
    return scale * (a - low), scale * b, scale * (c - low)


def _one_tag(found) -> bool:
    """A global fix from one tag alone (no slot, no second tag agreeing)."""
    return found.source == "tags" and found.tags_used < 2
