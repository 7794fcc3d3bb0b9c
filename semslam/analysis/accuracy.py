"""Predicted positioning accuracy from a map (Hofmann 2011), before any drive.

At a vehicle pose ``mTv = (x, y, yaw)`` the landmarks the sensors would see give the
observation equations of one frame; stacked, their Jacobian ``A`` with respect to the
pose and the weight matrix ``P`` (inverse measurement covariance, map uncertainty
included) give the single-frame covariance ``Q_xx = (A^T P A)^-1`` (3 x 3: x, y in metres,
yaw in radians). Along a route, a Kalman filter with an odometry / IMU ``grade`` bridges
the stretches where a frame alone cannot fix the pose: prediction with the grade's speed
and yaw-rate noise (and isotropic position walk), update with the frame's information
``A^T P A``.

What the sensors see (:class:`SensorModel`): slot corners inside the top view (10 m x
10 m around the car, outside the ego box; or, the simulator's rule, whole slots whose
entrance is in view), tags in the front camera's field of view within the range limit
and facing the car, painted lines inside the top view (their clipped end points, across
the line only), each kind detected with its detection rate (the information is the
expected one). Occlusion by parked cars is not modelled, so the figures are what the map
allows at best.

How the filter uses it (:class:`LocalizerModel`): by default Hofmann's ideal filter,
every landmark in every frame at its sensor noise. :func:`localizer_model` and
:func:`localizer_grade` describe semslam's own localizer instead (its ``localization``
configuration): the kinds it uses, its corner sigma floor, inflated map covariance,
painted lines (its slots' separators among them) only as a fallback where fewer than
``fallback_below`` slots + tags are detected, its covariance floor at the map's
uncertainty, and its process noise (odometry as 50 Hz measurements
plus position and heading walks). Pure numpy.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from semslam.errors import ConfigError
from semslam.geometry import FloatArray, clip_segments, rotation, segment_pieces
from semslam.line_uncertainty import across_variance, end_covariances
from semslam.localization.measurements import point_jacobian
from semslam.localization.slot_sides import slot_sides
from semslam.types import SemanticMap

if TYPE_CHECKING:
    from semslam.config import LocalizationConfig, ObservationNoiseConfig
    from semslam.rig import Rig

UNOBSERVABLE = math.inf
"""Reported sigma where a frame (or the filter) cannot fix the pose."""

SLOT_RULES = ("corners", "entrance")


@dataclass(frozen=True)
class SensorModel:
    """What the car sees and how well (defaults: the simulator's noisy sensors' noise, every
    landmark in view detected).

    Attributes:
        topview_half_m: half side of the top view, m (ps2.0: 5 m).
        ego_half_length_m, ego_half_width_m: the blind ego box, m.
        corner_sigma: slot corner noise per axis, m.
        marking_sigma: painted line end point across the line, m.
        tag_range_limit: farthest tag used, m.
        tag_fov_deg: front camera horizontal field of view, deg.
        tag_max_incidence_deg: largest angle between the tag normal and the view ray.
        tag_range_sigma_abs, tag_range_sigma_rel: range noise ``abs + rel * r``, m.
        tag_bearing_sigma_deg, tag_yaw_sigma_deg: bearing and tag-yaw noise, deg.
        camera_x: the front camera's position ahead of the vehicle centre, m.
        slot_rule: ``corners``: every slot corner inside the top view is measured on its
            own; ``entrance``: a slot is detected whole (all four corners measured, the
            far ones perhaps outside the view) when both entrance corners (its first two)
            lie ``entrance_margin_m`` inside the top view and outside the ego box: the
            simulator's detector and ps2.0's labels.
        entrance_margin_m: see ``slot_rule``, m.
        slot_detection_rate, tag_detection_rate, marking_detection_rate: the chance that a
            landmark in view is detected in a frame (1 - miss rate); each kind's
            information is weighted by it (the expected information of a frame).
    """

    topview_half_m: float = 5.0
    ego_half_length_m: float = 1.8
    ego_half_width_m: float = 0.8
    corner_sigma: float = 0.05
    marking_sigma: float = 0.05
    tag_range_limit: float = 20.0
    tag_fov_deg: float = 90.0
    tag_max_incidence_deg: float = 70.0
    tag_range_sigma_abs: float = 0.02
    tag_range_sigma_rel: float = 0.01
    tag_bearing_sigma_deg: float = 0.3
    tag_yaw_sigma_deg: float = 3.0
    camera_x: float = 1.2
    slot_rule: str = "corners"
    entrance_margin_m: float = 0.15
    slot_detection_rate: float = 1.0
    tag_detection_rate: float = 1.0
    marking_detection_rate: float = 1.0


def simulated_sensors(noise: ObservationNoiseConfig, rig: Rig | None = None) -> SensorModel:
    """The simulator's noisy detectors (``config.simulation.observation_noise``) on ``rig``
    (default: the simulator's): its top view and ego box, the front camera's position and
    field of view, its noise, its miss rates as detection rates, whole slots by their
    entrance. Not modelled: false detections, misread IDs, the tags' pixel-size limit and
    occlusion by pillars."""
    from semslam.rig import default_rig

    rig = rig or default_rig()
    top = rig.topview
    kw: dict[str, float] = {}
    camera = rig.cameras.get("front")
    if camera is not None:
        kw["camera_x"] = float(camera.T_vehicle_camera[0, 3])
        kw["tag_fov_deg"] = math.degrees(2 * math.atan(camera.size[0] / 2 / camera.K[0, 0]))
    return SensorModel(
        topview_half_m=top.half_extent_m,
        ego_half_length_m=top.ego_length_m / 2,
        ego_half_width_m=top.ego_width_m / 2,
        corner_sigma=noise.slot_corner_sigma,
        marking_sigma=noise.marking_endpoint_sigma,
        tag_range_limit=noise.tag_range_limit,
        tag_max_incidence_deg=noise.tag_max_incidence_deg,
        tag_range_sigma_abs=noise.tag_range_sigma_abs,
        tag_range_sigma_rel=noise.tag_range_sigma_rel,
        tag_bearing_sigma_deg=noise.tag_bearing_sigma_deg,
        tag_yaw_sigma_deg=noise.tag_yaw_sigma_deg,
        slot_rule="entrance",
        slot_detection_rate=1 - noise.slot_miss_rate,
        tag_detection_rate=1 - noise.tag_miss_rate,
        marking_detection_rate=1 - noise.marking_miss_rate,
        **kw,
    )


@dataclass(frozen=True)
class OdometryGrade:
    """Dead-reckoning quality in Hofmann's terms: speed noise (m/s), the heading's initial
    uncertainty (deg) and yaw-rate noise (deg/s). Speed and rate noise are taken as white
    with a 1 s correlation: the variance they add grows as sigma^2 * t (t in seconds),
    the speed's along the travel, the rate's on the heading. ``position_walk`` (m per
    sqrt(s), 0 for Hofmann's grades) adds ``position_walk^2 * t`` on x AND y: slip and
    whatever else a filter covers with an isotropic random walk (semslam's localizer).

    A filter that estimates the odometry's own errors (semslam's localizer) has two more
    states: the wheel speed's relative scale error, known to ``scale_sigma`` before any
    landmark and drifting by ``scale_walk`` per sqrt(s), and the gyro's bias, known to
    ``bias_sigma_deg`` (deg/s) and drifting by ``bias_walk_deg`` (deg/s per sqrt(s)).
    Both 0 (Hofmann's grades): no such states, the errors are part of the white noise."""

    name: str
    speed_sigma: float
    heading_sigma_deg: float
    rate_sigma_deg: float
    position_walk: float = 0.0
    scale_sigma: float = 0.0
    scale_walk: float = 0.0
    bias_sigma_deg: float = 0.0
    bias_walk_deg: float = 0.0

    @property
    def calibrated(self) -> bool:
        """Does the filter estimate the wheel scale and the gyro bias?"""
        return self.scale_sigma > 0 or self.bias_sigma_deg > 0


GRADES = {
    "precise": OdometryGrade("precise", 0.02, 0.01, 0.001),
    "automotive": OdometryGrade("automotive", 0.1, 0.1, 0.005),
}
"""Hofmann's two grades: a precise IMU and automotive sensors."""


def localizer_grade(cfg: LocalizationConfig, odometry_rate: float) -> OdometryGrade:
    """semslam's localizer's process noise as an :class:`OdometryGrade` (name ``localizer``).

    The localizer (:mod:`semslam.localization.filter`) takes each wheel-speed and gyro
    sample, at ``odometry_rate`` Hz, as a measurement of ``v`` (``speed_sigma``) and of
    the yaw rate (``yaw_rate_sigma``), and adds a random walk on the position
    (``position_walk`` on x and y) and the heading (``yaw_walk``). Between frames its
    covariance then grows by ``speed_sigma^2 / f`` per second along the travel (the
    displacement is the integral of the speed samples, each with independent noise, over
    ``1 / f`` s; its acceleration noise does not enter while it follows every sample), by
    ``yaw_rate_sigma^2 / f + yaw_walk^2`` per second on the heading and by
    ``position_walk^2`` per second on x and y: in the grade's ``sigma^2 * t`` convention
    ``speed_sigma / sqrt(f)``, ``sqrt(yaw_rate_sigma^2 / f + yaw_walk^2)``, and the walk.
    Checked against the localizer's own filter coasting in the tests. The heading starts
    from the first frame's own uncertainty (no floor). With
    ``estimate_odometry_errors`` the localizer has states for the wheel speed's scale error
    and the gyro's bias, and so has the grade, with the same priors and drifts.
    """
    if not (math.isfinite(odometry_rate) and odometry_rate > 0):
        raise ValueError(f"odometry rate must be a positive number of Hz, got {odometry_rate}")
    rate = math.sqrt(cfg.yaw_rate_sigma**2 / odometry_rate + cfg.yaw_walk**2)
    calibration = {}
    if cfg.estimate_odometry_errors:
        calibration = {
            "scale_sigma": cfg.speed_scale_prior_sigma,
            "scale_walk": cfg.speed_scale_walk,
            "bias_sigma_deg": math.degrees(cfg.gyro_bias_prior_sigma),
            "bias_walk_deg": math.degrees(cfg.gyro_bias_walk),
        }
    return OdometryGrade(
        "localizer",
        cfg.speed_sigma / math.sqrt(odometry_rate),
        0.0,
        math.degrees(rate),
        cfg.position_walk,
        **calibration,
    )


@dataclass(frozen=True)
class LocalizerModel:
    """How the filter uses what the sensors see (defaults: Hofmann's ideal filter, every
    landmark in every frame at the sensor's noise, the map's covariance as stored).

    Attributes:
        corner_sigma_min: floor on the slot corner sigma, m.
        map_covariance_scale: the map's corner and tag covariances are multiplied by this.
        tag_range_limit: tags farther than this are not used, m (also the sensor's limit).
        marking_sigma: a painted line end point across the line, m (None: the sensor's).
        marking_min_length: shorter visible lines are not used, m.
        fallback_below: painted lines only in frames where fewer than this many slots +
            tags are detected (0: in every frame). With detection rates below 1 the lines'
            information is weighted by the chance of that (binomial in the slots and tags
            in view).
        map_floor_scale: after each update the position covariance is raised (PSD sense)
            to this times the mean covariance of the seen slots' corners and the heading
            variance to this times their mean orientation variance, or, where
            painted lines are used without any slot, to this times
            ``marking_map_sigma^2`` (0: no floor); applied where that case is the more
            likely one (chance >= 0.5).
        marking_map_sigma: least uncertainty of a map line across itself, m (the part of
            ``marking_sigma`` that is the map's).
        line_own_sigma: a line's own variance where each visible end falls on it (a
            semslam map's marginal, :mod:`semslam.line_uncertainty`) counts where larger
            than ``marking_map_sigma`` squared, in its noise and in the floor, as the
            localizer has it; False: every line as ``marking_sigma`` says.
        map_heading_radius: the heading variance reported (not the filter's) is at least
            ``map_floor_scale`` times the mean orientation variance of the map's slots whose
            centre lies this near the pose, m (0: as the filter holds it).
        use_slots, use_tags, use_markings: a kind switched off is never used.
        slot_sides: the slots' separators join the map's painted lines where it holds none
            (:func:`~semslam.localization.slot_sides.slot_sides`); read by
            :meth:`MapGeometry.for_model`.
    """

    corner_sigma_min: float = 0.0
    map_covariance_scale: float = 1.0
    tag_range_limit: float = math.inf
    marking_sigma: float | None = None
    marking_min_length: float = 0.3
    fallback_below: int = 0
    map_floor_scale: float = 0.0
    marking_map_sigma: float = 0.0
    line_own_sigma: bool = False
    map_heading_radius: float = 0.0
    use_slots: bool = True
    use_tags: bool = True
    use_markings: bool = True
    slot_sides: bool = False


IDEAL = LocalizerModel()
"""Hofmann's ideal filter."""


def localizer_model(cfg: LocalizationConfig) -> LocalizerModel:
    """semslam's localizer's use of the measurements (``config.localization``; see
    :mod:`semslam.localization.association` and ``Localizer._floor_to_map``): corner sigma
    floor, map covariance scale, tag range limit, line end points at
    ``hypot(marking_endpoint_sigma, marking_map_sigma)`` (a line's own uncertainty where the
    end point falls on it in place of ``marking_map_sigma`` where larger) and only as a
    fallback when ``markings_as_fallback``, the covariance floor at the map's uncertainty, the kinds
    switched off (``use_slots``, ``use_tags``, ``use_markings``) and the slots' separators
    as painted lines (``slot_sides_as_markings``; build the geometry with
    :meth:`MapGeometry.for_model`), and the heading it reports raised to the map's slots'
    near the car (``map_heading_radius``)."""
    return LocalizerModel(
        corner_sigma_min=cfg.slot_corner_sigma_min,
        map_covariance_scale=cfg.map_covariance_scale,
        tag_range_limit=cfg.tag_range_limit,
        marking_sigma=math.hypot(cfg.marking_endpoint_sigma, cfg.marking_map_sigma),
        marking_min_length=max(0.3, cfg.marking_min_length),
        fallback_below=cfg.fallback_below if cfg.markings_as_fallback else 0,
        map_floor_scale=cfg.map_floor_scale,
        marking_map_sigma=cfg.marking_map_sigma,
        line_own_sigma=True,
        map_heading_radius=cfg.map_heading_radius,
        use_slots=cfg.use_slots,
        use_tags=cfg.use_tags,
        use_markings=cfg.use_markings,
        slot_sides=cfg.slot_sides_as_markings,
    )


def _in_topview(vP: FloatArray, s: SensorModel) -> np.ndarray:
    inside = (np.abs(vP) <= s.topview_half_m).all(axis=1)
    ego = (np.abs(vP[:, 0]) <= s.ego_half_length_m) & (np.abs(vP[:, 1]) <= s.ego_half_width_m)
    return inside & ~ego


class MapGeometry:
    """The map's landmarks as arrays, ready for many poses; :meth:`around` keeps those near
    one place, so that a pose's cost does not grow with the size of the garage."""

    def __init__(self, semantic_map: SemanticMap, with_slot_sides: bool = False) -> None:
        """``with_slot_sides``: the slots' separators join the painted lines where the map
        holds none, as the localizer's do (``slot_sides_as_markings``)."""
        self._trees: dict[str, tuple[cKDTree, np.ndarray]] = {}
        slots = semantic_map.slots
        self.corners = np.array([c for s in slots for c in s.corners], float).reshape(-1, 2)
        self.corner_cov = np.array([c for s in slots for c in s.corner_covariances], float).reshape(
            -1, 2, 2
        )
        self.heading_var = np.array([s.orientation_variance for s in slots], float)
        self.slot_centres = np.array([np.mean(s.corners, axis=0) for s in slots],
                                     float).reshape(-1, 2)
        self.slot_of_corner = np.repeat(np.arange(len(slots)), [len(s.corners) for s in slots])
        self.entrances = np.array([s.corners[:2] for s in slots], float).reshape(-1, 2, 2)
        tags = semantic_map.tags
        self.tags = np.array([t.mTt for t in tags], float).reshape(-1, 3)
        self.tag_cov = np.array([t.covariance for t in tags], float).reshape(-1, 3, 3)
        markings = semantic_map.markings + (slot_sides(semantic_map) if with_slot_sides else ())
        self.lines = np.array([[m.a, m.b] for m in markings], float).reshape(-1, 2, 2)
        # each line's own uncertainty across itself at its ends, m^2 (zeros: none known)
        self.line_end_cov = end_covariances(markings).reshape(-1, 2, 2)

    @classmethod
    def for_model(cls, semantic_map: SemanticMap, model: LocalizerModel) -> MapGeometry:
        """The map's landmarks as ``model``'s filter uses them (its slots' separators among
        the painted lines if ``model.slot_sides``)."""
        return cls(semantic_map, with_slot_sides=model.slot_sides)

    def around(self, point: FloatArray, sensors: SensorModel, model: LocalizerModel) -> MapGeometry:
        """The landmarks that can be in view at ``point`` (x, y, metres; map frame) whatever
        the heading: whole slots with a corner, and painted lines, that come within the top
        view's circumradius; tags within the range limit of the camera. In the map's order,
        so every frame at ``point`` gets from it exactly what it gets from the whole map."""
        point = np.asarray(point, float)[:2]
        view = sensors.topview_half_m * math.sqrt(2.0) + _REACH_MARGIN
        tag_reach = (min(sensors.tag_range_limit, model.tag_range_limit) + abs(sensors.camera_x)
                     + _REACH_MARGIN)
        near = copy.copy(self)
        near._trees = {}  # its own KD-trees, if it is ever asked in turn
        corners = self._near("corners", self.corners, point, view)
        slots = np.unique(self.slot_of_corner[corners])
        whole = np.nonzero(np.isin(self.slot_of_corner, slots))[0]
        near.corners, near.corner_cov = self.corners[whole], self.corner_cov[whole]
        near.heading_var, near.entrances = self.heading_var[slots], self.entrances[slots]
        near.slot_of_corner = np.searchsorted(slots, self.slot_of_corner[whole])
        tags = self._near("tags", self.tags[:, :2], point, tag_reach)
        near.tags, near.tag_cov = self.tags[tags], self.tag_cov[tags]
        pieces = self._near("lines", None, point, view + 0.5 * _LINE_PIECE)
        near.lines, near.line_end_cov = self.lines[pieces], self.line_end_cov[pieces]
        return near

    def heading_variance_near(self, point: FloatArray, radius: float) -> float | None:
        """The mean orientation variance (rad^2) of the slots whose centre lies within
        ``radius`` m of ``point`` (x, y; map frame), as the localizer's
        ``LocalMap.heading_variance_near``; None where no slot is that near."""
        near = self._near("slot_centres", self.slot_centres, np.asarray(point, float)[:2],
                          radius)
        return float(self.heading_var[near].mean()) if len(near) else None

    def _near(self, kind: str, points: FloatArray | None, point: FloatArray,
              reach: float) -> np.ndarray:
        """Indices (ascending, each once) of ``kind``'s points within ``reach`` of ``point``;
        for lines, of the lines with a piece (at most :data:`_LINE_PIECE` long) whose middle
        is there. One KD-tree per kind, built on first use."""
        if kind not in self._trees:
            if kind == "lines":
                a = self.lines[:, 0]
                points, owner = segment_pieces(a, self.lines[:, 1] - a, _LINE_PIECE)
            else:
                owner = np.arange(len(points))
            self._trees[kind] = (cKDTree(np.asarray(points, float).reshape(-1, 2)), owner)
        tree, owner = self._trees[kind]
        if not tree.n or not np.isfinite(point).all():  # no pose, nothing in view (as before)
            return np.zeros(0, dtype=int)
        return np.unique(owner[np.asarray(tree.query_ball_point(point, reach), dtype=int)])

    def bounds(self, margin: float = 2.0) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of every landmark, widened by ``margin`` metres."""
        pts = np.concatenate([self.corners, self.tags[:, :2], self.lines.reshape(-1, 2)])
        if not len(pts):
            return (-margin, -margin, margin, margin)
        lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


_REACH_MARGIN = 1e-6  # m: round-off at the edge of a reach keeps a landmark in
_LINE_PIECE = 2.0  # m: painted lines enter the KD-tree as pieces at most this long


@dataclass(frozen=True)
class _Frame:
    """One frame's information per landmark kind (3 x 3 each), what is in view, and the
    pose covariance floor the filter applies after it (3 x 3: the position block and the
    heading variance)."""

    slots: FloatArray
    tags: FloatArray
    lines: FloatArray
    counts: dict[str, int]
    lines_weight: float  # expected share of frames that use the lines
    floor: FloatArray


def _binomial(n: int, p: float) -> FloatArray:
    """P(k of n detected), k = 0..n, each with chance p."""
    return np.array([math.comb(n, k) * p**k * (1 - p) ** (n - k) for k in range(n + 1)])


def _fewer_than(k: int, counts: list[tuple[int, float]]) -> float:
    """Chance that fewer than ``k`` of the landmarks are detected, ``counts`` = (how many
    in view, detection rate) per kind."""
    pmf = np.ones(1)
    for n, p in counts:
        pmf = np.convolve(pmf, _binomial(n, p))
    return float(pmf[:k].sum())


def _frame(
    geometry: MapGeometry, pose: FloatArray, sensors: SensorModel, model: LocalizerModel
) -> _Frame:
    if sensors.slot_rule not in SLOT_RULES:
        raise ValueError(f"slot_rule: choose one of {', '.join(SLOT_RULES)}, "
                         f"got {sensors.slot_rule!r}")
    pose = np.asarray(pose, float)
    R = rotation(pose[2])
    infos = {k: np.zeros((3, 3)) for k in ("slots", "tags", "lines")}
    counts = {"corners": 0, "slots": 0, "tags": 0, "lines": 0}
    slot_floor = None
    # slot corners: vP = R^T (mP - t)
    if model.use_slots and len(geometry.corners):
        if sensors.slot_rule == "corners":
            seen = np.nonzero(_in_topview((geometry.corners - pose[:2]) @ R, sensors))[0]
        else:  # whole slots whose entrance is in view
            ent = (geometry.entrances - pose[:2]) @ R  # (S, 2, 2)
            inside = (np.abs(ent) <= sensors.topview_half_m - sensors.entrance_margin_m).all(
                axis=(1, 2))
            ego = ((np.abs(ent[..., 0]) < sensors.ego_half_length_m)
                   & (np.abs(ent[..., 1]) < sensors.ego_half_width_m)).any(axis=1)
            whole = np.asarray(inside & ~ego, dtype=bool)
            seen = np.nonzero(whole[geometry.slot_of_corner])[0]
        if len(seen):
            H = point_jacobian(pose, geometry.corners[seen]).reshape(len(seen), 2, 3)
            sigma = max(sensors.corner_sigma, model.corner_sigma_min)
            cov = (R.T @ (model.map_covariance_scale * geometry.corner_cov[seen]) @ R
                   + np.eye(2) * sigma**2)
            infos["slots"] = np.einsum("kai,kab,kbj->ij", H, np.linalg.inv(cov), H)
            slots = np.unique(geometry.slot_of_corner[seen])
            counts["corners"], counts["slots"] = len(seen), len(slots)
            slot_floor = np.zeros((3, 3))
            slot_floor[:2, :2] = geometry.corner_cov[
                np.isin(geometry.slot_of_corner, slots)].mean(axis=0)
            slot_floor[2, 2] = geometry.heading_var[slots].mean()
    # tags: vTt = mTv^-1 mTt, in the camera's field of view, facing it
    if model.use_tags and len(geometry.tags):
        limit = min(sensors.tag_range_limit, model.tag_range_limit)
        tag_sensors = sensors if limit == sensors.tag_range_limit else replace(
            sensors, tag_range_limit=limit)
        tag_info, seen_tags = tag_information(
            pose[None], geometry.tags, model.map_covariance_scale * geometry.tag_cov, tag_sensors)
        infos["tags"] = tag_info[0]
        counts["tags"] = int(seen_tags[0])
    # painted lines: the visible part's end points, across the line only
    half = sensors.topview_half_m
    marking_sigma = model.marking_sigma if model.marking_sigma is not None else (
        sensors.marking_sigma)
    within = (_lines_within(geometry.lines, pose[:2], half * math.sqrt(2.0))
              if model.use_markings else np.zeros(len(geometry.lines), bool))
    lines = geometry.lines[within]
    line_map_var = np.zeros(0)
    if len(lines):
        ends, keep = clip_segments((lines[:, 0] - pose[:2]) @ R, (lines[:, 1] - pose[:2]) @ R,
                                    -half, half)
        d = lines[:, 1] - lines[:, 0]
        length = np.hypot(d[:, 0], d[:, 1])
        visible = np.hypot(*(ends[:, 1] - ends[:, 0]).T)
        keep &= (length >= 1e-6) & (visible >= model.marking_min_length)
        n = np.column_stack([-d[keep, 1], d[keep, 0]]) / length[keep, None]
        # per end, d(n . (t + R vE)) / d(x, y, yaw): (n_x, n_y, n . (J R vE))
        h = np.concatenate([np.repeat(n[:, None, :], 2, axis=1),
                            _yaw_row(n[:, None, :], R, ends[keep])[..., None]],
                           axis=2).reshape(-1, 3)
        # each line's map part: its own variance where each visible end falls on it, where
        # larger than the model's least one (the localizer's LocalMap.marking_map_var)
        own = np.zeros((int(keep.sum()), 2))
        if model.line_own_sigma:
            a_v = (lines[keep, 0] - pose[:2]) @ R
            lam = ((ends[keep] - a_v[:, None, :]) @ ((d[keep] @ R) / length[keep, None] ** 2)[
                :, :, None])[..., 0]  # (K, 2 ends): share of the way from a to b
            own = across_variance(geometry.line_end_cov[within][keep][:, None], lam)
        line_map_var = np.maximum(own, model.marking_map_sigma**2)  # (K, 2 ends)
        extra = line_map_var - model.marking_map_sigma**2
        weights = (1.0 / (marking_sigma**2 + extra)).reshape(-1)  # per end point
        infos["lines"] = (h * weights[:, None]).T @ h
        counts["lines"] = int(keep.sum())
    ps, pt, pm = (sensors.slot_detection_rate, sensors.tag_detection_rate,
                  sensors.marking_detection_rate)
    use_lines, lines_without_slots = 1.0, 1.0
    if model.fallback_below > 0:
        k = model.fallback_below
        use_lines = _fewer_than(k, [(counts["slots"], ps), (counts["tags"], pt)])
        lines_without_slots = _fewer_than(k, [(counts["tags"], pt)])
    floor = np.zeros((3, 3))
    if model.map_floor_scale > 0:
        no_slot = (1 - ps) ** counts["slots"]
        only_lines = no_slot * lines_without_slots * (1 - (1 - pm) ** counts["lines"])
        if slot_floor is not None and no_slot <= 0.5:
            floor = model.map_floor_scale * slot_floor
        elif only_lines >= 0.5:
            line_var = float(line_map_var.mean()) if len(line_map_var) else (
                model.marking_map_sigma**2)
            floor[:2, :2] = model.map_floor_scale * line_var * np.eye(2)
    return _Frame(infos["slots"], infos["tags"], infos["lines"], counts, use_lines, floor)


def _lines_within(lines: FloatArray, point: FloatArray, reach: float) -> np.ndarray:
    """Which of the segments (L, 2, 2) come within ``reach`` of ``point`` (L,) bool: the
    only ones that can cross the square view around it (``reach`` its circumradius). One
    vectorised test, so a map of thousands of painted lines costs no Python loop over all
    of them."""
    if not len(lines):
        return np.zeros(0, bool)
    a, d = lines[:, 0], lines[:, 1] - lines[:, 0]
    t = np.clip(np.einsum("ij,ij->i", point - a, d) / np.maximum(
        np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    gap = a + t[:, None] * d - point
    return np.einsum("ij,ij->i", gap, gap) <= reach * reach


def _expected_information(frame: _Frame, sensors: SensorModel) -> FloatArray:
    return (sensors.slot_detection_rate * frame.slots + sensors.tag_detection_rate * frame.tags
            + sensors.marking_detection_rate * frame.lines_weight * frame.lines)


def frame_information(
    geometry: MapGeometry,
    pose: FloatArray,
    sensors: SensorModel = SensorModel(),
    model: LocalizerModel = IDEAL,
) -> tuple[FloatArray, dict[str, int]]:
    """``A^T P A`` (3 x 3) of one frame at ``pose`` and the count of each landmark kind in
    view (``corners``, ``slots``, ``tags``, ``lines``).

    Map covariances (times the model's scale) add to the measurement covariance (projected
    into the vehicle frame). Each kind's information is weighted by its detection rate and,
    for lines used as a fallback, by the chance that they are used (:class:`LocalizerModel`).
    """
    frame = _frame(geometry, pose, sensors, model)
    return _expected_information(frame, sensors), frame.counts


def tag_information(
    poses: FloatArray,
    tags: FloatArray,
    tag_cov: FloatArray | None = None,
    sensors: SensorModel = SensorModel(),
) -> tuple[FloatArray, np.ndarray]:
    """Information (N, 3, 3) that tags ``mTt`` (T, 3) give at each of ``poses`` (N, 3), and
    how many are seen (N,): those within the range limit, inside the front camera's
    field of view and facing it. Range noise along the view ray, bearing noise across,
    yaw noise on the tag's yaw; the tags' map covariance (T, 3, 3) adds (vehicle frame)."""
    poses = np.asarray(poses, float).reshape(-1, 3)
    tags = np.asarray(tags, float).reshape(-1, 3)
    tag_cov = np.zeros((len(tags), 3, 3)) if tag_cov is None else np.asarray(tag_cov, float)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    dx = tags[None, :, 0] - poses[:, :1]
    dy = tags[None, :, 1] - poses[:, 1:2]
    vx, vy = c * dx + s * dy, -s * dx + c * dy  # tag centre in the vehicle frame (N, T)
    rx, ry = vx - sensors.camera_x, vy
    r = np.hypot(rx, ry)
    bearing = np.arctan2(ry, rx)
    facing = np.cos(tags[None, :, 2] - poses[:, 2:3] - bearing - np.pi)
    seen = (
        (r <= sensors.tag_range_limit)
        & (r >= 0.5)
        & (np.abs(bearing) <= np.radians(sensors.tag_fov_deg) / 2)
        & (facing >= math.cos(math.radians(sensors.tag_max_incidence_deg)))
    )
    info = np.zeros((len(poses), 3, 3))
    n_idx, t_idx = np.nonzero(seen)
    if not len(n_idx):
        return info, seen.sum(axis=1)
    rr = r[n_idx, t_idx]
    cb, sb_ = np.cos(bearing[n_idx, t_idx]), np.sin(bearing[n_idx, t_idx])
    sr = sensors.tag_range_sigma_abs + sensors.tag_range_sigma_rel * rr
    st = math.radians(sensors.tag_bearing_sigma_deg) * rr
    C = np.zeros((len(n_idx), 3, 3))
    C[:, 0, 0] = sr**2 * cb**2 + st**2 * sb_**2
    C[:, 1, 1] = sr**2 * sb_**2 + st**2 * cb**2
    C[:, 0, 1] = C[:, 1, 0] = (sr**2 - st**2) * cb * sb_
    C[:, 2, 2] = math.radians(sensors.tag_yaw_sigma_deg) ** 2
    Rt = np.zeros((len(n_idx), 3, 3))
    cc, ss = c[n_idx, 0], s[n_idx, 0]
    Rt[:, 0, 0], Rt[:, 0, 1], Rt[:, 1, 0], Rt[:, 1, 1] = cc, -ss, ss, cc
    Rt[:, 2, 2] = 1.0
    C += np.transpose(Rt, (0, 2, 1)) @ tag_cov[t_idx] @ Rt
    # Jacobian of (R^T (t_tag - t), yaw_tag - yaw) with respect to (x, y, yaw)
    H = np.zeros((len(n_idx), 3, 3))
    ddx, ddy = dx[n_idx, t_idx], dy[n_idx, t_idx]
    H[:, 0, 0], H[:, 0, 1] = -cc, -ss
    H[:, 1, 0], H[:, 1, 1] = ss, -cc
    H[:, 0, 2] = -ss * ddx + cc * ddy
    H[:, 1, 2] = -cc * ddx - ss * ddy
    H[:, 2, 2] = -1.0
    contrib = np.transpose(H, (0, 2, 1)) @ np.linalg.inv(C) @ H
    np.add.at(info, n_idx, contrib)
    return info, seen.sum(axis=1)


def _yaw_row(n: FloatArray, R: FloatArray, vE: FloatArray) -> FloatArray:
    """d(n . R(yaw) vE) / d(yaw) = n . (J R vE), J the 90 deg rotation; ``n`` and ``vE``
    (..., 2) broadcast."""
    w = np.asarray(vE, float) @ R.T
    n = np.asarray(n, float)
    return n[..., 0] * -w[..., 1] + n[..., 1] * w[..., 0]


def position_sigma(cov: FloatArray) -> float:
    """Square root of the largest eigenvalue of the 2 x 2 position block (m): the semi-axis
    of the 1-sigma error ellipse; infinite where the pose is not observable."""
    if not np.all(np.isfinite(cov)):
        return UNOBSERVABLE
    return float(math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2]).max(), 0.0)))


def single_frame_covariance(info: FloatArray) -> FloatArray:
    """``(A^T P A)^-1``, or a matrix of infinities where the frame cannot fix the pose."""
    w = np.linalg.eigvalsh(info)
    if w.min() <= 1e-9 * max(w.max(), 1e-300):
        return np.full((3, 3), UNOBSERVABLE)
    return np.asarray(np.linalg.inv(info), float)


def _route_frames(
    geometry: MapGeometry, poses: FloatArray, sensors: SensorModel, model: LocalizerModel
) -> tuple[FloatArray, dict[str, np.ndarray], FloatArray]:
    poses = np.asarray(poses, float).reshape(-1, 3)
    infos = np.zeros((len(poses), 3, 3))
    floors = np.zeros((len(poses), 3, 3))
    counts = {k: np.zeros(len(poses), int) for k in ("corners", "slots", "tags", "lines")}
    for k, pose in enumerate(poses):
        frame = _frame(geometry.around(pose, sensors, model), pose, sensors, model)
        infos[k], floors[k] = _expected_information(frame, sensors), frame.floor
        for key, value in frame.counts.items():
            counts[key][k] = value
    return infos, counts, floors


def route_information(
    geometry: MapGeometry,
    poses: FloatArray,
    sensors: SensorModel = SensorModel(),
    model: LocalizerModel = IDEAL,
) -> tuple[FloatArray, dict[str, np.ndarray]]:
    """:func:`frame_information` at every pose: (N, 3, 3) and the counts per pose."""
    infos, counts, _ = _route_frames(geometry, poses, sensors, model)
    return infos, counts


def route_floors(
    geometry: MapGeometry,
    poses: FloatArray,
    sensors: SensorModel = SensorModel(),
    model: LocalizerModel = IDEAL,
) -> FloatArray:
    """The pose covariance floor (N, 3, 3: the position block in m^2 and the heading
    variance in rad^2, no cross terms) the model's filter applies after the update at each
    pose (zeros without one; see :class:`LocalizerModel`)."""
    return _route_frames(geometry, poses, sensors, model)[2]


class RouteFilter:
    """The filter of :func:`filter_route` one pose at a time, so a caller can restart it
    anywhere along the route from a state it kept.

    A state is the (n, n) covariance of x, y (m), yaw (rad) in the map frame and, for a
    grade that estimates them (``n`` 5), the wheel scale and the gyro bias (rad/s).
    """

    def __init__(
        self,
        poses: FloatArray,
        times: FloatArray,
        grade: OdometryGrade = GRADES["automotive"],
        floors: FloatArray | None = None,
    ) -> None:
        self.poses = np.asarray(poses, float).reshape(-1, 3)
        self.times = np.asarray(times, float).reshape(-1)
        self.grade, self.floors = grade, floors
        self.n = 5 if grade.calibrated else 3
        self._sv2, self._sw2 = grade.speed_sigma**2, math.radians(grade.rate_sigma_deg) ** 2
        self._walk2 = grade.position_walk**2
        self._calibration_walk2 = (
            np.array([grade.scale_walk, math.radians(grade.bias_walk_deg)]) ** 2
        )

    def start(self, info: FloatArray) -> FloatArray:
        """The state at the first pose from its information ``info`` (3, 3): the frame's
        own covariance (or 1 m / 5 deg if it has none), the heading never better than the
        grade's."""
        grade = self.grade
        first = single_frame_covariance(info)
        P = np.zeros((self.n, self.n))
        P[:3, :3] = (
            first if np.all(np.isfinite(first)) else np.diag([1.0, 1.0, math.radians(5) ** 2])
        )
        P[2, 2] = max(P[2, 2], math.radians(grade.heading_sigma_deg) ** 2)
        if grade.calibrated:
            P[3, 3] = grade.scale_sigma**2
            P[4, 4] = math.radians(grade.bias_sigma_deg) ** 2
        return P

    def step(self, P: FloatArray, k: int, info: FloatArray) -> FloatArray:
        """The state at pose ``k`` (k >= 1) from the state ``P`` at pose ``k - 1`` and the
        information ``info`` (3, 3) of pose ``k``'s frame (see :func:`filter_route`)."""
        poses, grade = self.poses, self.grade
        dt = max(float(self.times[k] - self.times[k - 1]), 1e-6)
        step = poses[k, :2] - poses[k - 1, :2]
        c, s = math.cos(poses[k - 1, 2]), math.sin(poses[k - 1, 2])
        F = np.eye(self.n)
        F[0, 2], F[1, 2] = -step[1], step[0]
        if grade.calibrated:
            F[:2, 3] = -step  # the wheels over-read by the scale: the car went less far
            F[2, 4] = -dt  # the gyro over-reads by the bias: the car turned less
        P = F @ P @ F.T
        P[:2, :2] += self._sv2 * dt * np.array([[c * c, c * s], [c * s, s * s]])
        if self._walk2:
            P[:2, :2] += self._walk2 * dt * np.eye(2)
        P[2, 2] += self._sw2 * dt
        if grade.calibrated:
            P[3:, 3:] += np.diag(self._calibration_walk2 * dt)
        if info.any():
            full = np.zeros((self.n, self.n))
            full[:3, :3] = info
            P = np.linalg.inv(np.linalg.inv(P) + full)
        floors = self.floors
        if floors is not None and floors[k].any():
            gap = floors[k][:2, :2] - P[:2, :2]
            w, V = np.linalg.eigh(0.5 * (gap + gap.T))
            P[:2, :2] += (V * np.maximum(w, 0.0)) @ V.T
            if len(floors[k]) == 3:
                P[2, 2] = max(P[2, 2], floors[k][2, 2])
        return (P + P.T) / 2

    def states(self, infos: FloatArray) -> FloatArray:
        """The state at every pose (N, n, n), the frames' information ``infos`` (N, 3, 3)."""
        out = np.zeros((len(self.poses), self.n, self.n))
        if len(out):
            out[0] = P = self.start(infos[0])
            for k in range(1, len(out)):
                out[k] = P = self.step(P, k, infos[k])
        return out


def filter_route(
    infos: FloatArray,
    poses: FloatArray,
    times: FloatArray,
    grade: OdometryGrade = GRADES["automotive"],
    floors: FloatArray | None = None,
) -> FloatArray:
    """Filtered pose covariance (N, 3, 3) along a route from the frames' information.

    The filter starts from the first frame's own covariance (or 1 m / 5 deg if it has
    none, the heading never better than the grade's) and predicts between poses with
    the grade: speed noise along the travelled step, yaw-rate noise on the heading, the
    position walk on x and y (see :class:`OdometryGrade`), heading uncertainty carried
    into the position by the step. A grade that estimates the wheel scale and gyro bias
    carries them as two more states: the scale error moves the position along the step
    (by the step's length per unit of scale), the bias turns the heading (by ``dt`` per
    rad/s). After each update the position block is raised (in the PSD sense) to the
    position block of ``floors`` (N, 3, 3), and the heading variance to its ``[2, 2]``,
    where given, as the localizer does (a (N, 2, 2) ``floors`` is the position alone).
    See :class:`RouteFilter` for the filter one pose at a time.
    """
    return RouteFilter(poses, times, grade, floors).states(infos)[:, :3, :3].copy()


def position_sigmas(covs: FloatArray) -> FloatArray:
    """:func:`position_sigma` of each of ``covs`` (N, >=2, >=2) at once: (N,) m."""
    covs = np.asarray(covs, float)
    out = np.full(len(covs), UNOBSERVABLE)
    finite = np.all(np.isfinite(covs.reshape(len(covs), -1)), axis=1)
    if finite.any():
        w = np.linalg.eigvalsh(covs[finite][:, :2, :2]).max(axis=1)
        out[finite] = np.sqrt(np.maximum(w, 0.0))
    return out


def predicted_along_route(
    geometry: MapGeometry,
    poses: FloatArray,
    times: FloatArray,
    grade: OdometryGrade = GRADES["automotive"],
    sensors: SensorModel = SensorModel(),
    model: LocalizerModel = IDEAL,
) -> dict[str, FloatArray]:
    """Single-frame and filtered (:func:`filter_route`, with the model's floors) predicted
    accuracy at every pose.

    Returns:
        ``single_sigma`` and ``filtered_sigma`` (m, position semi-axis), ``single_yaw_deg``
        and ``filtered_yaw_deg`` (1-sigma), ``corners``, ``slots``, ``tags``, ``lines``
        (counts in view), ``covariance`` (N, 3, 3; the filtered covariance: m, rad; its
        heading as reported, :func:`reported_heading`).
    """
    infos, counts, floors = _route_frames(geometry, poses, sensors, model)
    filtered = reported_heading(geometry, poses,
                                filter_route(infos, poses, times, grade, floors), model)
    singles = [single_frame_covariance(info) for info in infos]
    return {
        "single_sigma": np.array([position_sigma(q) for q in singles]),
        "filtered_sigma": np.array([position_sigma(p) for p in filtered]),
        "single_yaw_deg": np.degrees(np.sqrt(np.array([q[2, 2] for q in singles]))),
        "filtered_yaw_deg": np.degrees(np.sqrt(filtered[:, 2, 2])),
        "covariance": filtered,
        **{k: v.astype(float) for k, v in counts.items()},
    }


def reported_heading(
    geometry: MapGeometry, poses: FloatArray, covs: FloatArray, model: LocalizerModel
) -> FloatArray:
    """``covs`` (N, 3, 3) at ``poses`` with each heading variance raised, as the localizer
    reports it, to ``map_floor_scale`` times the mean orientation variance of the map's
    slots within ``map_heading_radius`` of the pose; the filter itself is not raised, so
    this comes after :func:`filter_route`. A copy; ``covs`` itself if the model raises
    nothing."""
    k, radius = model.map_floor_scale, model.map_heading_radius
    if k <= 0 or radius <= 0 or not len(geometry.slot_centres):
        return covs
    out = np.array(covs, float)
    for n, pose in enumerate(np.asarray(poses, float).reshape(-1, 3)):
        heading = geometry.heading_variance_near(pose, radius)
        if heading is not None and out[n, 2, 2] < k * heading:
            out[n, 2, 2] = k * heading
    return out


def predicted_on_grid(
    geometry: MapGeometry,
    step: float = 1.0,
    headings_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0),
    sensors: SensorModel = SensorModel(),
    bounds: tuple[float, float, float, float] | None = None,
    model: LocalizerModel = IDEAL,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Single-frame position sigma (m) on a grid over ``bounds`` (xmin, ymin, xmax, ymax;
    default: the map's landmarks plus 2 m): the worst over ``headings_deg`` at each cell.
    Returns the grid's x (W,), y (H,) and sigma (H, W).

    Raises:
        ConfigError: a step that is not a positive finite number, bounds that are not
            finite, a grid of fewer than 2 cells either way, or of more than
            :data:`MAX_GRID_CELLS` cells (refused before
            anything is allocated: a tiny step or a far-away landmark or route)."""
    x0, y0, x1, y1 = bounds or geometry.bounds()
    _check_grid(x0, y0, x1, y1, step)
    xs = np.arange(x0, x1 + 1e-9, step)
    ys = np.arange(y0, y1 + 1e-9, step)
    sigma = np.zeros((len(ys), len(xs)))
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            worst = 0.0
            near = geometry.around(np.array([x, y]), sensors, model)
            for h in headings_deg:
                pose = np.array([x, y, math.radians(h)])
                info, _ = frame_information(near, pose, sensors, model)
                worst = max(worst, position_sigma(single_frame_covariance(info)))
            sigma[i, j] = worst
    return xs, ys, sigma


MAX_GRID_CELLS = 4_000_000
"""Most cells :func:`predicted_on_grid` computes (at a few ms a cell, already hours)."""

MIN_GRID_STEP = 1e-3
"""Smallest grid step, metres (a millimetre: finer says nothing more about a pose sigma)."""


def _check_grid(x0: float, y0: float, x1: float, y1: float, step: float) -> None:
    """Refuse a step, bounds or cell count (:data:`MAX_GRID_CELLS`) the grid cannot have."""
    if not (math.isfinite(step) and step >= MIN_GRID_STEP):
        raise ConfigError(
            f"accuracy: the grid step must be a number of metres >= {MIN_GRID_STEP:g}, "
            f"got {step:g}"
        )
    if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or x1 < x0 or y1 < y0:
        raise ConfigError(f"accuracy: the grid bounds {(x0, y0, x1, y1)} are not a finite box")
    nx = math.floor((x1 - x0 + 1e-9) / step) + 1
    ny = math.floor((y1 - y0 + 1e-9) / step) + 1
    if min(nx, ny) < 2:
        raise ConfigError(
            f"accuracy: a step of {step:g} m leaves a grid of {nx} x {ny} cells over "
            f"{x1 - x0:.4g} m x {y1 - y0:.4g} m (at least 2 each way); lower --grid-step "
            f"to {min(x1 - x0, y1 - y0):.4g} m or less"
        )
    if nx * ny > MAX_GRID_CELLS:
        raise ConfigError(
            f"accuracy: a grid of {nx * ny:.3g} cells ({nx} x {ny}, {x1 - x0:.4g} m x "
            f"{y1 - y0:.4g} m at {step:g} m) is more than {MAX_GRID_CELLS:,}; raise "
            "--grid-step or check the map extent (and the route's)"
        )


def worst_stretches(
    distance: FloatArray, sigma: FloatArray, threshold: float, limit: int = 5
) -> list[dict[str, float]]:
    """Contiguous stretches of a route where ``sigma`` exceeds ``threshold`` (m), longest
    first: start and end (metres along the route), length and the worst sigma."""
    above = np.asarray(sigma) > threshold
    out = []
    k = 0
    while k < len(above):
        if not above[k]:
            k += 1
            continue
        j = k
        while j + 1 < len(above) and above[j + 1]:
            j += 1
        out.append(
            {
                "start_m": float(distance[k]),
                "end_m": float(distance[j]),
                "length_m": float(distance[j] - distance[k]),
                "worst_sigma_m": float(np.max(sigma[k : j + 1])),
            }
        )
        k = j + 1
    out.sort(key=lambda s: (-s["length_m"], -s["worst_sigma_m"]))
    return out[:limit]


__all__ = [
    "GRADES",
    "IDEAL",
    "SLOT_RULES",
    "UNOBSERVABLE",
    "LocalizerModel",
    "MapGeometry",
    "OdometryGrade",
    "RouteFilter",
    "SensorModel",
    "frame_information",
    "filter_route",
    "localizer_grade",
    "localizer_model",
    "position_sigma",
    "position_sigmas",
    "predicted_along_route",
    "predicted_on_grid",
    "reported_heading",
    "route_floors",
    "route_information",
    "simulated_sensors",
    "single_frame_covariance",
    "tag_information",
    "worst_stretches",
]
