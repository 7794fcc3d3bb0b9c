"""Random labelled top views for training and testing the perception CNNs.

A sample is a rendered ps2.0-style top view with its :class:`TopviewAnnotation`, taken at
a random pose in a random world: world preset and seed, a point on an aisle (anywhere
across its width, heading along it either way with a few degrees of jitter, or turning
at a junction; or, for a share of the views, parking into a free slot), and a per-frame
render seed (lighting, camera gains, noise, JPEG).
Held-out sets use disjoint world seeds, so a model is never scored on a garage it saw.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from semslam.simulation.render_topview import TopviewAnnotation, TopviewRenderer
from semslam.simulation.world import make_world
from semslam.simulation.world_types import World
from semslam.types import JunctionShape, Marking, SlotKind


@dataclass(frozen=True, eq=False)
class TopviewSample:
    """One labelled top view: BGR uint8 image (600 x 600), its labels, and where it came
    from (world preset and seed, vehicle pose ``mTv`` in the map frame, render seed)."""

    image: np.ndarray
    annotation: TopviewAnnotation
    preset: str
    world_seed: int
    mTv: np.ndarray
    render_seed: int


@dataclass(frozen=True)
class PaintVariation:
    """Paint the simulator's garages do not have, for training data only: real garages
    paint thinner lines and some draw a slot's separators as short stubs at the entrance
    (ps2.0). Per world, with probability ``thin_share`` every line gets a width drawn from
    ``thin_width`` (m), and independently with probability ``stub_share`` every separator
    is cut to a length drawn from ``stub_length`` (m) from its junction. With probability
    ``cross_share`` every T junction's separator is painted on across the entrance line,
    ``cross_length`` (m) into the aisle (a "+" or, on slanted rows, an "X": many of the real
    ps2.0 garages paint their junctions so). With probability ``faint_share`` the paint is
    worn faint: its colour pulled towards mid grey (128) by a share drawn from ``faint_mix``.
    Independently for each separator, with probability ``worn_share`` its first metres from
    the junction, a length drawn from ``worn_length``, are worn away where cars drive over
    them (the entrance line stays: the junction shows as a bare entrance line). With
    probability ``dash_share`` every line that is not a separator (the entrance lines) is
    painted only as a dash across each junction on it, a length drawn from ``dash_length``
    (m) per world, its middle up to ``dash_shift`` (m) off the junction; between the dashes,
    with probability ``gap_share`` per world, the line is painted in ``gap_colour`` (BGR,
    yellow) pulled towards mid grey by a share drawn from ``gap_faint``, else left bare (some
    ps2.0 lots paint white dashes at the junctions joined by a faint yellow line). The
    junctions, and so the labels, stay where they are."""

    thin_share: float = 0.5
    thin_width: tuple[float, float] = (0.05, 0.10)
    stub_share: float = 0.3
    stub_length: tuple[float, float] = (0.3, 0.8)
    cross_share: float = 0.0
    cross_length: tuple[float, float] = (0.1, 0.4)
    faint_share: float = 0.0
    faint_mix: tuple[float, float] = (0.3, 0.7)
    worn_share: float = 0.0
    worn_length: tuple[float, float] = (0.5, 2.0)
    dash_share: float = 0.0
    dash_length: tuple[float, float] = (0.5, 1.6)
    dash_shift: float = 0.2
    gap_share: float = 0.7
    gap_colour: tuple[int, int, int] = (40, 200, 230)
    gap_faint: tuple[float, float] = (0.4, 0.85)


def vary_paint(world: World, variation: PaintVariation, rng: np.random.Generator) -> World:
    """``world`` with its line markings varied as ``variation`` says (see there)."""
    width = rng.uniform(*variation.thin_width) if rng.random() < variation.thin_share else None
    stub = rng.uniform(*variation.stub_length) if rng.random() < variation.stub_share else None
    cross = None  # no draw when crosses are off: the older variations' worlds stay as they were
    if variation.cross_share > 0 and rng.random() < variation.cross_share:
        cross = rng.uniform(*variation.cross_length)
    if variation.faint_share > 0 and rng.random() < variation.faint_share:  # likewise
        faint = rng.uniform(*variation.faint_mix)
        colour = tuple(int(round(c + (128.0 - c) * faint)) for c in world.line_colour)
        world = replace(world, line_colour=colour)
    worn = variation.worn_share > 0
    dash = gap = None  # likewise no draw when dashes are off
    if variation.dash_share > 0 and rng.random() < variation.dash_share:
        dash = rng.uniform(*variation.dash_length)
        if rng.random() < variation.gap_share:
            mix = rng.uniform(*variation.gap_faint)
            gap = tuple(int(round(c + (128.0 - c) * mix)) for c in variation.gap_colour)
    if width is None and stub is None and cross is None and not worn and dash is None:
        return world
    starts = [(np.asarray(p.position, float), p.direction, p.shape is JunctionShape.T)
              for p in world.marking_points]
    junctions = [q for q, _, _ in starts]
    out: list[Marking] = []
    colours: list[tuple[int, int, int] | None] = []
    for m in world.markings:
        a, b = np.asarray(m.a, float), np.asarray(m.b, float)
        d = b - a
        length = float(np.hypot(*d))
        heading = math.atan2(d[1], d[0])
        junction = next((is_t for q, t, is_t in starts if np.hypot(*(a - q)) < 1e-6
                         and abs(math.remainder(heading - t, math.tau)) < 1e-6), None)
        separator = junction is not None  # from a junction along its direction
        if dash is not None and not separator:
            w = m.width if width is None else width
            for (p, q), white in _dashed(a, b, junctions, dash, variation.dash_shift, rng):
                if white or gap is not None:
                    out.append(Marking(p, q, w))
                    colours.append(None if white else gap)
            continue
        if stub is not None and separator and length > stub:
            b = a + d * (stub / length)
        if cross is not None and junction:
            a = a - d * (cross / length)
        if worn and separator and rng.random() < variation.worn_share:
            left = float(np.hypot(*(b - a)))
            gone = rng.uniform(*variation.worn_length)
            if gone >= left:
                continue  # worn away whole
            a = a + (b - a) * (gone / left)
        out.append(Marking(a, b, m.width if width is None else width))
        colours.append(None)
    if all(c is None for c in colours):
        return replace(world, markings=tuple(out))
    return replace(world, markings=tuple(out), marking_colours=tuple(colours))


_Piece = tuple[tuple[np.ndarray, np.ndarray], bool]


def _dashed(a: np.ndarray, b: np.ndarray, junctions: list[np.ndarray], length: float,
            shift: float, rng: np.random.Generator) -> list[_Piece]:
    """The line ``a``-``b`` (m) cut into pieces: a dash ``length`` long across each of
    ``junctions`` lying on it (within 5 cm), its middle shifted along the line by up to
    ``shift``, flagged True; the pieces between them flagged False. Pieces in order from
    ``a``; the whole line as one False piece when no junction lies on it."""
    d = b - a
    n = float(np.hypot(*d))
    if n < 1e-9:
        return [((a, b), False)]
    u = d / n
    spans = []
    for q in junctions:
        r = q - a
        s = float(r @ u)
        if abs(float(r[0] * u[1] - r[1] * u[0])) < 0.05 and -0.05 <= s <= n + 0.05:
            mid = s + rng.uniform(-shift, shift)
            spans.append((max(mid - length / 2, 0.0), min(mid + length / 2, n)))
    spans.sort()
    pieces: list[_Piece] = []
    at = 0.0
    for lo, hi in spans:
        lo = max(lo, at)
        if hi <= lo:
            continue
        if lo > at:
            pieces.append(((a + u * at, a + u * lo), False))
        pieces.append(((a + u * lo, a + u * hi), True))
        at = hi
    if at < n:
        pieces.append(((a + u * at, b), False))
    return pieces


def random_aisle_pose(world, rng: np.random.Generator) -> np.ndarray:
    """A vehicle pose ``(x, y, yaw)`` on a random aisle of ``world``: uniform along it,
    anywhere across its width less 1 m, heading along it (either way) +-15 deg, or in
    one case out of six turned by up to 90 deg (a car turning at a junction)."""
    aisle = world.aisles[int(rng.integers(len(world.aisles)))]
    a, b = np.asarray(aisle.a, float), np.asarray(aisle.b, float)
    d = b - a
    length = float(np.hypot(*d))
    u = d / length
    n = np.array([-u[1], u[0]])
    half = max(aisle.width / 2.0 - 1.0, 0.0)
    p = a + u * rng.uniform(0.0, length) + n * rng.uniform(-half, half)
    yaw = math.atan2(u[1], u[0]) + (math.pi if rng.random() < 0.5 else 0.0)
    if rng.random() < 1.0 / 6.0:
        yaw += rng.uniform(-math.pi / 2, math.pi / 2)
    else:
        yaw += math.radians(rng.uniform(-15.0, 15.0))
    return np.array([p[0], p[1], math.atan2(math.sin(yaw), math.cos(yaw))])


def random_slot_pose(world, rng: np.random.Generator) -> np.ndarray | None:
    """A vehicle pose ``(x, y, yaw)`` parking into a random free perpendicular or slanted
    slot of ``world``: heading along the slot's depth, nose in or reversing in, +-8 deg, up
    to 0.3 m off its middle, its centre from 1.5 m before the entrance line to 2 m short of
    the rear (the car straddles the entrance line, as in ps2.0's views, recorded while
    parking). A slot is free when no parked car's centre lies within its bounding box (which
    may pass over a free slanted slot, never takes an occupied one). None when the world has
    no free slot."""
    cars = np.array([c.centre for c in world.parked_cars]).reshape(-1, 2)
    free = []
    for slot in world.slots:
        if slot.kind == SlotKind.PARALLEL:
            continue
        c = np.asarray(slot.corners, float)
        lo, hi = c.min(axis=0), c.max(axis=0)
        if not ((cars >= lo) & (cars <= hi)).all(axis=1).any():
            free.append(c)
    if not free:
        return None
    c = free[int(rng.integers(len(free)))]
    entrance = 0.5 * (c[0] + c[1])
    depth_vec = 0.5 * (c[2] + c[3]) - entrance
    depth = float(np.hypot(*depth_vec))
    u = depth_vec / depth
    n = np.array([-u[1], u[0]])
    along = rng.uniform(-1.5, max(depth - 2.0, -1.0))
    p = entrance + u * along + n * rng.uniform(-0.3, 0.3)
    yaw = math.atan2(u[1], u[0]) + (math.pi if rng.random() < 0.5 else 0.0)
    yaw += math.radians(rng.uniform(-8.0, 8.0))
    return np.array([p[0], p[1], math.atan2(math.sin(yaw), math.cos(yaw))])


def sample_topviews(
    world_seeds: list[int] | range,
    per_world: int,
    seed: int,
    presets: tuple[str, ...] = ("garage", "small"),
    paint: PaintVariation | None = None,
    slot_share: float = 0.0,
) -> Iterator[TopviewSample]:
    """``per_world`` random top views from each world seed (preset drawn per world), the
    worlds' paint varied by ``paint`` (training data; its draws do not move the poses);
    a share ``slot_share`` of the views taken parking into a slot (:func:`random_slot_pose`),
    the rest on an aisle (:func:`random_aisle_pose`).

    Deterministic in (world_seeds, per_world, seed, presets, paint, slot_share); with
    ``slot_share`` 0 the same views as before it existed.
    """
    rng = np.random.default_rng(seed)
    for ws in world_seeds:
        preset = presets[int(rng.integers(len(presets)))]
        world = make_world(preset, int(ws))
        if paint is not None:
            world = vary_paint(world, paint, np.random.default_rng([seed, int(ws), 7]))
        renderer = TopviewRenderer(world)
        for _ in range(per_world):
            mTv = None
            if slot_share > 0 and rng.random() < slot_share:
                mTv = random_slot_pose(world, rng)
            if mTv is None:
                mTv = random_aisle_pose(world, rng)
            rseed = int(rng.integers(2**31 - 1))
            image, annotation = renderer.render(mTv, rseed)
            yield TopviewSample(image, annotation, preset, int(ws), mTv, rseed)


__all__ = [
    "PaintVariation",
    "TopviewSample",
    "random_aisle_pose",
    "random_slot_pose",
    "sample_topviews",
    "vary_paint",
]
