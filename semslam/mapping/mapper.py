"""The offline mapper: keyframes, odometry, tags and slots on a robust factor graph.

Follows TiEV (DESIGN.md) with the association made exact:

- a keyframe every ``keyframe_distance`` metres or ``keyframe_angle_deg`` of turn;
  odometry between keyframes from the CTRV integration of wheel speed and gyro
  with a covariance that grows with distance;
- tags are trusted and associated by ID (relative Pose2, dropped beyond the range
  limit); a sighting that places its tag farther from the tag's estimate than
  ``tag_conflict_distance`` plus ``tag_conflict_per_m`` of the distance driven since the tag
  was last seen (one ID printed twice, not drift) is counted in ``tag_conflicts`` and left
  out;
- a slot observation's candidates are the nearest mapped slots within a gate plus,
  when its ID is confident, the slot holding that ID; one candidate becomes a
  native-style factor whose loss is a max-mixture with the null hypothesis,
  several become one multi-hypothesis max-mixture factor (plus null);
- the slot detections of the frames between keyframes are fused into the keyframe's
  (:mod:`.frame_fusion`);
- with no candidate the sighting waits in a pool and becomes a new landmark after
  M consistent sightings (within ``pool_radius``, the last M from M keyframes and
  agreeing with their mean as their corner sigmas say: ghosts come several at a time
  and scatter), unless it overlaps a mapped slot;
  duplicates (same place, compatible ID) are merged by
  tight equality factors; optionally, loop closures by agreeing IDs when the drift
  exceeds the gates (:mod:`.loop_closure`, off by default);
- iSAM2 every ``update_every`` keyframes (the map is usable at any time), a final
  batch Levenberg-Marquardt, marginal covariances for every landmark;
- labels: each slot keeps the label its *accepted* observations voted for most
  (summed confidence), with the probability that it is right given every reading
  (:func:`.landmarks.label_probability`) as its confidence.

Everything is in the map frame anchored at the drive's start pose.
"""

from __future__ import annotations

import functools
import itertools
import math
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import gtsam
import numpy as np

from semslam.config import MappingConfig
from semslam.errors import MappingError
from semslam.geometry import (
    FloatArray,
    compose,
    rotate_pose_covariance,
    rotation_variance,
    transform_points,
    wrap_angle,
)
from semslam.io.odometry import check_covered, odometry_span
from semslam.mapping.factors import (
    calibrated_odometry_residual,
    custom_factor,
    marking_observation_residual,
    same_line_residual,
    slot_observation_residual,
    slot_shape_residual,
)
from semslam.mapping.frame_fusion import fuse_detection, slots_in_keyframe
from semslam.mapping.graph import Graph
from semslam.mapping.landmarks import (
    PooledSlot,
    SlotLandmark,
    SlotLandmarks,
    SlotPool,
    label_probability,
    mean_corner_distance,
)
from semslam.mapping.lines import LineLandmarks, end_covariance, segment_sigma
from semslam.mapping.loop_closure import ClosureVote, IdLoopClosure, correction_to
from semslam.mapping.markings import merge_marking_observations, robust_extent
from semslam.mapping.maxmix import (
    Component,
    MaxMixture,
    NullHypothesis,
    is_null_chosen,
    null_hypothesis_noise,
)
from semslam.mapping.odometry import calibration_jacobian, odometry_between, pose_between
from semslam.mapping.shared_error import (
    SlotSightingFactor,
    has_shared_error,
    sandwich_covariances,
)
from semslam.types import (
    FrameObservations,
    Marking,
    MarkingObservation,
    SemanticMap,
    Slot,
    SlotKind,
    SlotObservation,
    Tag,
)

X = gtsam.symbol_shorthand.X  # keyframe poses
C = gtsam.symbol_shorthand.C  # slot corners: C(4 * slot + k)
T = gtsam.symbol_shorthand.T  # tags
K = gtsam.symbol_shorthand.K  # odometry calibration (speed scale, gyro bias)
L = gtsam.symbol_shorthand.L  # painted lines (theta, d)

_SHAPE_PRIORS = {  # (right angles, entrance width m, depth m, width sigma, depth sigma)
    SlotKind.PERPENDICULAR: (True, 2.5, 5.0, 0.4, 0.6),
    SlotKind.PARALLEL: (True, 6.0, 2.5, 1.0, 0.4),
    SlotKind.SLANTED: (False, 3.0, 5.0, 1.0, 0.6),
}


TAG_CONDITION_FLOOR = 1e-11
"""A tag sighting's covariance gets at least this share of its largest variance on every axis
(and 1e-8 absolutely): a sighting sure on one axis and vague on another (variances 1e-13 and
1, say) would otherwise give a graph edge no solver can use, and one the g2o export refuses
(condition number above 1e12)."""

_REFRESH_RADIUS = 25.0  # m around the car where landmark estimates are kept current


@functools.lru_cache
def _consistent_chi2(m: int) -> float:
    """Chi-square bound on M sightings of one slot about their mean: 8 (M - 1) degrees of
    freedom, exceeded by chance once in 10,000."""
    from scipy.special import chdtri  # scipy.stats would cost 0.4 s of import

    return float(chdtri(8 * (m - 1), 1e-4))


class SightingStatus(StrEnum):
    """What became of one slot observation (the association audit)."""

    POOLED = "pooled"  # waiting, never reached M sightings
    ACCEPTED = "accepted"  # its factor sits on a landmark's component
    NULL = "null"  # its factor sits on the null hypothesis
    REASSIGNED = "reassigned"  # accepted, but by another candidate than the nearest at first


@dataclass
class Sighting:
    """One slot observation at a keyframe and what the mapper did with it."""

    t: float
    keyframe: int
    observation: SlotObservation
    candidates: list[int] = field(default_factory=list)  # landmark index per component
    first_choice: int | None = None
    factor: object | None = None  # gtsam factor or MaxMixture
    fused: int = 1  # detections averaged into this one (frame_fusion)
    status: SightingStatus = SightingStatus.POOLED
    landmark: int | None = None
    sigma: float | None = None  # m, the corner sigma of its factor (``_observation_sigma``)


