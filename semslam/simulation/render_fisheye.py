"""Synthetic surround-view fisheye images of a simulated garage.

Each camera pixel is traced once per camera (the rays depend only on the rig, never on
the pose): unprojected through the equidistant model (:func:`semslam.rig.fisheye_unproject`),
turned into the vehicle frame and intersected with the ground plane ``z = 0``. Rays at or
above the horizon, or meeting the ground farther than ``max_range`` from the camera, see
the dark garage ceiling; rays meeting the ground under the ego car see its body. The
ground itself comes from the top-view renderer's sharp ground image (world-anchored floor
texture, stains and light pools, painted lines, slot numbers, grates) painted on two
vehicle-centred grids (a fine one, 1/80 m per px over +-6 m, and a coarse one, 1/25 m per
px over +-17.6 m, with two area-averaged reductions of it), chosen per camera pixel by
the pixel's footprint on the ground so that far floor does not alias. Tall things
(parked cars, pillars, walls) are drawn on the ground grids as seen from the camera: a
point at height h above ground point q, seen from a camera at height H above ground
point c, lies on the ray to the ground point ``c + (q - c) * H / (H - h)``, so painting
each face band there is exact for that camera (parts above the camera's height are left
out; they would be seen above the horizon).

All levels sit side by side in one atlas, so every camera image is a single
``cv2.remap`` with a precomputed fixed-point table, then a per-camera gain and colour
cast, vignetting and sensor noise. The same (world, mTv, seed, camera) always gives the
same bytes.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from semslam.geometry import FloatArray, clip_segment
from semslam.rig import Camera, CameraModel, TopviewSpec, VehicleSpec, fisheye_unproject
from semslam.simulation.render_topview import (
    _FMAX,
    _LOW,
    _SHIFT,
    TopviewRenderer,
    _area2,
    _fixed,
)
from semslam.simulation.world_types import World

_FINE = TopviewSpec(size_px=960, metres_per_px=1.0 / 80.0)  # +-6 m
_COARSE = TopviewSpec(size_px=880, metres_per_px=1.0 / 25.0)  # +-17.6 m
_REDUCE = 4  # each further level is the coarse grid reduced 4x (area average)
_GAP = 4  # px between atlas blocks (bilinear sampling never mixes two blocks)
_TILE = 8  # side of the uniform ceiling and ego-body tiles, px
_CEILING = (46.0, 44.0, 42.0)
_BODY = (30.0, 30.0, 34.0)
_WALL = (150.0, 152.0, 155.0)  # floor beyond the world's bounds (below the walls)


class _Ground(TopviewRenderer):
    """The top-view renderer's world-anchored ground painter on another grid.

    Only what the sharp ground image needs is built (floor texture, items, low-resolution
    light and stain map); the top-view camera rig is skipped, so two grids of the same
    world draw the same random stream and show the same floor.
    """

    def __init__(self, world: World, spec: TopviewSpec) -> None:  # noqa: D107
        self.world = world
        self.spec = spec
        self.jpeg = False
        rng = np.random.default_rng([world.seed, 9017])
        self._build_floor(rng)
        self._build_items(rng)
        self._build_low_map(rng)
        # the ego car's soft shadow on the low-resolution layer (as the top-view renderer)
        n, s, c = spec.size_px, spec.metres_per_px, spec.centre_px
        L2, W2 = spec.ego_length_m / 2.0, spec.ego_width_m / 2.0
        g = (np.arange(_LOW) + 0.5) * (n / _LOW) - 0.5
        gv, gu = np.meshgrid(g, g, indexing="ij")
        d = np.hypot(
            np.maximum(np.abs(c - gv) * s - L2, 0.0), np.maximum(np.abs(c - gu) * s - W2, 0.0)
        )
        shadow = 1.0 - 0.5 * np.exp(-((d / 0.25) ** 2))
        self._ego_shadow = np.clip(shadow * 255.0, 0, 255).astype(np.uint8)
        xmin, ymin, xmax, ymax = world.bounds
        self._bounds_poly = np.array(
            [[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]], float
        )

    def ground(self, mTv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The sharp ground image at ``mTv`` (no tall things) and its map -> pixel matrix."""
        P = self._world_to_pixel(mTv)
        S = self._floor_img.copy()
        self._draw_grates(S, P, mTv)
        self._draw_markings(S, P, mTv)
        self._draw_labels(S, P, mTv)
        S = self._modulate_floor(S, P)
        n = self.spec.size_px
        inside = np.zeros((n, n), np.uint8)
        cv2.fillConvexPoly(inside, _fixed(self._apply(P, self._bounds_poly)), 255, 8, _SHIFT)
        S[inside == 0] = _WALL
        return S, P

    def draw_solids_from(
        self, S: np.ndarray, P: np.ndarray, mTv: np.ndarray, cam_xy: FloatArray, H: float
    ) -> None:
        """Parked cars, pillars and walls as a camera at ``cam_xy`` (vehicle frame, m),
        ``H`` m above the floor, sees them, drawn far to near onto ``S``."""
        spec = self.spec
        n = spec.size_px
        radius = spec.half_extent_m * math.sqrt(2.0) + 1.0
        cpx = spec.vehicle_to_pixel(cam_xy)[0]
        solids: list[tuple[np.ndarray, list, tuple[float, float, float]]] = []
        for i in self._near(self._car_fp, mTv, radius):
            solids.append((self._apply(P, self._car_fp[i]), self._car_bands[i], (18.0, 18.0, 20.0)))
        for i in self._near(self._pillar_fp, mTv, radius):
            solids.append((self._apply(P, self._pillar_fp[i]), self._pillar_bands, _WALL))
        wall_bands = [
            (0.0, 0.15, (70.0, 75.0, 80.0)),
            (0.15, 0.45, self._wall_stripe),
            (0.45, 5.0, (175.0, 178.0, 180.0)),
        ]
        for w in self.world.walls:
            ends = self._apply(P, np.array([w.a, w.b], float))
            seg = clip_segment(ends[0], ends[1], -30.0, n + 30.0)
            if seg is not None:
                a, b = seg
                d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
                nrm = np.array([-d[1], d[0]]) * (0.1 / spec.metres_per_px)
                solids.append((np.array([a - nrm, b - nrm, b + nrm, a + nrm]), wall_bands, _WALL))
        if not solids:
            return
        dist = [float(np.hypot(*(fp - cpx).T).min()) for fp, _, _ in solids]
        cx, cy = float(cpx[0]), float(cpx[1])
        for j in np.argsort(dist)[::-1]:  # far to near: nearer things cover farther ones
            fp, bands, top = solids[j]
            wedge = np.concatenate([fp, cpx + (fp - cpx) * _FMAX])
            lo, hi = wedge.min(axis=0), wedge.max(axis=0)
            if hi[0] < -2 or hi[1] < -2 or lo[0] > n + 1 or lo[1] > n + 1:
                continue
            stretched = [
                (self._stretch(H, h0), self._stretch(H, h1), colour)
                for h0, h1, colour in bands
                if h0 < H * 0.98
            ]
            cv2.fillConvexPoly(S, _fixed(fp), top, cv2.LINE_AA, _SHIFT)
            area = _area2(fp)
            for e in range(len(fp)):
                p, q = fp[e], fp[(e + 1) % len(fp)]
                if ((q[0] - p[0]) * (cy - p[1]) - (q[1] - p[1]) * (cx - p[0])) * area >= 0:
                    continue  # a face is seen when the camera is on its outer side
                dp, dq = p - cpx, q - cpx
                for f0, f1, colour in stretched:
                    quad = np.array([cpx + dp * f0, cpx + dq * f0, cpx + dq * f1, cpx + dp * f1])
                    cv2.fillConvexPoly(S, _fixed(quad), colour, cv2.LINE_AA, _SHIFT)


