"""Seeded garage worlds: aisles along +x, rows of slots on both sides, cross aisles at the ends.

Layout, bottom (small y) to top: a row whose slots open upward onto aisle
n-1, the aisle, a row opening downward onto it, back to back with the next
aisle's row, and so on. Cross aisles at both ends join the aisles into loops
(a single-aisle world gets wide turnaround areas instead). Every choice that
is random comes from ``numpy.random.default_rng(seed)``, so a seed fixes the
world exactly.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from semslam.errors import SimulationError
from semslam.geometry import FloatArray
from semslam.simulation.world_types import (
    Aisle,
    MarkingPoint,
    ParkedCar,
    Pillar,
    SlotPaint,
    Wall,
    World,
)
from semslam.types import JunctionShape, Marking, Slot, SlotKind, Tag, TagFamily

AISLE_WIDTH = 6.0
ROW_END_MARGIN = 0.8  # free floor between a row's last junction and its end, m
PILLAR_SIDE = 0.6
TAG36H11_CODES = 587
LABEL_CHARS = "ABCDEFGHJKLMNPQRSTUVWXYZ"  # no I, O: painted they read as 1, 0


@dataclass(frozen=True)
class Preset:
    """Size of a world: aisle count and length (m), row kinds bottom-up (two per aisle),
    cross-aisle width (m) and how many tags."""

    n_aisles: int
    aisle_length: float
    row_kinds: tuple[SlotKind, ...]
    cross_width: float
    n_tags: int


_P, _L, _S = SlotKind.PERPENDICULAR, SlotKind.PARALLEL, SlotKind.SLANTED

PRESETS: dict[str, Preset] = {
    "small": Preset(1, 52.0, (_P, _P), 16.0, 4),
    "garage": Preset(3, 90.0, (_L, _P, _P, _S, _P, _P), 8.0, 10),
    "large": Preset(10, 250.0, (_P, _P, _P, _S, _P, _P, _L, _P, _P, _P) * 2, 8.0, 40),
}


@dataclass(frozen=True)
class _RowGeometry:
    kind: SlotKind
    entrance_y: float
    normal: int  # +1: slots extend to +y from the entrance line, -1: to -y
    slot_width: float  # across the slot, perpendicular to its separators
    separator_angle: float  # between separator and entrance line, rad
    separator_length: float

    @property
    def depth(self) -> float:
        return self.separator_length * math.sin(self.separator_angle)

    @property
    def pitch(self) -> float:
        """Distance between junctions along the entrance line."""
        return self.slot_width / math.sin(self.separator_angle)


def _row_geometry(kind: SlotKind, rng: np.random.Generator, entrance_y: float, normal: int):
    if kind is SlotKind.PERPENDICULAR:
        return _RowGeometry(kind, entrance_y, normal, rng.uniform(2.4, 2.7), math.pi / 2, 5.0)
    if kind is SlotKind.SLANTED:
        angle = math.radians(rng.choice([45.0, 60.0]))
        return _RowGeometry(kind, entrance_y, normal, rng.uniform(2.4, 2.6), angle, 5.0)
    # parallel: the long side is the entrance
    return _RowGeometry(kind, entrance_y, normal, rng.uniform(5.6, 6.4), math.pi / 2, 2.5)


class _Builder:
    """Accumulates the world's parts row by row."""

    def __init__(self, rng: np.random.Generator, line_width: float) -> None:
        self.rng = rng
        self.line_width = line_width
        self.slots: list[Slot] = []
        self.paint: list[SlotPaint] = []
        self.markings: list[Marking] = []
        self.points: list[MarkingPoint] = []
        self.cars: list[ParkedCar] = []

    def add_row(self, row: _RowGeometry, length: float, labels: list[str], paint_rear: bool):
        rng, w = self.rng, self.line_width
        pitch = row.pitch
        # slanted separators lean forward: the rear end shifts along the row
        lean = row.separator_length * math.cos(row.separator_angle)
        usable = length - 2 * ROW_END_MARGIN - abs(lean)
        n = int(usable // pitch)
        if n < 1:
            return
        x0 = ROW_END_MARGIN + (usable - n * pitch) / 2.0 + max(0.0, -lean)
        sep = np.array([math.cos(row.separator_angle), row.normal * math.sin(row.separator_angle)])
        nvec = np.array([0.0, float(row.normal)])
        junctions = [np.array([x0 + k * pitch, row.entrance_y]) for k in range(n + 1)]
        for k, p in enumerate(junctions):
            shape = JunctionShape.L if k in (0, n) else JunctionShape.T
            self.points.append(MarkingPoint(p, math.atan2(sep[1], sep[0]), shape))
            self.markings.append(Marking(p.copy(), p + sep * row.separator_length, w))
        continuous = rng.random() < 0.5
        if continuous:
            self.markings.append(Marking(junctions[0].copy(), junctions[-1].copy(), w))
        else:  # T and L stubs at each junction
            stub = min(0.45, pitch / 3.0)
            for k, p in enumerate(junctions):
                a = p - [stub, 0.0] if k > 0 else p.copy()
                b = p + [stub, 0.0] if k < n else p.copy()
                self.markings.append(Marking(a, b, w))
        if paint_rear:
            rear = [j + sep * row.separator_length for j in (junctions[0], junctions[-1])]
            self.markings.append(Marking(rear[0], rear[1], w))
        left = np.array([-nvec[1], nvec[0]])  # left of a viewer in the aisle facing the slots
        for k in range(n):
            p0, p1 = junctions[k], junctions[k + 1]
            el, er = (p0, p1) if float(np.dot(p1 - p0, left)) < 0 else (p1, p0)
            corners = np.array(
                [el, er, er + sep * row.separator_length, el + sep * row.separator_length]
            )
            slot_id = len(self.slots)
            self.slots.append(
                Slot(slot_id, labels[k], 1.0, corners, np.zeros((4, 2, 2)), row.kind, 0)
            )
            centre_entrance = (p0 + p1) / 2.0
            text_h = rng.uniform(0.35, 0.55)
            self.paint.append(
                SlotPaint(
                    slot_id,
                    centre_entrance + sep * (0.35 + text_h),
                    math.atan2(sep[1], sep[0]),
                    text_h,
                )
            )
            if rng.random() < 0.45:
                self.cars.append(self._parked_car(corners, row))

    def _parked_car(self, corners: FloatArray, row: _RowGeometry) -> ParkedCar:
        rng = self.rng
        centre = corners.mean(axis=0) + rng.normal(0.0, 0.08, 2)
        # a parked car lies along the separators, or along the kerb in a parallel slot
        long_side = (1, 0) if row.kind is SlotKind.PARALLEL else (3, 0)
        axis = corners[long_side[0]] - corners[long_side[1]]
        yaw = (
            math.atan2(axis[1], axis[0])
            + rng.normal(0.0, 0.03)
            + (math.pi if rng.random() < 0.5 else 0.0)
        )
        palette = [
            (40, 40, 40),
            (200, 200, 205),
            (235, 235, 235),
            (50, 50, 150),
            (140, 90, 30),
            (30, 30, 30),
            (120, 120, 125),
            (40, 110, 40),
            (20, 60, 170),
            (160, 160, 60),
        ]
        colour = palette[int(rng.integers(len(palette)))]
        return ParkedCar(
            centre,
            float(yaw),
            rng.uniform(4.1, 4.8),
            rng.uniform(1.72, 1.9),
            rng.uniform(1.42, 1.65),
            colour,
        )


def _row_labels(rng: np.random.Generator, row_index: int, count: int, letter: str) -> list[str]:
    """Painted IDs for one row: ``B17`` style, or plain numbers ``117`` (2-4 characters).
    A row of more than 99 slots (``large``) is lettered: its numbers would run into the next
    row's hundred."""
    if rng.random() < 0.7 or count > 99:
        return [f"{letter}{k + 1}" for k in range(count)]
    start = (row_index + 1) * 100 + 1
    return [str(start + k) for k in range(count)]


def make_world(preset: str = "garage", seed: int = 0) -> World:
    """Build the garage world of ``preset`` (small, garage, large) from ``seed``."""
    if preset not in PRESETS:
        raise SimulationError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    spec = PRESETS[preset]
    rng = np.random.default_rng(seed)
    line_width = float(rng.uniform(0.10, 0.25))
    line_colour = (235, 235, 235) if rng.random() < 0.6 else (40, 200, 230)
    builder = _Builder(rng, line_width)
    letters = list(LABEL_CHARS)
    rng.shuffle(letters)
    length = spec.aisle_length
    y = 0.0
    aisle_centres: list[float] = []
    rear_pillar_ys: list[float] = []
    rows: list[_RowGeometry] = []
    for a in range(spec.n_aisles):
        below_kind, above_kind = spec.row_kinds[2 * a], spec.row_kinds[2 * a + 1]
        if a > 0:
            rear_pillar_ys.append(y)
        below = _row_geometry(below_kind, rng, 0.0, -1)
        below = _RowGeometry(
            below.kind,
            y + below.depth,
            -1,
            below.slot_width,
            below.separator_angle,
            below.separator_length,
        )
        aisle_centres.append(below.entrance_y + AISLE_WIDTH / 2.0)
        above = _row_geometry(above_kind, rng, below.entrance_y + AISLE_WIDTH, +1)
        rows += [below, above]
        y = above.entrance_y + above.depth
    top = y
    for r, row in enumerate(rows):
        n_est = int((length - 2 * ROW_END_MARGIN) // row.pitch) + 1
        labels = _row_labels(rng, r, n_est, letters[r % len(letters)])
        paint_rear = row.kind is not SlotKind.PARALLEL and row.normal > 0 and rng.random() < 0.5
        builder.add_row(row, length, labels, paint_rear)

    pillars, tag_faces = _pillars_and_tag_faces(rows, rear_pillar_ys, length, rng)
    tags = _place_tags(tag_faces, spec.n_tags, rng)
    xmin, xmax = -spec.cross_width, length + spec.cross_width
    ymin, ymax = -0.3, top + 0.3
    corners = [np.array(c) for c in ((xmin, ymin), (xmax, ymin), (xmax, ymax), (xmin, ymax))]
    walls = tuple(Wall(corners[i], corners[(i + 1) % 4], 3.0) for i in range(4))
    cx_west, cx_east = -spec.cross_width / 2.0, length + spec.cross_width / 2.0
    aisles = [
        Aisle(np.array([cx_west, c]), np.array([cx_east, c]), AISLE_WIDTH)
        for c in reversed(aisle_centres)
    ]  # aisle 0 at the top
    if spec.n_aisles > 1:
        for cx in (cx_west, cx_east):
            aisles.append(
                Aisle(
                    np.array([cx, aisle_centres[0]]),
                    np.array([cx, aisle_centres[-1]]),
                    spec.cross_width,
                )
            )
    return World(
        preset=preset,
        seed=seed,
        slots=tuple(builder.slots),
        tags=tuple(tags),
        markings=tuple(builder.markings),
        marking_points=tuple(builder.points),
        slot_paint=tuple(builder.paint),
        pillars=tuple(pillars),
        walls=walls,
        parked_cars=tuple(builder.cars),
        aisles=tuple(aisles),
        bounds=(xmin, ymin, xmax, ymax),
        line_colour=line_colour,
    )


def _pillars_and_tag_faces(rows, rear_ys, length, rng):
    """Pillars at both ends of every row and along shared rear lines; the faces a tag
    can hang on as (centre (2,), outward normal yaw, priority)."""
    pillars: list[Pillar] = []
    faces: list[tuple[FloatArray, float, int]] = []
    half = PILLAR_SIDE / 2.0
    for row in rows:
        y = row.entrance_y + row.normal * min(1.5, row.depth / 2.0)
        for x, face_yaw in (
            (ROW_END_MARGIN / 2.0 - 0.1, 0.0),
            (length - ROW_END_MARGIN / 2.0 + 0.1, math.pi),
        ):
            centre = np.array([x, y])
            pillars.append(Pillar(centre, PILLAR_SIDE, 3.0))
            normal = np.array([math.cos(face_yaw), math.sin(face_yaw)])
            faces.append((centre + normal * (half + 0.005), face_yaw, 0))
    for y in rear_ys:
        for x in np.arange(10.0, length - 5.0, 3 * 2.5 * 3):
            centre = np.array([x, y])
            pillars.append(Pillar(centre, PILLAR_SIDE, 3.0))
            for face_yaw in (math.pi / 2, -math.pi / 2):
                normal = np.array([math.cos(face_yaw), math.sin(face_yaw)])
                faces.append((centre + normal * (half + 0.005), face_yaw, 1))
    return pillars, faces


def _place_tags(faces, n_tags, rng) -> list[Tag]:
    """Up to ``n_tags`` tag36h11 tags, row-end faces first, spread by random order."""
    order = sorted(range(len(faces)), key=lambda i: (faces[i][2], rng.random()))
    chosen = order[: min(n_tags, len(faces))]
    ids = rng.choice(TAG36H11_CODES, size=len(chosen), replace=False)
    tags = []
    for tag_id, i in zip(ids, chosen, strict=True):
        centre, yaw, _ = faces[i]
        tags.append(
            Tag(
                TagFamily.TAG36H11,
                int(tag_id),
                0.5,
                np.array([centre[0], centre[1], yaw]),
                float(rng.uniform(1.4, 1.9)),
                np.zeros((3, 3)),
            )
        )
    return tags


PLACED_TAG_SIZE = 0.5  # m, as the world's own tags
PLACED_TAG_HEIGHT = 1.6  # m, tag centre above the ground


def with_placed_tags(world: World, poses: FloatArray | None) -> World:
    """The world with tag36h11 tags added at ``poses`` (K, 3: x, y m and the yaw they face,
    map frame; e.g. a `semslam plan-tags` plan), numbered with the lowest IDs the world does
    not use, free-standing (no pillar), 0.5 m, centre 1.6 m above the ground. No poses (None
    or K = 0): the world as it is.

    Raises:
        SimulationError: more tags than tag36h11 has codes left.
    """
    if poses is None or not len(poses):
        return world
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    used = {t.tag_id for t in world.tags if t.family is TagFamily.TAG36H11}
    free = [i for i in range(TAG36H11_CODES) if i not in used]
    if len(poses) > len(free):
        raise SimulationError(
            f"{len(poses)} tags to place, but tag36h11 has only {len(free)} codes left"
        )
    added = tuple(
        Tag(TagFamily.TAG36H11, tag_id, PLACED_TAG_SIZE, pose.copy(), PLACED_TAG_HEIGHT,
            np.zeros((3, 3)))
        for tag_id, pose in zip(free, poses, strict=False)
    )
    return dataclasses.replace(world, tags=world.tags + added)


__all__ = ["PRESETS", "Preset", "make_world", "with_placed_tags"]