@dataclass(frozen=True, eq=False)
class MappingResult:
    """The map, the keyframe trajectory (times (K,), poses (K, 3)), the audit, statistics."""

    map: SemanticMap
    keyframe_times: FloatArray
    keyframe_poses: FloatArray
    sightings: tuple[Sighting, ...]
    statistics: dict
    odometry_edges: tuple  # (k-1, k, relative pose (3,) after calibration, covariance (3, 3)
    # along k's axes, as the between error)
    tag_edges: tuple  # (keyframe, tag id, vTt (3,), covariance (3, 3))
    slot_of_landmark: dict[int, int]  # landmark index (after merges) -> Slot.id in the map


def _marginal(marginals, keys: int | list[int]) -> FloatArray | None:
    """The marginal covariance of one key, or the joint one of a list of keys (blocks in their
    order), from :meth:`Graph.marginals`' answer (gtsam's Marginals or a QR Bayes tree, in
    two tiers of vague priors); None when the whole graph was refused (``marginals`` None)
    or this clique at both tiers (ill-conditioned): the caller falls back."""
    if marginals is None:
        return None
    try:
        if isinstance(keys, list):
            return np.asarray(marginals.jointMarginalCovariance(keys).fullMatrix(), dtype=float)
        return np.asarray(marginals.marginalCovariance(keys), dtype=float)
    except RuntimeError:
        return None


_SEEN_FROM_REACH = 100  # keyframes (50 m at 0.5 m each) searched either way for a marginal


def _pose_spread(poses: FloatArray, centre: FloatArray) -> FloatArray:
    """(3, 3) sample covariance of poses (N, 3) about ``centre``, yaw differences wrapped (a
    tag facing +-pi has sightings on both sides of the cut)."""
    d = np.asarray(poses, dtype=float) - centre
    d[:, 2] = wrap_angle(d[:, 2])
    return d.T @ d / (len(d) - 1)


