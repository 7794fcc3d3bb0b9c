"""Simulated detectors: exact and noisy slot, tag and marking observations per frame.

Exact observations are the truth seen from the true pose (what a perfect
detector would report: slots whose entrance is inside the top view, markings
clipped to it, tags in the front camera's view and range). Noisy ones are
derived from them with :class:`ObservationNoiseConfig`: misses, false
detections, corner and end-point noise, wrong IDs whose confidence is drawn
from the same range as right ones, tag range and bearing noise growing with
distance. All vehicle-frame, metres and radians.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from semslam.config import ObservationNoiseConfig
from semslam.geometry import FloatArray, clip_segment, inverse_transform_points, wrap_angle
from semslam.rig import Rig
from semslam.simulation.world_types import World
from semslam.types import (
    FrameObservations,
    MarkingObservation,
    SlotKind,
    SlotObservation,
    TagObservation,
)

_CHUNK = 4.0  # long markings are indexed in pieces of this length, m


def clip_segment_to_square(a: FloatArray, b: FloatArray, half: float):
    """Clip segment a-b (2,) to the square |x|, |y| <= half; None if outside."""
    return clip_segment(a, b, -half, half)


def tag_observation_covariance(
    vTt: FloatArray, camera_xy: FloatArray, cfg: ObservationNoiseConfig
) -> FloatArray:
    """Covariance of a tag observation (x, y, yaw in the vehicle frame) from range noise
    ``sigma_abs + sigma_rel * r`` and bearing noise about the camera, plus PnP yaw noise."""
    rel = vTt[:2] - camera_xy
    r = float(np.hypot(*rel))
    b = math.atan2(rel[1], rel[0])
    sr = cfg.tag_range_sigma_abs + cfg.tag_range_sigma_rel * r
    sb = math.radians(cfg.tag_bearing_sigma_deg)
    sy = math.radians(cfg.tag_yaw_sigma_deg)
    J = np.array(
        [[math.cos(b), -r * math.sin(b), 0.0], [math.sin(b), r * math.cos(b), 0.0], [0.0, 0.0, 1.0]]
    )
    return J @ np.diag([sr * sr, sb * sb, sy * sy]) @ J.T


class ExactSensor:
    """What a perfect detector reports from a true pose; built once per world."""

    def __init__(self, world: World, rig: Rig, cfg: ObservationNoiseConfig) -> None:
        self.world, self.rig, self.cfg = world, rig, cfg
        self.half = rig.topview.half_extent_m
        self._slot_entrances = np.array([s.corners[:2] for s in world.slots]).reshape(-1, 2, 2)
        self._slot_tree = cKDTree(self._slot_entrances.mean(axis=1))
        pieces, owners = [], []
        for i, m in enumerate(world.markings):
            n = max(1, int(np.ceil(np.linalg.norm(m.b - m.a) / _CHUNK)))
            for k in range(n + 1):
                pieces.append(m.a + (m.b - m.a) * k / n)
                owners.append(i)
        self._marking_tree = cKDTree(np.array(pieces))
        self._marking_owner = np.array(owners)
        self._pillars = [p.footprint for p in world.pillars]
        self.camera = rig.cameras.get("front")

    def observe(self, t: float, mTv: FloatArray) -> FrameObservations:
        return FrameObservations(
            t=t,
            slots=self._slots(mTv),
            tags=self._tags(mTv) if self.camera is not None else (),
            markings=self._markings(mTv),
        )

    def _slots(self, mTv: FloatArray) -> tuple[SlotObservation, ...]:
        out = []
        reach = self.half * math.sqrt(2) + 0.5
        ego_x, ego_y = self.rig.topview.ego_length_m / 2, self.rig.topview.ego_width_m / 2
        margin = self.half - 0.15
        for i in sorted(self._slot_tree.query_ball_point(mTv[:2], reach)):
            slot = self.world.slots[i]
            vC = inverse_transform_points(mTv, slot.corners)
            ent = vC[:2]
            if np.any(np.abs(ent) > margin):
                continue
            if np.any((np.abs(ent[:, 0]) < ego_x) & (np.abs(ent[:, 1]) < ego_y)):
                continue
            out.append(
                SlotObservation(vC, slot.kind, slot.label, 1.0, 1.0, self.cfg.slot_exact_sigma)
            )
        return tuple(out)

    def _markings(self, mTv: FloatArray) -> tuple[MarkingObservation, ...]:
        hits = self._marking_tree.query_ball_point(mTv[:2], self.half * math.sqrt(2) + _CHUNK)
        out = []
        for i in sorted(set(self._marking_owner[hits].tolist())):
            m = self.world.markings[i]
            vA, vB = inverse_transform_points(mTv, np.array([m.a, m.b]))
            clipped = clip_segment_to_square(vA, vB, self.half)
            if (
                clipped is None
                or np.linalg.norm(clipped[1] - clipped[0]) < self.cfg.marking_min_length
            ):
                continue
            out.append(MarkingObservation(clipped[0], clipped[1], m.width, 1.0))
        return tuple(out)

    def _tags(self, mTv: FloatArray) -> tuple[TagObservation, ...]:
        cam = self.camera
        assert cam is not None
        cfg = self.cfg
        cam_v = cam.T_vehicle_camera[:3, 3]
        cam_m = (
            mTv[:2]
            + np.array(
                [[math.cos(mTv[2]), -math.sin(mTv[2])], [math.sin(mTv[2]), math.cos(mTv[2])]]
            )
            @ cam_v[:2]
        )
        w, h = cam.size
        out = []
        for tag in self.world.tags:
            to_cam = cam_m - tag.mTt[:2]
            dist = float(np.hypot(*to_cam))
            if dist > cfg.tag_range_limit or dist < 0.5:
                continue
            normal = np.array([math.cos(tag.mTt[2]), math.sin(tag.mTt[2])])
            cos_inc = float(np.dot(normal, to_cam)) / dist
            if cos_inc < math.cos(math.radians(cfg.tag_max_incidence_deg)):
                continue
            vTt_xy = inverse_transform_points(mTv, tag.mTt[:2])
            side = np.array([-normal[1], normal[0]]) * tag.size / 2
            corners_m = [tag.mTt[:2] + s * side for s in (-1, 1)]
            corners_3d = [
                np.append(inverse_transform_points(mTv, c), tag.height + dz)
                for c in corners_m
                for dz in (-tag.size / 2, tag.size / 2)
            ]
            uv, z = cam.project_vehicle_points(np.array(corners_3d))
            if (
                np.any(z < 0.3)
                or np.any(uv < 2)
                or np.any(uv[:, 0] > w - 3)
                or np.any(uv[:, 1] > h - 3)
            ):
                continue
            if np.ptp(uv[:, 0]) < cfg.tag_min_pixels and np.ptp(uv[:, 1]) < cfg.tag_min_pixels:
                continue
            if self._occluded(cam_m, tag.mTt[:2]):
                continue
            vTt = np.array([vTt_xy[0], vTt_xy[1], wrap_angle(tag.mTt[2] - mTv[2])])
            cov = tag_observation_covariance(vTt, cam_v[:2], cfg)
            out.append(TagObservation(tag.family, tag.tag_id, tag.size, vTt, tag.height, cov))
        return tuple(out)

    def _occluded(self, a: FloatArray, b: FloatArray) -> bool:
        """Does the sight line a-b (map frame) cross a pillar?"""
        for fp in self._pillars:
            centre = fp.mean(axis=0)
            if np.linalg.norm(centre - b) < 0.6:  # the tag's own pillar
                continue
            half = (fp[:, 0].max() - fp[:, 0].min()) / 2
            if clip_segment_to_square(a - centre, b - centre, half) is not None:
                return True
        return False


class NoisySensor:
    """Corrupts exact observations the way a real detector would (see module docstring)."""

    def __init__(
        self, world: World, rig: Rig, cfg: ObservationNoiseConfig, rng: np.random.Generator
    ) -> None:
        self.world, self.rig, self.cfg, self.rng = world, rig, cfg, rng
        self.half = rig.topview.half_extent_m
        self.labels = [s.label for s in world.slots if s.label]
        self._label_index = {s.label: i for i, s in enumerate(world.slots)}
        self.camera_xy = (
            rig.cameras["front"].T_vehicle_camera[:2, 3] if "front" in rig.cameras else np.zeros(2)
        )

    def corrupt(self, exact: FrameObservations) -> FrameObservations:
        return FrameObservations(
            t=exact.t,
            slots=self._slots(exact.slots),
            tags=self._tags(exact.tags),
            markings=self._markings(exact.markings),
        )

    # -- slots
    def _confidence(self, bounds: tuple[float, float]) -> float:
        return float(self.rng.uniform(*bounds))

    def _read_label(self, true_label: str | None) -> tuple[str | None, float]:
        cfg, rng = self.cfg, self.rng
        if true_label is None or rng.random() < cfg.id_missing_rate:
            return None, 0.0
        conf = self._confidence(cfg.label_confidence_range)
        if rng.random() < cfg.id_error_rate:
            return self._wrong_label(true_label), conf
        return true_label, conf

    def _wrong_label(self, true_label: str) -> str:
        """A plausible misread: a nearby slot's label, or one character swapped."""
        rng = self.rng
        if rng.random() < 0.5 and true_label in self._label_index:
            i = self._label_index[true_label] + int(rng.choice([-2, -1, 1, 2]))
            if 0 <= i < len(self.world.slots) and self.world.slots[i].label not in (
                None,
                true_label,
            ):
                return str(self.world.slots[i].label)
        confusions = {
            "1": "7",
            "7": "1",
            "3": "8",
            "8": "3",
            "5": "6",
            "6": "5",
            "0": "8",
            "2": "Z",
            "B": "8",
            "E": "F",
            "F": "E",
            "4": "9",
            "9": "4",
            "Z": "2",
        }
        k = int(rng.integers(len(true_label)))
        ch = true_label[k]
        new = confusions.get(ch, "0123456789"[(int(ch, 36) + 1) % 10] if ch.isdigit() else "H")
        if new == ch:
            new = "4"
        return true_label[:k] + new + true_label[k + 1 :]

    def _slots(self, exact: tuple[SlotObservation, ...]) -> tuple[SlotObservation, ...]:
        cfg, rng = self.cfg, self.rng
        out = []
        for s in exact:
            if rng.random() < cfg.slot_miss_rate:
                continue
            label, lconf = self._read_label(s.label)
            corners = s.vCorners + rng.normal(0.0, cfg.slot_corner_sigma, (4, 2))
            out.append(
                SlotObservation(
                    corners,
                    s.kind,
                    label,
                    lconf,
                    self._confidence(cfg.detection_confidence_range),
                    max(cfg.slot_corner_sigma, 1e-3),
                )
            )
        n_false = rng.poisson(cfg.slot_false_rate / (1 - cfg.slot_false_rate) * max(len(out), 0.5))
        for _ in range(n_false):
            out.append(self._false_slot(exact))
        order = rng.permutation(len(out))
        return tuple(out[i] for i in order)

    def _false_slot(self, exact: tuple[SlotObservation, ...]) -> SlotObservation:
        """A ghost: a real slot shifted by part of a slot width, or a random rectangle."""
        cfg, rng = self.cfg, self.rng
        if exact and rng.random() < 0.5:
            base = exact[int(rng.integers(len(exact)))]
            along = base.vCorners[1] - base.vCorners[0]
            corners = base.vCorners + along * rng.uniform(0.35, 0.65) * rng.choice([-1, 1])
            kind = base.kind
        else:
            yaw = rng.uniform(-math.pi, math.pi)
            c, s = math.cos(yaw), math.sin(yaw)
            local = np.array([[0, 0], [2.5, 0], [2.5, 5.0], [0, 5.0]])
            origin = rng.uniform(-self.half + 0.5, self.half - 0.5, 2)
            corners = local @ np.array([[c, s], [-s, c]]) + origin
            kind = SlotKind.PERPENDICULAR
        corners = corners + rng.normal(0.0, cfg.slot_corner_sigma, (4, 2))
        label = (
            str(self.labels[int(rng.integers(len(self.labels)))])
            if rng.random() > cfg.id_missing_rate
            else None
        )
        lconf = self._confidence(cfg.label_confidence_range) if label else 0.0
        return SlotObservation(
            corners,
            kind,
            label,
            lconf,
            self._confidence(cfg.detection_confidence_range),
            max(cfg.slot_corner_sigma, 1e-3),
        )

    # -- markings
    def _markings(self, exact: tuple[MarkingObservation, ...]) -> tuple[MarkingObservation, ...]:
        cfg, rng = self.cfg, self.rng
        out = []
        for m in exact:
            if rng.random() < cfg.marking_miss_rate:
                continue
            a = m.vA + rng.normal(0.0, cfg.marking_endpoint_sigma, 2)
            b = m.vB + rng.normal(0.0, cfg.marking_endpoint_sigma, 2)
            out.append(
                MarkingObservation(a, b, m.width, self._confidence(cfg.detection_confidence_range))
            )
        n_false = rng.poisson(
            cfg.marking_false_rate / (1 - cfg.marking_false_rate) * max(len(out), 0.5)
        )
        for _ in range(n_false):
            a = rng.uniform(-self.half + 0.3, self.half - 0.3, 2)
            ang = rng.uniform(-math.pi, math.pi)
            b = a + rng.uniform(0.5, 3.0) * np.array([math.cos(ang), math.sin(ang)])
            clipped = clip_segment_to_square(a, b, self.half)
            if clipped is None:
                continue
            out.append(
                MarkingObservation(
                    clipped[0],
                    clipped[1],
                    float(rng.uniform(0.1, 0.25)),
                    self._confidence(cfg.detection_confidence_range),
                )
            )
        return tuple(out)

    # -- tags
    def _tags(self, exact: tuple[TagObservation, ...]) -> tuple[TagObservation, ...]:
        cfg, rng = self.cfg, self.rng
        out = []
        for tag in exact:
            if rng.random() < cfg.tag_miss_rate:
                continue
            rel = tag.vTt[:2] - self.camera_xy
            r, b = float(np.hypot(*rel)), math.atan2(rel[1], rel[0])
            r += rng.normal(0.0, cfg.tag_range_sigma_abs + cfg.tag_range_sigma_rel * r)
            b += rng.normal(0.0, math.radians(cfg.tag_bearing_sigma_deg))
            yaw = wrap_angle(tag.vTt[2] + rng.normal(0.0, math.radians(cfg.tag_yaw_sigma_deg)))
            vTt = np.array(
                [self.camera_xy[0] + r * math.cos(b), self.camera_xy[1] + r * math.sin(b), yaw]
            )
            cov = tag_observation_covariance(vTt, self.camera_xy, cfg)
            out.append(TagObservation(tag.family, tag.tag_id, tag.size, vTt, tag.height, cov))
        return tuple(out)
