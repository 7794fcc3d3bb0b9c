"""Random labelled top views for training and testing the perception CNNs.

A sample is a rendered ps2.0-style top view with its :class:`TopviewAnnotation`, taken at
a random pose in a random world: world preset and seed, a point on an aisle (anywhere
across its width, heading along it either way with a few degrees of jitter, or turning
at a junction), and a per-frame render seed (lighting, camera gains, noise, JPEG).
Held-out sets use disjoint world seeds, so a model is never scored on a garage it saw.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from semslam.simulation.render_topview import TopviewAnnotation, TopviewRenderer
from semslam.simulation.world import make_world


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


def sample_topviews(
    world_seeds: list[int] | range,
    per_world: int,
    seed: int,
    presets: tuple[str, ...] = ("garage", "small"),
) -> Iterator[TopviewSample]:
    """``per_world`` random top views from each world seed (preset drawn per world).

    Deterministic in (world_seeds, per_world, seed, presets).
    """
    rng = np.random.default_rng(seed)
    for ws in world_seeds:
        preset = presets[int(rng.integers(len(presets)))]
        world = make_world(preset, int(ws))
        renderer = TopviewRenderer(world)
        for _ in range(per_world):
            mTv = random_aisle_pose(world, rng)
            rseed = int(rng.integers(2**31 - 1))
            image, annotation = renderer.render(mTv, rseed)
            yield TopviewSample(image, annotation, preset, int(ws), mTv, rseed)


__all__ = ["TopviewSample", "random_aisle_pose", "sample_topviews"]
