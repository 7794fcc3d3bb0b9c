"""What a simulated garage is made of, in the map (world) frame, metres.

The true map (slots, tags, markings) plus what only the renderer needs:
marking points with their junction shape, pillars, walls, parked cars,
and the aisle lanes the route planner drives along.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semslam.geometry import FloatArray
from semslam.types import JunctionShape, Marking, SemanticMap, Slot, Tag


@dataclass(frozen=True, eq=False)
class MarkingPoint:
    """A painted junction at a slot's entrance corner (what the marking-point CNN finds).

    Attributes:
        position: (2,) where the separator's centre line meets the entrance line, map frame.
        direction: heading (rad, map frame) of the separator line from the junction into the slot.
        shape: T (entrance line continues on both sides) or L (it ends here).
    """

    position: FloatArray
    direction: float
    shape: JunctionShape


@dataclass(frozen=True, eq=False)
class Pillar:
    """A square concrete pillar: centre (2,), side length and height, metres."""

    centre: FloatArray
    side: float
    height: float

    @property
    def footprint(self) -> FloatArray:
        """(4, 2) corners counter-clockwise, map frame."""
        h = self.side / 2.0
        return self.centre + np.array([[-h, -h], [h, -h], [h, h], [-h, h]])


@dataclass(frozen=True, eq=False)
class Wall:
    """A wall from ``a`` to ``b`` (2,) with a height, metres."""

    a: FloatArray
    b: FloatArray
    height: float


@dataclass(frozen=True, eq=False)
class ParkedCar:
    """A parked car: centre (2,), heading (rad), length, width, height (m), colour BGR 0-255."""

    centre: FloatArray
    yaw: float
    length: float
    width: float
    height: float
    colour: tuple[int, int, int]

    @property
    def footprint(self) -> FloatArray:
        """(4, 2) corners counter-clockwise, map frame."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        hl, hw = self.length / 2.0, self.width / 2.0
        local = np.array([[-hl, -hw], [hl, -hw], [hl, hw], [-hl, hw]])
        return local @ np.array([[c, s], [-s, c]]) + self.centre


@dataclass(frozen=True, eq=False)
class Aisle:
    """A straight driving lane: centre line from ``a`` to ``b`` (2,) and full width (m)."""

    a: FloatArray
    b: FloatArray
    width: float


@dataclass(frozen=True, eq=False)
class SlotPaint:
    """How a slot's ID is painted: the label's text centre (2,), the text's up direction
    (rad, map frame: the text reads upright for a viewer standing in the aisle looking
    into the slot), and the character height (m)."""

    slot_id: int
    centre: FloatArray
    up: float
    text_height: float


@dataclass(frozen=True, eq=False)
class World:
    """A whole simulated garage.

    Attributes:
        preset, seed: what built it.
        slots, tags, markings: the true map elements (covariances zero).
        marking_points: every painted entrance junction.
        slot_paint: where each slot's ID is painted (same order as ``slots``).
        pillars, walls, parked_cars: solid things for the renderers and occlusion.
        aisles: driving lanes: the ``rows`` aisles along +x, then the cross aisles.
        bounds: (xmin, ymin, xmax, ymax) of the floor, metres.
        line_colour: paint colour BGR (white or yellow).
        marking_colours: per marking (same order as ``markings``), a BGR colour of its own
            or None for ``line_colour``; empty: every marking in ``line_colour``. Only the
            top-view renderer reads it (training paint, ``topview_samples.vary_paint``).
    """

    preset: str
    seed: int
    slots: tuple[Slot, ...]
    tags: tuple[Tag, ...]
    markings: tuple[Marking, ...]
    marking_points: tuple[MarkingPoint, ...]
    slot_paint: tuple[SlotPaint, ...]
    pillars: tuple[Pillar, ...]
    walls: tuple[Wall, ...]
    parked_cars: tuple[ParkedCar, ...]
    aisles: tuple[Aisle, ...]
    bounds: tuple[float, float, float, float]
    line_colour: tuple[int, int, int]
    marking_colours: tuple[tuple[int, int, int] | None, ...] = ()

    def to_map(self) -> SemanticMap:
        """The true map in the map format (for world.json and evaluation)."""
        return SemanticMap(
            slots=self.slots,
            tags=self.tags,
            markings=self.markings,
            metadata={"generator": "semslam.simulation", "preset": self.preset, "seed": self.seed},
        )
