"""Routes through a world's aisles: lane polylines with rounded corners.

A route keeps to the right of each aisle's centre line (``lane_offset``),
turns at cross aisles with circular fillets, visits every aisle in a
serpentine and then comes back over the first aisles again, so a drive
closes loops. ``drive_index`` picks another route through the same world:
other start corner and direction, other lane jitter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semslam.geometry import FloatArray
from semslam.simulation.world_types import World


@dataclass(frozen=True, eq=False)
class Path:
    """A densely sampled route: points (N, 2), arc length (N,), signed curvature (N,) 1/m."""

    points: FloatArray
    s: FloatArray
    curvature: FloatArray

    @property
    def length(self) -> float:
        return float(self.s[-1])


def _right_offset_polyline(nodes: FloatArray, offset: FloatArray) -> FloatArray:
    """Shift every segment of ``nodes`` (N, 2) to its right by ``offset[i]`` and intersect
    consecutive shifted segments to get the lane's corner points."""
    d = np.diff(nodes, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    right = np.stack([d[:, 1], -d[:, 0]], axis=1)
    a = nodes[:-1] + right * offset[:, None]
    out = [a[0]]
    for i in range(1, len(d)):
        # intersect line (a[i-1], d[i-1]) with line (a[i], d[i])
        A = np.stack([d[i - 1], -d[i]], axis=1)
        if abs(np.linalg.det(A)) < 1e-9:
            out.append(a[i])
            continue
        t = np.linalg.solve(A, a[i] - a[i - 1])
        out.append(a[i - 1] + d[i - 1] * t[0])
    out.append(nodes[-1] + right[-1] * offset[-1])
    return np.array(out)


def fillet_path(corners: FloatArray, radius: float, step: float = 0.05) -> Path:
    """Sample a polyline with each corner replaced by a tangent circular arc."""
    pts: list[FloatArray] = [corners[0]]
    curv: list[float] = [0.0]

    def line_to(p: FloatArray) -> None:
        q = pts[-1]
        n = max(1, int(np.ceil(np.linalg.norm(p - q) / step)))
        for k in range(1, n + 1):
            pts.append(q + (p - q) * k / n)
            curv.append(0.0)

    for i in range(1, len(corners) - 1):
        p_in, p, p_out = corners[i - 1], corners[i], corners[i + 1]
        d1 = (p - p_in) / np.linalg.norm(p - p_in)
        d2 = (p_out - p) / np.linalg.norm(p_out - p)
        turn = math.atan2(d1[0] * d2[1] - d1[1] * d2[0], float(np.dot(d1, d2)))
        if abs(turn) < 1e-6:
            line_to(p)
            continue
        r = radius
        tangent = r * math.tan(abs(turn) / 2.0)
        limit = 0.49 * min(np.linalg.norm(p - p_in), np.linalg.norm(p_out - p))
        if tangent > limit:
            tangent = limit
            r = tangent / math.tan(abs(turn) / 2.0)
        start = p - d1 * tangent
        line_to(start)
        sign = 1.0 if turn > 0 else -1.0
        normal = np.array([-d1[1], d1[0]]) * sign
        centre = start + normal * r
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        n = max(2, int(np.ceil(r * abs(turn) / step)))
        for k in range(1, n + 1):
            a = a0 + sign * abs(turn) * k / n
            pts.append(centre + r * np.array([math.cos(a), math.sin(a)]))
            curv.append(sign / r)
    line_to(corners[-1])
    points = np.array(pts)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(s) > 1e-9])
    return Path(points[keep], s[keep], np.array(curv)[keep])


def route_nodes(world: World, drive_index: int) -> tuple[FloatArray, bool]:
    """Aisle-centre-line nodes of the route and whether lanes are offset (False for the
    hand-made turnaround loops of a single-aisle world, which are already lane-level)."""
    rng = np.random.default_rng([world.seed, drive_index, 7])
    row_aisles = [a for a in world.aisles if abs(a.a[1] - a.b[1]) < 1e-9]
    west, east = float(row_aisles[0].a[0]), float(row_aisles[0].b[0])
    ys = [float(a.a[1]) for a in row_aisles]  # aisle 0 at the top
    mirror_x = drive_index % 2 == 1
    mirror_y = (drive_index // 2) % 2 == 1 or (drive_index > 3 and rng.random() < 0.5)
    if mirror_y:
        ys = ys[::-1]
    if len(ys) == 1:
        return _single_aisle_loop(world, ys[0], west, east, mirror_x), False
    x_start, x_end = (east, west) if mirror_x else (west, east)
    inner = 8.0 if not mirror_x else -8.0
    nodes = [(x_start + inner, ys[0])]
    here = x_start
    for k, y in enumerate(ys):
        if k > 0:
            nodes.append((here, y))
        there = x_end if here == x_start else x_start
        nodes.append((there, y))
        here = there
    # come back up the cross aisle we are at and drive the first aisles again (loops)
    nodes.append((here, ys[0]))
    there = x_end if here == x_start else x_start
    nodes.append((there, ys[0]))
    nodes.append((there, ys[1]))
    nodes.append(((west + east) / 2.0, ys[1]))
    return np.array(nodes), True


def _single_aisle_loop(world: World, y: float, west: float, east: float, mirror: bool):
    """Lane-level nodes for a one-aisle world: down, turn around, back, turn, half again."""
    xmin, _, xmax, _ = world.bounds
    lane = 1.5
    row_west, row_east = xmin + (west - xmin) * 0.0 + 16.0, xmax - 16.0

    def turnaround(x_edge: float, direction: float) -> list[tuple[float, float]]:
        # a lollipop loop in the free area beyond the rows (direction +1 east end, -1 west)
        d = direction
        return [
            (x_edge + d * 1.0, y - d * lane),
            (x_edge + d * 8.0, y - d * 4.5),
            (x_edge + d * 12.5, y),
            (x_edge + d * 8.0, y + d * 4.5),
            (x_edge + d * 1.0, y + d * lane),
        ]

    nodes = [(row_west + 2.0, y - lane)]
    nodes += turnaround(row_east, +1.0)
    nodes += turnaround(row_west, -1.0)
    nodes.append(((row_west + row_east) / 2.0, y - lane))
    pts = np.array(nodes)
    if mirror:
        pts[:, 0] = (row_west + row_east) - pts[:, 0]
        pts[:, 1] = 2 * y - pts[:, 1]
    return pts


def make_path(world: World, drive_index: int, lane_offset: float, turn_radius: float) -> Path:
    """The sampled route of drive ``drive_index`` through ``world``."""
    nodes, offset_lanes = route_nodes(world, drive_index)
    if offset_lanes:
        rng = np.random.default_rng([world.seed, drive_index, 11])
        offsets = lane_offset + rng.uniform(-0.3, 0.3, len(nodes) - 1)
        corners = _right_offset_polyline(nodes, offsets)
    else:
        corners = nodes
    return fillet_path(corners, turn_radius)