@dataclass(frozen=True, eq=False)
class _CameraMaps:
    maps: tuple[np.ndarray, np.ndarray]  # fixed-point remap table into the atlas
    vignette: np.ndarray  # (h, w, 3) uint8, 255 = no loss
    position: FloatArray  # (2,) camera position on the floor, vehicle frame
    height: float


def _camera_key(camera: Camera) -> tuple:
    return (
        camera.name,
        tuple(camera.size),
        np.asarray(camera.K, float).tobytes(),
        np.asarray(camera.D, float).tobytes(),
        np.asarray(camera.T_vehicle_camera, float).tobytes(),
    )


class FisheyeRenderer:
    """Renders the rig's fisheye images of one world; per-world and per-camera tables are
    built once.

    Args:
        world: the garage.
        vehicle: the ego car (its footprint is drawn as the car body).
        max_range: metres; farther floor is shown as the dark ceiling.
    """

    def __init__(
        self, world: World, vehicle: VehicleSpec | None = None, max_range: float = 15.0
    ) -> None:
        self.world = world
        self.vehicle = vehicle or VehicleSpec()
        self.max_range = float(max_range)
        self._levels = (_Ground(world, _FINE), _Ground(world, _COARSE))
        n0, n1 = _FINE.size_px, _COARSE.size_px
        n2 = n1 // _REDUCE
        n3 = n2 // _REDUCE
        x = 0
        self._offsets: list[int] = []
        for side in (n0, n1, n2, n3, _TILE, _TILE):
            self._offsets.append(x)
            x += side + _GAP
        self._level_px = (n0, n1, n2, n3)
        self._mpp = (
            _FINE.metres_per_px,
            _COARSE.metres_per_px,
            _COARSE.metres_per_px * n1 / n2,
            _COARSE.metres_per_px * n1 / n3,
        )
        self._atlas_shape = (max(n0, n1), x)
        self._cameras: dict[tuple, _CameraMaps] = {}
        nrng = np.random.default_rng(24680)  # sensor-noise bank, uint8 around 128
        self._noise_bank = np.clip(nrng.normal(128.0, 20.0, (1024, 1408, 3)), 0, 255).astype(
            np.uint8
        )

    # ------------------------------------------------------------------ per camera

    def _tables(self, camera: Camera) -> _CameraMaps:
        key = _camera_key(camera)
        tab = self._cameras.get(key)
        if tab is None:
            if len(self._cameras) >= 16:
                self._cameras.clear()
            tab = self._cameras[key] = self._build_tables(camera)
        return tab

    def _build_tables(self, camera: Camera) -> _CameraMaps:
        if camera.model is not CameraModel.FISHEYE:
            raise ValueError(f"camera '{camera.name}' is not a fisheye camera")
        w, h = camera.size
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
        rays = fisheye_unproject(camera, np.stack([uu.ravel(), vv.ravel()], axis=1))
        T = np.asarray(camera.T_vehicle_camera, float)
        R = T[:3, :3]  # broadcast, not matmul: a BLAS call per table is slow when shared
        d = (rays[:, :1] * R[:, 0] + rays[:, 1:2] * R[:, 1] + rays[:, 2:] * R[:, 2]).reshape(
            h, w, 3
        )
        o = T[:3, 3]
        down = d[..., 2] < -1e-6
        t = np.where(down, -o[2] / np.where(down, d[..., 2], -1.0), np.nan)
        g = o[:2] + t[..., None] * d[..., :2]  # (h, w, 2) ground point, vehicle frame
        rng_m = np.hypot(g[..., 0] - o[0], g[..., 1] - o[1])
        floor = down & (rng_m <= self.max_range)
        body = (
            floor
            & (np.abs(g[..., 0]) <= self.vehicle.length / 2.0)
            & (np.abs(g[..., 1]) <= self.vehicle.width / 2.0)
        )
        g = np.where(floor[..., None], g, 0.0)
        # ground footprint of each pixel: geometric mean of its two edges
        gu = np.hypot(*np.moveaxis(np.gradient(g, axis=1), -1, 0))
        gv = np.hypot(*np.moveaxis(np.gradient(g, axis=0), -1, 0))
        fp = np.sqrt(gu * gv)
        half0 = _FINE.half_extent_m - 0.1
        in0 = (np.abs(g[..., 0]) < half0) & (np.abs(g[..., 1]) < half0)
        level = np.full((h, w), 3, np.int8)
        for k in (2, 1, 0):
            ok = fp <= 2.0 * self._mpp[k]
            if k == 0:
                ok &= in0
            level[ok] = k
        # reduced levels: pixel centres at (i + 0.5) * r - 0.5 of the coarse grid, so every
        # level maps as the ps2.0 grid does, with its own centre, scale and atlas offset
        sides = np.array(self._level_px, float)
        off = np.array(self._offsets[:4], float)[level]
        mpp = np.array(self._mpp)[level]
        c = (sides[level] - 1.0) / 2.0
        mx = (off + c - g[..., 1] / mpp).astype(np.float32)
        my = (c - g[..., 0] / mpp).astype(np.float32)
        tile_c = (_TILE - 1) / 2.0
        mx[~floor], my[~floor] = self._offsets[4] + tile_c, tile_c
        mx[body], my[body] = self._offsets[5] + tile_c, tile_c
        maps = cv2.convertMaps(mx, my, cv2.CV_16SC2)
        # vignetting: falls with the angle from the optical axis
        theta = np.arccos(np.clip(rays[:, 2], -1.0, 1.0)).reshape(h, w)
        vig = 1.0 - 0.45 * (theta / (math.pi / 2)) ** 3
        vignette = cv2.cvtColor(np.clip(vig * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        return _CameraMaps(maps, vignette, o[:2].copy(), float(o[2]))

    # ------------------------------------------------------------------ per frame

    def render(
        self, mTv: np.ndarray, seed: int, cameras: Iterable[Camera], solids: bool = True
    ) -> dict[str, np.ndarray]:
        """BGR uint8 images of ``cameras`` (fisheye) at vehicle pose ``mTv`` (x, y, yaw in
        the map frame), by camera name; ``seed`` picks the per-frame variation (gains,
        noise); ``solids=False`` leaves parked cars, pillars and walls out."""
        mTv = np.asarray(mTv, dtype=float)
        cams = list(cameras)
        tables = [self._tables(c) for c in cams]
        grounds = [lvl.ground(mTv) for lvl in self._levels]
        frng = np.random.default_rng([self.world.seed, int(seed) & 0x7FFFFFFF, 4711])
        temp, glob = float(frng.normal(0.0, 0.03)), float(frng.uniform(0.85, 1.12))
        out: dict[str, np.ndarray] = {}
        for cam, tab in zip(cams, tables, strict=True):
            atlas = np.zeros((*self._atlas_shape, 3), np.uint8)
            coarse = None
            for k, (lvl, (S, P)) in enumerate(zip(self._levels, grounds, strict=True)):
                if solids:
                    S = S.copy()
                    lvl.draw_solids_from(S, P, mTv, tab.position, tab.height)
                atlas[: S.shape[0], self._offsets[k] : self._offsets[k] + S.shape[1]] = S
                coarse = S
            assert coarse is not None
            for k in (2, 3):
                n = self._level_px[k]
                coarse = cv2.resize(coarse, (n, n), interpolation=cv2.INTER_AREA)
                atlas[:n, self._offsets[k] : self._offsets[k] + n] = coarse
            atlas[:_TILE, self._offsets[4] : self._offsets[4] + _TILE] = _CEILING
            atlas[:_TILE, self._offsets[5] : self._offsets[5] + _TILE] = _BODY
            img = cv2.remap(atlas, tab.maps[0], tab.maps[1], cv2.INTER_LINEAR)
            rng = np.random.default_rng(
                [self.world.seed, int(seed) & 0x7FFFFFFF, 4712, zlib.crc32(cam.name.encode())]
            )
            g = (
                glob
                * (1.0 + rng.normal(0.0, 0.05))
                * (1.0 + np.array([temp, 0.0, -temp]) + rng.normal(0.0, 0.015, 3))
            )
            img = cv2.multiply(img, (float(g[0]), float(g[1]), float(g[2]), 0.0))  # type: ignore[call-overload]
            img = cv2.multiply(img, tab.vignette, scale=1.0 / 255.0)
            h, w = img.shape[:2]
            nr, nc = self._noise_bank.shape[:2]
            if h <= nr and w <= nc:
                oy, ox = int(rng.integers(0, nr - h + 1)), int(rng.integers(0, nc - w + 1))
                noise = self._noise_bank[oy : oy + h, ox : ox + w]
            else:
                noise = np.clip(rng.normal(128.0, 20.0, (h, w, 3)), 0, 255).astype(np.uint8)
            ns = float(rng.uniform(0.04, 0.12))
            img = cv2.addWeighted(img, 1.0, noise, ns, -128.0 * ns)
            out[cam.name] = img
        return out


_CACHE: dict[int, FisheyeRenderer] = {}


def _renderer(world: World) -> FisheyeRenderer:
    r = _CACHE.get(id(world))
    if r is None or r.world is not world:
        if len(_CACHE) >= 4:
            _CACHE.clear()
        r = _CACHE[id(world)] = FisheyeRenderer(world)
    return r


def render_fisheye(
    world: World, mTv: np.ndarray, seed: int, camera: Camera, solids: bool = True
) -> np.ndarray:
    """The BGR uint8 image of one fisheye ``camera`` at vehicle pose ``mTv`` (map frame).

    A thin wrapper over :class:`FisheyeRenderer` that keeps a few renderers (by world);
    to render several cameras of one frame, :func:`render_fisheye_rig` shares the ground.
    """
    return _renderer(world).render(mTv, seed, [camera], solids)[camera.name]


def render_fisheye_rig(
    world: World, mTv: np.ndarray, seed: int, cameras: Iterable[Camera], solids: bool = True
) -> dict[str, np.ndarray]:
    """The BGR uint8 images of several fisheye cameras of one frame, by camera name."""
    return _renderer(world).render(mTv, seed, cameras, solids)


__all__ = ["FisheyeRenderer", "render_fisheye", "render_fisheye_rig"]