class Mapper:
    """Builds a semantic map frame by frame; call :meth:`add_frame` in time order, then
    :meth:`finish`."""

    def __init__(
        self,
        config: MappingConfig,
        start_pose: FloatArray,
        odometry_t: FloatArray,
        odometry_speed: FloatArray,
        odometry_yaw_rate: FloatArray,
    ) -> None:
        self.cfg = config
        self.odo = (
            np.asarray(odometry_t),
            np.asarray(odometry_speed),
            np.asarray(odometry_yaw_rate),
        )
        self._span = odometry_span(self.odo[0])  # frames must lie within it
        self.use_graph = config.optimizer == "isam2"
        self.robust = config.robust == "maxmix"
        self.null = NullHypothesis(config.null_weight, config.null_information_scale)
        self.graph = Graph(
            config.relinearize_threshold, config.relinearize_skip, config.reorder_growth,
            config.rebuild_share,
        )
        self.slots = SlotLandmarks()
        self.pool = SlotPool(config.pool_radius, config.pool_max_age)
        self.sightings: list[Sighting] = []
        self.keyframe_times: list[float] = []
        self.keyframe_poses: list[FloatArray] = []  # current estimates (dead reckoning if no graph)
        self.tags: dict[int, dict] = {}
        self._start = np.asarray(start_pose, dtype=float)
        self._between: list[tuple[FrameObservations, FloatArray]] = []  # since the keyframe
        # (time, pose in the last keyframe's frame) of the last frame: see _pose_since_keyframe
        self._since_keyframe: tuple[float, FloatArray] = (0.0, np.zeros(3))
        self._timing = {"update_s": 0.0, "association_s": 0.0}
        self._last_update = 0  # keyframe of the last iSAM2 update
        self._slot_observation_sums: dict[int, list[FloatArray]] = {}
        self.calibration = np.array([1.0, 0.0])  # current (speed scale, gyro bias) estimate
        self._label_votes: list[tuple[int, str, float]] = []  # from frames between keyframes
        self.odometry_edges: list[tuple] = []  # (k-1, k, delta, covariance, calibration J)
        self.tag_edges: list[tuple] = []  # (k, tag id, vTt, covariance)
        self.tag_mismatches: list[tuple] = []  # (k, tag id, family, size) refused
        self.tag_conflicts: list[tuple] = []  # (k, tag id, m from the tag) refused
        self._odometer: list[float] = []  # metres driven (odometry) up to each keyframe
        self._marginal_fallbacks = 0  # slots, tags and lines whose marginal gtsam refused
        # (slots and tags then take the spread of their sightings; lines get no sigma)
        self.lines = LineLandmarks(
            config.marking_angle_tolerance_deg,
            config.marking_distance_gate,
            config.marking_gap,
            config.marking_min_support,
        )
        self.closure = IdLoopClosure(config.loop_closure_window, config.loop_closure_support)
        self._landmarks_of_label: dict[str, set[int]] = {}  # landmarks that got a vote
        self.marking_detections: list[tuple[int, FloatArray, float, float]] = []
        # (keyframe, end points (2, 2) vehicle frame, width, confidence): every one used
        self._slot_factors: list[tuple[int, Sighting, int | None]] = []
        # (graph factor index, its sighting, the landmark of a loop-closure factor; None:
        # the sighting's own factor, on the landmark it ends on): for shared_error

    # ------------------------------------------------------------------ frames
    def add_frame(self, frame: FrameObservations) -> bool:
        """Add a frame; returns True if it became a keyframe.

        Raises:
            DriveError: the frame lies outside the odometry (before its first sample, or
                more than one sample period after its last one).
        """
        check_covered(frame.t, self._span, start=True)
        if not self.keyframe_times:
            self._add_keyframe(frame.t, self._start, None)
            self._observe(frame)
            return True
        t_prev = self.keyframe_times[-1]
        delta = self._pose_since_keyframe(frame.t)
        moved = math.hypot(delta[0], delta[1])
        turned = abs(math.degrees(delta[2]))
        if moved < self.cfg.keyframe_distance and turned < self.cfg.keyframe_angle_deg:
            self._read_labels_between_keyframes(frame, compose(self.keyframe_poses[-1], delta))
            if frame.slots and self.cfg.fuse_frames_max > 1:
                self._between.append((frame, delta))
            return False
        delta, cov = odometry_between(
            *self.odo,
            t_prev,
            frame.t,
            self.cfg.speed_sigma,
            self.cfg.speed_scale_sigma,
            self.cfg.yaw_rate_sigma,
        )
        J = calibration_jacobian(*self.odo, t_prev, frame.t) if self._calibrating else None
        corrected = delta if J is None else delta + J @ (self.calibration - [1.0, 0.0])
        predicted = compose(self.keyframe_poses[-1], corrected)
        self._add_keyframe(frame.t, predicted, (delta, cov, J))
        self._observe(frame, slots_in_keyframe(self._between, delta))
        self._between = []
        agreed = self.closure.consensus(len(self.keyframe_times) - 1, self.keyframe_poses[-1])
        if agreed:
            self._close_loop(agreed)
        if self.use_graph and self._update_due():
            started = time.perf_counter()
            self.graph.update()
            self._refresh_estimates()
            self._merge_duplicates()
            self._last_update = len(self.keyframe_times) - 1
            self._timing["update_s"] += time.perf_counter() - started
        return True

    def _pose_since_keyframe(self, t: float) -> FloatArray:
        """Pose (x, y, yaw) at ``t`` in the last keyframe's frame, integrated on from the
        previous frame, so a car standing still for minutes (no new keyframe) costs each
        frame only its own odometry samples (integrating from the keyframe every frame made
        a 4-minute standstill 35 s of mapping). Arcs of one held sample compose exactly, so
        this is the keyframe-to-``t`` integration up to rounding."""
        t_last, last = self._since_keyframe
        delta = compose(last, pose_between(*self.odo, t_last, t))
        self._since_keyframe = (t, delta)
        return delta

    def _update_due(self) -> bool:
        """Every ``update_every`` keyframes (10, relinearising every 5th update; 20 cost
        less on `large` but broke its map: BENCHMARKS.md)."""
        return len(self.keyframe_times) - 1 - self._last_update >= self.cfg.update_every

    def _add_keyframe(self, t: float, pose: FloatArray, odometry) -> None:
        k = len(self.keyframe_times)
        step = 0.0 if odometry is None else math.hypot(odometry[0][0], odometry[0][1])
        self._odometer.append((self._odometer[-1] if self._odometer else 0.0) + step)
        self.keyframe_times.append(t)
        self.keyframe_poses.append(np.asarray(pose, dtype=float))
        self._since_keyframe = (t, np.zeros(3))
        if not self.use_graph:
            return
        self.graph.add_pose(X(k), pose)
        if odometry is None:
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
            self.graph.add_factor(gtsam.PriorFactorPose2(X(k), gtsam.Pose2(*pose), noise))
            if self._calibrating:
                self.graph.add_vector(K(0), self.calibration)
                sigmas = np.array([self.cfg.scale_prior_sigma, self.cfg.gyro_bias_prior_sigma])
                self.graph.add_factor(
                    gtsam.PriorFactorVector(
                        K(0), self.calibration, gtsam.noiseModel.Diagonal.Sigmas(sigmas)
                    )
                )
            return
        delta, cov, J = odometry
        # odometry_between gives the covariance along k-1's axes; the between error (gtsam's,
        # g2o's, calibrated_odometry_residual's) is along k's
        cov = rotate_pose_covariance(cov, -delta[2])
        self.odometry_edges.append((k - 1, k, delta, cov, J))
        noise = gtsam.noiseModel.Gaussian.Covariance(cov)
        if J is None:
            self.graph.add_factor(
                gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(*delta), noise)
            )
            return
        window = k // self.cfg.calibration_window
        if not self.graph.has(K(window)):
            self.graph.add_vector(K(window), self.calibration)
            walk = gtsam.noiseModel.Diagonal.Sigmas(np.array(self.cfg.calibration_walk))
            self.graph.add_factor(
                gtsam.BetweenFactorVector(K(window - 1), K(window), np.zeros(2), walk)
            )
        self.graph.add_factor(
            custom_factor(
                [X(k - 1), X(k), K(window)],
                calibrated_odometry_residual(X(k - 1), X(k), K(window), delta, J),
                noise,
            )
        )

    def _observe(
        self, frame: FrameObservations, between: Sequence[SlotObservation] = ()
    ) -> None:
        """Add a keyframe's observations; ``between``: slot detections of the frames since
        the last keyframe, in this keyframe's vehicle frame (fused into its own)."""
        k = len(self.keyframe_times) - 1
        started = time.perf_counter()
        for tag in frame.tags:
            self._add_tag(k, tag)
        for obs in frame.slots:
            fused, count = fuse_detection(
                obs, between, self.cfg.fuse_radius, self.cfg.fuse_frames_max
            )
            self._add_slot_sighting(k, frame.t, fused, count)
        self.pool.expire(k)
        if self.cfg.use_markings:
            for marking in frame.markings:
                self._add_marking(k, marking)
            self.lines.expire(k)
        self._timing["association_s"] += time.perf_counter() - started

    # ------------------------------------------------------------------ tags
    def _add_tag(self, k: int, tag) -> None:
        if math.hypot(tag.vTt[0], tag.vTt[1]) > self.cfg.tag_range_limit:
            return
        pose = self.keyframe_poses[k]
        info = self.tags.setdefault(
            tag.tag_id, {"family": tag.family, "size": tag.size, "heights": [], "poses": []}
        )
        if abs(tag.size - info["size"]) > 0.01 * info["size"] or tag.family != info["family"]:
            # a tag of another size (or family) under the same ID: another tag, or a wrong
            # size setting; its range would be wrong by the ratio, so it is reported, not used
            self.tag_mismatches.append((k, tag.tag_id, str(tag.family), float(tag.size)))
            return
        mTt = compose(pose, tag.vTt)
        key = T(tag.tag_id)
        if info["poses"]:
            known = self.graph.pose(key) if self.use_graph else info["poses"][0]
            last = info["poses"][-1]  # the estimate lags iSAM2's next update
            apart = min(math.hypot(mTt[0] - known[0], mTt[1] - known[1]),
                        math.hypot(mTt[0] - last[0], mTt[1] - last[1]))
            driven = self._odometer[k] - self._odometer[info["last_keyframe"]]
            if apart > self.cfg.tag_conflict_distance + self.cfg.tag_conflict_per_m * driven:
                # the same ID printed twice, at two places: the sighting would drag the whole
                # map (trusted tags have no null); the first place seen keeps the ID. Drift
                # since the tag was last seen is allowed for: a loop closed on a tag is kept
                self.tag_conflicts.append((k, tag.tag_id, apart))
                return
        info["last_keyframe"] = k
        info["heights"].append(tag.height)
        info["poses"].append(mTt)
        if not self.use_graph:
            return
        if not self.graph.has(key):
            self.graph.add_pose(key, compose(pose, tag.vTt))
        # the sighting's covariance is along the vehicle's axes, the between error along the tag's
        cov = rotate_pose_covariance(tag.covariance, -tag.vTt[2])
        cov = cov + np.eye(3) * max(1e-8, TAG_CONDITION_FLOOR * float(np.linalg.eigvalsh(cov)[-1]))
        self.tag_edges.append((k, tag.tag_id, np.asarray(tag.vTt, dtype=float), cov))
        # trusted, no null hypothesis: on the demo drive a null on tags dropped good image
        # tags (map 0.057 -> 0.071 m); the tag detector drops the ambiguous ones itself
        self.graph.add_factor(
            gtsam.BetweenFactorPose2(
                X(k), key, gtsam.Pose2(*tag.vTt), gtsam.noiseModel.Gaussian.Covariance(cov)
            )
        )

    # ------------------------------------------------------------------ markings
    def _add_marking(self, k: int, obs: MarkingObservation) -> None:
        """Associate a detected line piece with a line landmark (or start one)."""
        vE = np.array([obs.vA, obs.vB], dtype=float)
        if not (  # written so that a NaN end point is left out, as the localizer does
            obs.confidence >= self.cfg.marking_min_confidence
            and np.linalg.norm(vE[1] - vE[0]) >= self.cfg.marking_min_length
        ):
            return
        self.marking_detections.append((k, vE, float(obs.width), float(obs.confidence)))
        mE = transform_points(self.keyframe_poses[k], vE)
        sigma = self._line_sigma(obs)
        candidates = self.lines.candidates(mE)
        if not candidates:
            self.lines.start(mE, k).detections.append((k, vE, obs.width, sigma))
            return
        if len(candidates) > 1 and candidates[1][1] < 2 * candidates[0][1] + 0.02:
            return  # between two lines: leave it out rather than guess
        line = self.lines.items[candidates[0][0]]
        line.detections.append((k, vE, obs.width, sigma))
        if line.in_graph:
            self.lines.grow(line.index, mE)
            self._add_marking_factor(line, k, vE, sigma)
            return
        points = np.vstack([transform_points(self.keyframe_poses[j], e)
                            for j, e, _, _ in line.detections])
        self.lines.refit(line.index, points)
        if len(line.detections) >= self.cfg.marking_min_support and self.use_graph:
            self.lines.join_graph(line.index)
            self.graph.add_vector(L(line.index), np.array([line.theta, line.d]))
            for j, e, _, sigma in line.detections:
                self._add_marking_factor(line, j, e, sigma)

    def _line_sigma(self, obs: MarkingObservation) -> float:
        """1-sigma across the line of a detection's end points: the one it declares (or
        ``marking_sigma``), divided by the square root of its confidence."""
        sigma = self.cfg.marking_sigma if obs.sigma is None else obs.sigma
        return sigma / math.sqrt(max(obs.confidence, 0.05))

    def _add_marking_factor(self, line, k: int, vE: FloatArray, sigma: float) -> None:
        residual = marking_observation_residual(X(k), L(line.index), line.anchor, vE)
        noise = (
            null_hypothesis_noise(np.eye(2) * sigma * sigma, self.null)
            if self.robust
            else gtsam.noiseModel.Isotropic.Sigma(2, sigma)
        )
        self.graph.add_factor(custom_factor([X(k), L(line.index)], residual, noise))

    # ------------------------------------------------------------------ slots
    def _add_slot_sighting(self, k: int, t: float, obs: SlotObservation, fused: int) -> None:
        cfg = self.cfg
        corners = transform_points(self.keyframe_poses[k], obs.vCorners)
        sighting = Sighting(t, k, obs, fused=fused)
        index = len(self.sightings)
        self.sightings.append(sighting)
        candidates = self.slots.candidates(
            corners,
            obs.label,
            obs.label_confidence,
            cfg.association_gate,
            cfg.id_gate,
            cfg.id_confidence_high,
            cfg.max_candidates,
        )
        self._vote_for_loop_closure(k, index, corners, obs, candidates)
        if candidates:
            self._attach(sighting, candidates)
            return
        pooled = self.pool.add(corners, obs.kind, index, k)
        if len(pooled.sightings) >= cfg.new_landmark_observations and self._consistent(pooled):
            self.pool.remove(pooled)
            if self.robust and self.slots.overlapping(pooled.mean_corners, cfg.max_overlap):
                return  # a ghost of a mapped slot: its sightings stay unassociated
            landmark = self.slots.add(pooled.mean_corners, obs.kind)
            self._add_slot_variables(landmark.index, landmark.corners, landmark.kind)
            for i in pooled.sightings:
                self._attach(self.sightings[i], [(landmark.index, 0.0, False)])

    def _consistent(self, pooled: PooledSlot) -> bool:
        """Are the last M sightings of a pooled slot from M keyframes (a slot is seen once
        per keyframe, its frames fused; ghosts come several at a time) and do they agree
        with their mean as well as their corner sigmas say (chi-square, 8 (M - 1) degrees
        of freedom, 1e-4 false alarm)?"""
        m = self.cfg.new_landmark_observations
        if m < 2:
            return True
        sightings = [self.sightings[i] for i in pooled.sightings[-m:]]
        if len({s.keyframe for s in sightings}) < m:
            return False
        last = np.array(pooled.corners[-m:])
        sigmas = np.array([
            max(s.observation.corner_sigma, self.cfg.slot_corner_sigma_min) for s in sightings
        ])
        chi2 = float((((last - last.mean(axis=0)) ** 2).sum(axis=(1, 2)) / sigmas**2).sum())
        return chi2 <= _consistent_chi2(m)

    def _vote_for_loop_closure(
        self, k: int, index: int, corners: FloatArray, obs: SlotObservation, candidates
    ) -> None:
        """A confident ID votes for the correction that would put this sighting on the
        landmark with that ID: a small one when the landmark is within the ID gate (the
        current pose is right), a loop closure's when it lies farther, up to the
        loop-closure radius."""
        cfg = self.cfg
        if (
            not self.use_graph
            or cfg.loop_closure_radius <= 0
            or obs.label is None
            or obs.label_confidence < cfg.id_confidence_high
        ):
            return
        by_id = [i for i, _, proposed in candidates if proposed]
        landmark = self.slots.items[by_id[0]] if by_id else self._far_landmark(obs.label, corners)
        if landmark is not None:
            self.closure.vote(
                ClosureVote(k, index, landmark.index, obs.label,
                            correction_to(corners, landmark.corners))
            )

    def _far_landmark(self, label: str, corners: FloatArray) -> SlotLandmark | None:
        """The nearest landmark holding ``label`` beyond the ID gate and within the
        loop-closure radius of map-frame ``corners`` (4, 2), or None."""
        held = [self.slots.items[i] for i in
                {self.slots.resolve(j) for j in self._landmarks_of_label.get(label, ())}]
        held = [s for s in held if s.best_label()[0] == label]
        if not held:
            return None
        d = mean_corner_distance(corners, np.array([s.corners for s in held]))
        i = int(np.argmin(d))
        return held[i] if self.cfg.id_gate < d[i] <= self.cfg.loop_closure_radius else None

    def _close_loop(self, votes: list[ClosureVote]) -> None:
        """Agreeing ID votes: their sightings become plain factors on their landmarks, the
        graph is solved, every estimate refreshed and the duplicates around merged."""
        for vote in votes:
            sighting = self.sightings[vote.sighting]
            pose_key = X(sighting.keyframe)
            keys = [C(4 * vote.landmark + c) for c in range(4)]
            index = self.graph.add_factor(
                custom_factor(
                    [pose_key, *keys],
                    slot_observation_residual(pose_key, keys, sighting.observation.vCorners),
                    gtsam.noiseModel.Isotropic.Sigma(8, self._observation_sigma(sighting)),
                )
            )
            self._slot_factors.append((index, sighting, vote.landmark))
        started = time.perf_counter()
        self.graph.update()
        self._refresh_estimates(everything=True)
        self._merge_duplicates()
        self._last_update = len(self.keyframe_times) - 1
        self._timing["update_s"] += time.perf_counter() - started

    def _add_slot_variables(self, index: int, corners: FloatArray, kind: SlotKind) -> None:
        if not self.use_graph:
            return
        keys = [C(4 * index + c) for c in range(4)]
        for key, corner in zip(keys, corners, strict=True):
            self.graph.add_point(key, corner)
        right, width, depth, sw, sd = _SHAPE_PRIORS[kind]
        sigmas = [0.02, 0.02] + ([0.02] if right else []) + [sw, sd]
        self.graph.add_factor(
            custom_factor(
                keys,
                slot_shape_residual(keys, right, width, depth),
                gtsam.noiseModel.Diagonal.Sigmas(np.array(sigmas)),
            )
        )

    def _observation_sigma(self, sighting: Sighting) -> float:
        """Corner sigma of a (fused) detection, floored and scaled by its confidence; kept
        on the sighting (the g2o export writes the information its factor had)."""
        obs = sighting.observation
        sigma = max(obs.corner_sigma, self.cfg.slot_corner_sigma_min / math.sqrt(sighting.fused))
        sighting.sigma = sigma / math.sqrt(max(obs.confidence, 0.05))
        return sighting.sigma

    def _attach(self, sighting: Sighting, candidates: list[tuple[int, float, bool]]) -> None:
        """Turn a sighting with candidate landmarks into a factor."""
        obs = sighting.observation
        sighting.candidates = [c[0] for c in candidates]
        scores = np.array(
            [1.0 + 4.0 * obs.label_confidence if by_id else 1.0 for _, _, by_id in candidates]
        )
        sighting.first_choice = sighting.candidates[
            int(np.argmax(scores / (1 + np.array([c[1] for c in candidates]))))
        ]
        sighting.status = SightingStatus.ACCEPTED
        sighting.landmark = sighting.first_choice
        if obs.label is not None:  # running votes, recounted from final decisions at the end
            chosen = self.slots.resolve(sighting.first_choice)
            self.slots.items[chosen].votes[obs.label] += obs.label_confidence
            self._landmarks_of_label.setdefault(obs.label, set()).add(chosen)
        if not self.use_graph:
            self._slot_observation_sums.setdefault(sighting.first_choice, []).append(
                transform_points(self.keyframe_poses[sighting.keyframe], obs.vCorners)
            )
            return
        sigma = self._observation_sigma(sighting)
        pose_key = X(sighting.keyframe)
        corner_keys = {i: [C(4 * i + c) for c in range(4)] for i in sighting.candidates}
        if not self.robust:  # plain least squares: the most likely candidate, Gaussian
            keys = corner_keys[sighting.first_choice]
            sighting.factor = custom_factor(
                [pose_key, *keys],
                slot_observation_residual(pose_key, keys, obs.vCorners),
                gtsam.noiseModel.Isotropic.Sigma(8, sigma),
            )
            self._slot_factors.append((self.graph.add_factor(sighting.factor), sighting, None))
            return
        if len(candidates) == 1:
            keys = corner_keys[sighting.candidates[0]]
            sighting.factor = custom_factor(
                [pose_key, *keys],
                slot_observation_residual(pose_key, keys, obs.vCorners),
                null_hypothesis_noise(np.eye(8) * sigma * sigma, self.null),
            )
            self._slot_factors.append((self.graph.add_factor(sighting.factor), sighting, None))
            return
        weights = scores / scores.sum() * (1.0 - self.null.weight)
        sqrt_info = np.eye(8) / sigma
        components = [
            Component(
                slot_observation_residual(pose_key, corner_keys[i], obs.vCorners),
                sqrt_info,
                float(w),
            )
            for i, w in zip(sighting.candidates, weights, strict=True)
        ]
        nearest = corner_keys[sighting.candidates[0]]
        components.append(
            Component(
                slot_observation_residual(pose_key, nearest, obs.vCorners),
                sqrt_info * math.sqrt(self.null.information_scale),
                self.null.weight,
            )
        )
        keys = [pose_key] + [key for i in sighting.candidates for key in corner_keys[i]]
        mixture = MaxMixture(keys, [3] + [2] * (len(keys) - 1), components)
        sighting.factor = mixture
        self._slot_factors.append((self.graph.add_factor(mixture.factor()), sighting, None))

    # ------------------------------------------------------------------ estimates
    @property
    def _calibrating(self) -> bool:
        return self.use_graph and self.cfg.calibrate_odometry

    def _refresh_estimates(self, everything: bool = False) -> None:
        """Copy estimates back: the latest keyframes and the landmarks near the car (all of
        them at the end), so the work per update does not grow with the map."""
        g = self.graph
        if self._calibrating:
            window = (len(self.keyframe_times) - 1) // self.cfg.calibration_window
            while window > 0 and not g.has(K(window)):
                window -= 1
            self.calibration = g.vector(K(window))
        first = 0 if everything else max(0, self._last_update - self.cfg.update_every)
        for k in range(first, len(self.keyframe_poses)):
            if g.has(X(k)):
                self.keyframe_poses[k] = g.pose(X(k))
        landmarks = (
            self.slots.items
            if everything
            else self.slots.near(self.keyframe_poses[-1][:2], _REFRESH_RADIUS)
        )
        for s in landmarks:
            self.slots.set_corners(
                s.index, np.array([g.point(C(4 * s.index + c)) for c in range(4)])
            )
        here = self.keyframe_poses[-1][:2]
        lines = (
            [i for i, line in enumerate(self.lines.items) if line.in_graph]
            if everything
            else self.lines.near(here, _REFRESH_RADIUS)
        )
        for i in lines:
            self.lines.set_line(int(i), *g.vector(L(int(i))))

    def _merge_duplicates(self) -> None:
        around = self.keyframe_poses[-1][:2]
        for keep, drop in self.slots.duplicates(self.cfg.merge_distance, around, _REFRESH_RADIUS):
            noise = gtsam.noiseModel.Isotropic.Sigma(2, 0.005)
            for c in range(4):
                self.graph.add_factor(
                    gtsam.BetweenFactorPoint2(C(4 * keep + c), C(4 * drop + c), np.zeros(2), noise)
                )
            self.slots.items[drop].merged_into = keep
        for keep, drop in self.lines.duplicates(around, _REFRESH_RADIUS):
            a, b = self.lines.items[keep], self.lines.items[drop]
            self.graph.add_factor(
                custom_factor(
                    [L(keep), L(drop)],
                    same_line_residual(L(keep), a.anchor, L(drop), b.anchor),
                    gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 5e-3])),
                )
            )
            self.lines.merge(keep, drop)

    # ------------------------------------------------------------------ finish
    def finish(self) -> MappingResult:
        """Solve and export the map.

        Raises:
            MappingError: no frame was added (nothing to map).
        """
        if not self.keyframe_times:
            raise MappingError("mapping: no observation frames to map (the drive has none)")
        started = time.perf_counter()
        iterations = 0
        marginals = None
        slot_covariances: dict[int, FloatArray] = {}
        if self.use_graph:
            self.graph.update()
            iterations = self.graph.optimize_batch(
                self.cfg.batch_max_iterations, self.cfg.batch_relative_tolerance
            )
            self._refresh_estimates(everything=True)
            marginals = self.graph.marginals()
            self._decide_components()
            covariances_started = time.perf_counter()
            slot_covariances = self._slot_covariances()
            self._timing["slot_covariance_s"] = time.perf_counter() - covariances_started
        else:
            for index, sums in self._slot_observation_sums.items():
                self.slots.set_corners(index, np.mean(sums, axis=0))
        semantic_map, slot_of_landmark = self._export(marginals, slot_covariances)
        stats = {
            "keyframes": len(self.keyframe_times),
            "slot_observations": len(self.sightings),
            "accepted": sum(
                s.status in (SightingStatus.ACCEPTED, SightingStatus.REASSIGNED)
                for s in self.sightings
            ),
            "null": sum(s.status is SightingStatus.NULL for s in self.sightings),
            "reassigned": sum(s.status is SightingStatus.REASSIGNED for s in self.sightings),
            "pooled": sum(s.status is SightingStatus.POOLED for s in self.sightings),
            "landmarks_created": len(self.slots.items),
            "merged": sum(s.merged_into is not None for s in self.slots.items),
            "loop_closures_by_id": self.closure.closures,
            "batch_iterations": iterations,
            "tag_size_mismatches": len(self.tag_mismatches),
            "tag_conflicts": len(self.tag_conflicts),
            "marginal_fallbacks": self._marginal_fallbacks,
            "odometry_scale": round(float(self.calibration[0]), 5),
            "gyro_bias_rad_s": float(self.calibration[1]),
            "association_s": round(self._timing["association_s"], 3),
            "isam2_s": round(self._timing["update_s"], 3),
            "isam2_rebuilds": self.graph.rebuilds,
            "batch_s": round(time.perf_counter() - started, 3),
            "slot_covariance_s": round(self._timing.get("slot_covariance_s", 0.0), 3),
        }
        return MappingResult(
            semantic_map,
            np.array(self.keyframe_times),
            np.array(self.keyframe_poses),
            tuple(self.sightings),
            stats,
            tuple(
                (a, b, d if J is None else d + J @ (self._calibration_of(b) - [1.0, 0.0]), c)
                for a, b, d, c, J in self.odometry_edges
            ),
            tuple(self.tag_edges),
            slot_of_landmark,
        )

    def _slot_covariances(self) -> dict[int, FloatArray]:
        """Where the slot detections declare an error shared by every sighting of a slot:
        the joint covariance (8, 8) of each mapped slot's corners, the sandwich of
        :mod:`.shared_error`; else (or for a graph too large for it) none: the graph's
        marginals serve."""
        if not any(has_shared_error(s.observation) for _, s, _ in self._slot_factors):
            return {}
        factors = []
        for index, sighting, landmark in self._slot_factors:
            if landmark is None and sighting.status in (SightingStatus.ACCEPTED,
                                                        SightingStatus.REASSIGNED):
                landmark = sighting.landmark
            factors.append(SlotSightingFactor(index, sighting.keyframe, landmark,
                                              sighting.observation, sighting.sigma))
        other, columns = self.graph.jacobian([f.index for f in factors])
        landmarks = [s.index for s in self.slots.active()]
        covariances = sandwich_covariances(factors, other, columns, self.graph.estimate, X, C,
                                           self.slots.resolve, landmarks)
        return covariances or {}

    def _calibration_of(self, k: int) -> FloatArray:
        """The (speed scale, gyro bias) the odometry factor into keyframe ``k`` was solved
        with: its calibration window's estimate."""
        key = K(k // self.cfg.calibration_window)
        if self.use_graph and self.graph.has(key):
            return self.graph.vector(key)
        return self.calibration

    def _decide_components(self) -> None:
        """Read each slot factor's chosen component at the final estimate (the audit)."""
        values = self.graph.estimate
        for s in self.sightings:
            if s.factor is None:
                continue
            if isinstance(s.factor, MaxMixture):
                i = s.factor.chosen(values)
                chosen = s.candidates[i] if i < len(s.candidates) else None
            elif self.robust:
                chosen = None if is_null_chosen(s.factor, values, self.null) else s.candidates[0]
            else:
                chosen = s.first_choice
            if chosen is None:
                s.status, s.landmark = SightingStatus.NULL, None
            else:
                s.landmark = chosen
                s.status = (
                    SightingStatus.ACCEPTED
                    if chosen == s.first_choice
                    else SightingStatus.REASSIGNED
                )

    def _read_labels_between_keyframes(self, frame: FrameObservations, pose: FloatArray) -> None:
        """Painted IDs are cheap to use from every frame: a labelled slot seen between
        keyframes votes for the one landmark within the label gate (no factor is added)."""
        for obs in frame.slots:
            if obs.label is None:
                continue
            corners = transform_points(pose, obs.vCorners)
            near = self.slots.candidates(corners, None, 0.0, self.cfg.label_vote_gate, 0.0, 1.1, 2)
            if len(near) == 1:
                self._label_votes.append((near[0][0], obs.label, obs.label_confidence))

    def _export(
        self, marginals, slot_covariances: dict[int, FloatArray]
    ) -> tuple[SemanticMap, dict[int, int]]:
        readings: dict[int, list[tuple[str, float]]] = defaultdict(list)
        for index, label, confidence in self._label_votes:
            readings[self.slots.resolve(index)].append((label, confidence))
        accepted: dict[int, int] = {}
        seen_from: dict[int, list[int]] = defaultdict(list)  # keyframes of accepted sightings
        for s in self.sightings:
            if s.landmark is None or s.status in (SightingStatus.NULL, SightingStatus.POOLED):
                continue
            index = self.slots.resolve(s.landmark)
            accepted[index] = accepted.get(index, 0) + 1
            seen_from[index].append(s.keyframe)
            if s.observation.label is not None:
                readings[index].append((s.observation.label, s.observation.label_confidence))
        for landmark in self.slots.items:
            landmark.votes.clear()
            for label, confidence in readings.get(landmark.index, []):
                landmark.votes[label] += confidence
        slots = []
        slot_of_landmark: dict[int, int] = {}
        for landmark in self.slots.active():
            n = accepted.get(landmark.index, 0)
            if n < self.cfg.min_accepted_observations:
                continue
            label, _ = landmark.best_label()  # the most votes; its probability from all reads
            confidence = label_probability(readings[landmark.index], label) if label else 0.0
            covs = np.zeros((4, 2, 2))
            heading_variance = None
            if self.use_graph:
                keys = [C(4 * landmark.index + c) for c in range(4)]
                joint = slot_covariances.get(landmark.index)
                if joint is None:
                    joint = _marginal(marginals, keys)
                if joint is None:  # the corner noise over the accepted observations, counted,
                    # on the map's own uncertainty where the slot was seen from
                    floor = self.cfg.slot_corner_sigma_min
                    covs[:] = np.eye(2) * max(0.05, floor) ** 2 / max(n, 1) + self._seen_from(
                        marginals, seen_from[landmark.index], landmark.corners.mean(axis=0))
                    self._marginal_fallbacks += 1
                else:  # blocks in the order of the keys
                    for c in range(4):
                        covs[c] = joint[2 * c : 2 * c + 2, 2 * c : 2 * c + 2]
                    heading_variance = rotation_variance(landmark.corners, joint)
            slot_of_landmark[landmark.index] = len(slots)
            slots.append(
                Slot(
                    len(slots),
                    label,
                    float(confidence),
                    landmark.corners.copy(),
                    covs,
                    landmark.kind,
                    n,
                    heading_variance,
                )
            )
        for landmark in self.slots.items:  # merged duplicates answer for their survivor
            survivor = self.slots.resolve(landmark.index)
            if survivor in slot_of_landmark:
                slot_of_landmark[landmark.index] = slot_of_landmark[survivor]
        tags = []
        for tag_id, info in sorted(self.tags.items()):
            if self.use_graph:
                mTt = self.graph.pose(T(tag_id))
                cov = np.zeros((3, 3))
                marginal = _marginal(marginals, T(tag_id))
                if marginal is None:  # as for slots: the spread of its sightings
                    poses = np.array(info["poses"])
                    cov = _pose_spread(poses, mTt) / len(poses) if len(poses) > 1 else cov
                    self._marginal_fallbacks += 1
                else:  # gtsam's Pose2 marginal is along the tag's axes, the map's along the map's
                    cov = rotate_pose_covariance(marginal, mTt[2])
            else:
                poses = np.array(info["poses"])
                mTt = np.array(
                    [
                        *poses[:, :2].mean(axis=0),
                        math.atan2(np.sin(poses[:, 2]).mean(), np.cos(poses[:, 2]).mean()),
                    ]
                )
                cov = _pose_spread(poses, mTt) if len(poses) > 1 else np.zeros((3, 3))
            mTt[2] = wrap_angle(mTt[2])
            tags.append(
                Tag(
                    info["family"],
                    tag_id,
                    info["size"],
                    mTt,
                    float(np.median(info["heights"])),
                    cov,
                )
            )
        markings = self._export_markings(marginals)
        return SemanticMap(tuple(slots), tuple(tags), markings), slot_of_landmark

    def _seen_from(self, marginals, keyframes: list[int], point: FloatArray) -> FloatArray:
        """(2, 2) position covariance, map frame, of the keyframe among ``keyframes`` nearest
        ``point``: what a landmark whose own marginal gtsam refused is known no better than,
        the map's drift where it was seen. Where that keyframe's marginal is refused too
        (the same ill-conditioned clique), the next nearest of ``keyframes``, then the
        keyframes before and after it along the drive, up to :data:`_SEEN_FROM_REACH` away;
        zeros if none answers."""
        if not keyframes:
            return np.zeros((2, 2))
        poses = self.keyframe_poses
        ranked = sorted(set(keyframes), key=lambda j: math.hypot(*(poses[j][:2] - point)))
        nearest = ranked[0]
        along = (nearest + sign * step for step in range(1, _SEEN_FROM_REACH + 1)
                 for sign in (-1, 1))
        for k in itertools.chain(ranked, along):
            if not 0 <= k < len(poses):
                continue
            marginal = _marginal(marginals, X(k))
            if marginal is not None:
                return rotate_pose_covariance(marginal, poses[k][2])[:2, :2]
        return np.zeros((2, 2))

    def _export_markings(self, marginals) -> tuple[Marking, ...]:
        """Painted lines: the graph's line landmarks with extents re-measured from all their
        detections at the final keyframe poses (:func:`robust_extent`) and their position
        uncertainty from the line's marginal (at its two ends, :func:`end_covariance`, and
        their RMS along it, :func:`segment_sigma`), or, without a graph, the detections
        placed by odometry and merged (no uncertainty)."""
        poses = self.keyframe_poses
        if not self.use_graph:
            if not self.marking_detections:
                return ()
            segments = np.array([transform_points(poses[k], e)
                                 for k, e, _, _ in self.marking_detections])
            return merge_marking_observations(
                segments,
                np.array([w for _, _, w, _ in self.marking_detections]),
                np.array([c for _, _, _, c in self.marking_detections]),
                angle_tolerance_deg=self.cfg.marking_angle_tolerance_deg,
                min_support=self.cfg.marking_min_support,
                min_length=self.cfg.marking_min_length,
            )
        members: dict[int, list] = {}
        for line in self.lines.items:
            if line.merged_into == -1 or not (line.in_graph or line.merged_into is not None):
                continue
            members.setdefault(self.lines.resolve(line.index), []).extend(line.detections)
        out = []
        for index in sorted(members):
            line, detections = self.lines.items[index], members[index]
            if len(detections) < self.cfg.marking_min_support:
                continue
            points = np.vstack([transform_points(poses[k], e) for k, e, _, _ in detections])
            keyframes = len({k for k, _, _, _ in detections})
            spread = float(np.sqrt(np.mean(line.across(points) ** 2)))
            if keyframes < 3 or spread > 2 * self.cfg.marking_sigma:
                continue  # seen once, or its detections do not lie on one line: not a line
            s0, s1 = robust_extent(line.along(points))
            a = line.foot() + s0 * line.direction
            b = line.foot() + s1 * line.direction
            if np.linalg.norm(b - a) < self.cfg.marking_min_length:
                continue
            ends = None  # known from the line's marginal only
            marginal = _marginal(marginals, L(index))
            if marginal is None:  # as for slots: the detections' noise, counted, on the map's
                # own uncertainty where the line was seen from
                seen = self._seen_from(marginals, [k for k, _, _, _ in detections], 0.5 * (a + b))
                normal = np.array([-line.direction[1], line.direction[0]])
                sigma = math.sqrt(self.cfg.marking_sigma**2 / keyframes + normal @ seen @ normal)
                self._marginal_fallbacks += 1
            else:
                ends = end_covariance(marginal, s0, s1)
                sigma = segment_sigma(ends)
            width = float(np.median([w for _, _, w, _ in detections]))
            out.append(Marking(a, b, width, sigma, ends))
        return tuple(out)
