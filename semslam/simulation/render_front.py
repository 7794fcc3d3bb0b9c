"""The simulated front (dashcam) camera: a seeded, fast rasteriser of the garage world.

What it draws, back to front:

- the ceiling (rows above the horizon): concrete texture x a light map with bright
  patches around the fixtures, falling off with distance;
- the floor: a tiled concrete texture and a per-world light map (pools under the
  light fixtures, soft dark patches under parked cars and pillars, worn tyre tracks),
  both warped into the image with the ground-to-image homography
  (``cv2.warpPerspective``), the painted line markings as exact projected polygons,
  then distance fog;
- the walls (always behind everything else: the garage is convex);
- light fixtures, ceiling beams over the pillar lines, a pipe along each aisle,
  pillars (with the tags hung on them) and parked cars (wheels, body with lamps,
  cabin with glass), sorted far to near (painter's algorithm), back faces culled,
  every polygon clipped against the near plane before projection;
- tags: real AprilTag codes (``cv2.aruco``) with a white quiet border of one cell,
  warped from their four exactly projected corners (the source image is never finer
  than the destination, so edges land at their exact sub-pixel place): a detector
  plus PnP recovers the true tag pose. They are upright as the AprilTag library
  defines it (first corner bottom-left). Mind that the AprilTag library reports
  pixel coordinates with pixel centres at +0.5, OpenCV (and ``Camera.K``) at 0;
- camera effects drawn from ``seed``: exposure, a light blur, vignetting, sensor noise.

Only objects within ``max_range`` metres are drawn; far ones fade into the haze anyway.
The same inputs give the same bytes. Everything per world is built once in
:class:`FrontRenderer`'s constructor; the concrete texture once per process.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from semslam.errors import SimulationError
from semslam.geometry import FloatArray
from semslam.rig import Camera, CameraModel
from semslam.simulation.world_types import World
from semslam.types import Tag, TagFamily

NEAR = 0.1  # near clipping plane, metres along the optical axis
CEILING_Z = 3.0
LIGHT_Z = 2.8
SUBPIXEL_SHIFT = 4  # fixed-point bits for cv2 polygon vertices
_SUB = float(1 << SUBPIXEL_SHIFT)

TEXTURE_PX = 2048  # concrete tile side, pixels
TEXTURE_M_PER_PX = 0.01  # -> a 20.48 m tile
LIGHTMAP_M_PER_PX = 0.1

HAZE = np.array([22.0, 22.0, 24.0])  # BGR far objects fade into
FOG_DISTANCE = 38.0  # e-folding distance of the brightness, metres
FOG_FLOOR = 0.18  # brightness never drops below this share

TAG_WHITE = 205.0
TAG_BLACK = 22.0
_TAG_MIP_CELLS = (1, 2, 4, 8, 16, 32)  # source pixels per tag cell

_ARUCO_DICTS = {TagFamily.TAG36H11: "DICT_APRILTAG_36h11",
                TagFamily.TAG25H9: "DICT_APRILTAG_25h9",
                TagFamily.TAG16H5: "DICT_APRILTAG_16h5"}
_TAG_BITS = {TagFamily.TAG36H11: 6, TagFamily.TAG25H9: 5, TagFamily.TAG16H5: 4}

# fixed "key light" for face shading (map frame, pointing from the light to the scene)
_KEY = np.array([0.45, 0.75, 0.0])
_KEY /= np.linalg.norm(_KEY)


def _fog(d: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """Brightness share left after distance ``d`` (m)."""
    return FOG_FLOOR + (1.0 - FOG_FLOOR) * np.exp(-np.asarray(d, dtype=float) / FOG_DISTANCE)


# --------------------------------------------------------------------------- textures


def _periodic_noise(rng: np.random.Generator, n: int) -> FloatArray:
    """Tileable n x n noise: metre-scale stains plus decimetre-scale mottling (power
    spectra ~ 1/f^2.6 and 1/f^1.6 at 1 cm per pixel), unit standard deviation."""
    white = rng.standard_normal((n, n), dtype=np.float32)
    fy = np.fft.fftfreq(n)[:, None] * n
    fx = np.fft.rfftfreq(n)[None, :] * n
    f = np.maximum(np.sqrt(fx * fx + fy * fy), 1.0)
    stains = np.where(f < 2.0, 0.0, f ** -1.3)
    mottle = np.where(f < 20.0, 0.0, f ** -0.8)
    amp = stains / np.sqrt((stains**2).mean()) + 0.55 * mottle / np.sqrt((mottle**2).mean())
    out = np.fft.irfft2(np.fft.rfft2(white) * amp, s=(n, n))
    return (out - out.mean()) / (out.std() + 1e-12)


@functools.lru_cache(maxsize=1)
def _concrete_texture() -> NDArray[np.uint8]:
    """A tileable grey concrete texture (TEXTURE_PX square, 1 cm per pixel)."""
    rng = np.random.default_rng(12345)
    n = TEXTURE_PX
    tex = 112.0 + 10.0 * _periodic_noise(rng, n) + 4.0 * rng.standard_normal((n, n))
    # a few darker oil stains (wrapping around the tile edges)
    for _ in range(14):
        cx, cy = rng.uniform(0, n, 2)
        rx, ry = rng.uniform(15, 60, 2)
        depth = rng.uniform(6, 16)
        ys = np.arange(int(cy - 3 * ry), int(cy + 3 * ry) + 1)
        xs = np.arange(int(cx - 3 * rx), int(cx + 3 * rx) + 1)
        blob = np.exp(-(((ys[:, None] - cy) / ry) ** 2 + ((xs[None, :] - cx) / rx) ** 2))
        tex[np.ix_(ys % n, xs % n)] -= depth * blob
    # slab joints every 5.12 m (tile / 4): thin dark lines
    for k in range(4):
        p = k * n // 4
        tex[:, p : p + 1] -= 18.0
        tex[p : p + 1, :] -= 18.0
    return np.clip(tex, 0, 255).astype(np.uint8)


@functools.cache
def _upright_turns(family: TagFamily) -> int:
    """Quarter turns (``np.rot90``) that make ``cv2.aruco``'s code image upright as the
    AprilTag library reads it (its first corner bottom-left). OpenCV versions disagree
    with the AprilTag images on this, so ask pupil-apriltags once; without it assume
    the half turn measured with OpenCV 5.0."""
    try:
        from semslam.perception.apriltag_detector import shared_detector

        detector = shared_detector(str(family))
    except ImportError:  # pragma: no cover - pupil-apriltags is a dependency
        return 2
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, _ARUCO_DICTS[family]))
    side = (_TAG_BITS[family] + 2) * 20
    code = cv2.aruco.generateImageMarker(dictionary, 0, side)
    for turns in range(4):
        canvas = np.full((3 * side, 3 * side), 255, np.uint8)
        canvas[side : 2 * side, side : 2 * side] = np.rot90(code, turns)
        found = [d for d in detector.detect(canvas) if d.tag_id == 0]
        if found and found[0].corners[0][0] < 1.5 * side and found[0].corners[0][1] > 1.5 * side:
            return turns
    return 2  # pragma: no cover


@functools.lru_cache(maxsize=1)
def _tiled_texture() -> NDArray[np.uint8]:
    """3 x 3 copies of the concrete tile: warping from it with a constant border is several
    times faster than ``BORDER_WRAP`` on the tile itself."""
    return np.tile(_concrete_texture(), (3, 3))


@functools.lru_cache(maxsize=512)
def _tag_code_image(family: TagFamily, tag_id: int, cell_px: int) -> NDArray[np.uint8]:
    """The printed tag as a BGR image: the code (black square = (bits+2) cells) with a
    white quiet border of one cell; 255 white, 0 black."""
    if family not in _ARUCO_DICTS:
        raise SimulationError(f"cannot render tag family {family}")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, _ARUCO_DICTS[family]))
    cells = _TAG_BITS[family] + 2
    code = cv2.aruco.generateImageMarker(dictionary, int(tag_id), cells * cell_px)
    code = np.ascontiguousarray(np.rot90(code, _upright_turns(family)))
    padded = cv2.copyMakeBorder(code, cell_px, cell_px, cell_px, cell_px,
                                cv2.BORDER_CONSTANT, value=255)
    return np.asarray(cv2.cvtColor(padded, cv2.COLOR_GRAY2BGR), dtype=np.uint8)


# --------------------------------------------------------------------------- geometry


@dataclass
class _Face:
    verts: FloatArray  # (4, 3) map frame, a convex planar quad
    normal: FloatArray  # (3,) outward
    colour: FloatArray  # (3,) BGR before distance fog
    tag: int = -1  # index into the renderer's tags, or -1


def _shade(normal: FloatArray) -> float:
    """Constant per-face shading: tops bright, sides by their angle to the key light."""
    if normal[2] > 0.5:
        return 1.0
    if normal[2] < -0.5:
        return 0.55
    return 0.72 + 0.2 * float(np.dot(normal[:2], -_KEY[:2]))


def _box(foot: FloatArray, z0: float, z1: float, side: ArrayLike, top: ArrayLike | None,
         light: float) -> list[_Face]:
    """Faces of a prism over the CCW footprint ``foot`` (4, 2) from ``z0`` to ``z1``."""
    faces = []
    side_c = np.asarray(side, dtype=float)
    n = len(foot)
    for k in range(n):
        p, q = foot[k], foot[(k + 1) % n]
        d = q - p
        normal = np.array([d[1], -d[0], 0.0]) / (np.hypot(d[0], d[1]) + 1e-12)
        verts = np.array([[p[0], p[1], z0], [q[0], q[1], z0], [q[0], q[1], z1], [p[0], p[1], z1]])
        faces.append(_Face(verts, normal, side_c * _shade(normal) * light))
    if top is not None:
        normal = np.array([0.0, 0.0, 1.0])
        verts = np.column_stack([foot, np.full(n, z1)])
        faces.append(_Face(verts, normal, np.asarray(top, dtype=float) * light))
    return faces


def _frustum(bottom: FloatArray, top_foot: FloatArray, z0: float, z1: float, side: ArrayLike,
             top: ArrayLike, light: float) -> list[_Face]:
    """Faces of a truncated prism: CCW footprints ``bottom`` at ``z0`` and ``top_foot`` at
    ``z1`` (same vertex order), sides then top."""
    faces = []
    side_c = np.asarray(side, dtype=float)
    n = len(bottom)
    for k in range(n):
        j = (k + 1) % n
        verts = np.array([[*bottom[k], z0], [*bottom[j], z0], [*top_foot[j], z1],
                          [*top_foot[k], z1]])
        normal = np.cross(verts[1] - verts[0], verts[3] - verts[0])
        normal /= np.linalg.norm(normal) + 1e-12
        faces.append(_Face(verts, normal, side_c * _shade(normal) * light))
    faces.append(_Face(np.column_stack([top_foot, np.full(n, z1)]), np.array([0.0, 0.0, 1.0]),
                       np.asarray(top, dtype=float) * light))
    return faces


def _rect(centre: FloatArray, yaw: float, length: float, width: float) -> FloatArray:
    """(4, 2) CCW corners of a rectangle."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = length / 2.0, width / 2.0
    local = np.array([[-hl, -hw], [hl, -hw], [hl, hw], [-hl, hw]])
    return local @ np.array([[c, s], [-s, c]]) + centre


def _clip_near(poly: FloatArray, near: float) -> FloatArray:
    """Sutherland-Hodgman clip of a camera-frame polygon (N, 3) to z >= near."""
    out = []
    n = len(poly)
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        pin, qin = p[2] >= near, q[2] >= near
        if pin:
            out.append(p)
        if pin != qin:
            t = (near - p[2]) / (q[2] - p[2])
            out.append(p + t * (q - p))
    return np.array(out) if out else np.zeros((0, 3))


class _FaceSet:
    """Faces grouped into objects, flattened into arrays for vectorised culling."""

    def __init__(self) -> None:
        self._objects: list[tuple[FloatArray, float, bool, list[_Face]]] = []

    def add(self, faces: list[_Face], always: bool = False) -> None:
        if not faces:
            return
        pts = np.concatenate([f.verts for f in faces])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        centre = (lo + hi) / 2.0
        radius = float(np.linalg.norm(hi - lo) / 2.0)
        self._objects.append((centre, radius, always, faces))

    def freeze(self) -> None:
        objs = self._objects
        self.centre = np.array([o[0] for o in objs]).reshape(-1, 3)
        self.radius = np.array([o[1] for o in objs], dtype=float)
        self.always = np.array([o[2] for o in objs], dtype=bool)
        faces = [f for o in objs for f in o[3]]
        self.face_obj = np.array([i for i, o in enumerate(objs) for _ in o[3]], dtype=np.intp)
        self.verts = np.array([f.verts for f in faces]).reshape(-1, 4, 3)
        self.normal = np.array([f.normal for f in faces]).reshape(-1, 3)
        self.colour = np.array([f.colour for f in faces]).reshape(-1, 3)
        self.tag = np.array([f.tag for f in faces], dtype=np.intp)
        self.face_centre = self.verts.mean(axis=1)
        self.face_start = np.searchsorted(self.face_obj, np.arange(len(objs)))
        self.face_stop = np.searchsorted(self.face_obj, np.arange(len(objs)), side="right")


# --------------------------------------------------------------------------- renderer


class FrontRenderer:
    """Renders the front camera's view of ``world`` (see the module docstring).

    Args:
        world: the garage.
        camera: a pinhole camera (distortion ignored), mounted without roll.
        max_range: objects farther than this from the camera (m) are not drawn.
    """

    def __init__(self, world: World, camera: Camera, max_range: float = 35.0) -> None:
        if camera.model is not CameraModel.PINHOLE:
            raise SimulationError("FrontRenderer renders pinhole cameras only")
        self.world = world
        self.camera = camera
        self.max_range = float(max_range)
        self.W, self.H = int(camera.size[0]), int(camera.size[1])
        self.K = np.asarray(camera.K, dtype=float)
        self.T_vc = np.asarray(camera.T_vehicle_camera, dtype=float)
        self._fx, self._fy = self.K[0, 0], self.K[1, 1]
        self._cx, self._cy = self.K[0, 2], self.K[1, 2]
        self._cam_height = float(self.T_vc[2, 3])
        self._tex = _tiled_texture()
        self._build_lightmap()
        self._build_rows()
        self._build_objects()
        self._build_camera_effects()

    # ------------------------------------------------------------------ setup

    def _light_positions(self) -> list[tuple[FloatArray, float]]:
        """Light fixtures (centre (2,), yaw): every ~5 m along every aisle centre line and
        along lines over the parking rows on both sides."""
        out: list[tuple[FloatArray, float]] = []
        taken: set[tuple[int, int]] = set()  # 2.5 m grid cells holding a fixture
        xmin, ymin, xmax, ymax = self.world.bounds
        for aisle in self.world.aisles:
            a, b = np.asarray(aisle.a, float), np.asarray(aisle.b, float)
            length = float(np.linalg.norm(b - a))
            if length < 1e-6:
                continue
            d = (b - a) / length
            side = np.array([-d[1], d[0]])
            yaw = math.atan2(d[1], d[0])
            n = max(1, int(length // 5.0))
            for off in (0.0, aisle.width / 2.0 + 2.6, -aisle.width / 2.0 - 2.6):
                for k in range(n + 1):
                    p = a + d * (length * k / n) + side * off
                    if not (xmin + 1 < p[0] < xmax - 1 and ymin + 1 < p[1] < ymax - 1):
                        continue
                    i, j = int(p[0] // 2.5), int(p[1] // 2.5)
                    near = [(i + di, j + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)]
                    if any(c in taken for c in near):
                        continue
                    taken.add((i, j))
                    out.append((p, yaw))
        return out

    def _build_lightmap(self) -> None:
        """Per-world floor light map (1 px = 10 cm): pools under the fixtures, soft dark
        patches under cars and at pillar feet; 128 = gain 1."""
        xmin, ymin, xmax, ymax = self.world.bounds
        r = LIGHTMAP_M_PER_PX
        w = int(math.ceil((xmax - xmin) / r)) + 1
        h = int(math.ceil((ymax - ymin) / r)) + 1
        light = np.full((h, w), 0.62, np.float32)
        self._lights = self._light_positions()
        blob = cv2.getGaussianKernel(int(8.0 / r) | 1, 2.6 / r)
        blob = (blob @ blob.T).astype(np.float32)
        blob = blob / blob.max()
        bh = blob.shape[0] // 2
        for p, _ in self._lights:
            i, j = int(round((p[0] - xmin) / r)), int(round((p[1] - ymin) / r))
            x0, y0 = max(0, i - bh), max(0, j - bh)
            x1, y1 = min(w, i + bh + 1), min(h, j + bh + 1)
            if x1 > x0 and y1 > y0:
                light[y0:y1, x0:x1] += 0.55 * blob[y0 - (j - bh) : y1 - (j - bh),
                                                   x0 - (i - bh) : x1 - (i - bh)]
        ambient = light.copy()  # what lights things standing on the floor
        ceil = np.full((h, w), 0.75, np.float32)
        small = cv2.getGaussianKernel(int(4.0 / r) | 1, 1.2 / r)
        small = (small @ small.T).astype(np.float32)
        small = small / small.max()
        sh = small.shape[0] // 2
        for p, _ in self._lights:
            i, j = int(round((p[0] - xmin) / r)), int(round((p[1] - ymin) / r))
            x0, y0 = max(0, i - sh), max(0, j - sh)
            x1, y1 = min(w, i + sh + 1), min(h, j + sh + 1)
            if x1 > x0 and y1 > y0:
                ceil[y0:y1, x0:x1] += 0.9 * small[y0 - (j - sh) : y1 - (j - sh),
                                                  x0 - (i - sh) : x1 - (i - sh)]
        self._ceil_lightmap = np.clip(ceil * 128.0, 0, 255).astype(np.uint8)
        occ = np.zeros((h, w), np.float32)
        scale = np.array([1.0 / r, 1.0 / r])
        origin = np.array([xmin, ymin])
        for car in self.world.parked_cars:
            foot = _rect(np.asarray(car.centre), car.yaw, car.length + 0.3, car.width + 0.3)
            cv2.fillConvexPoly(occ, np.round((foot - origin) * scale).astype(np.int32), 1.0)
        for pillar in self.world.pillars:
            foot = _rect(np.asarray(pillar.centre), 0.0, pillar.side + 0.5, pillar.side + 0.5)
            cv2.fillConvexPoly(occ, np.round((foot - origin) * scale).astype(np.int32), 0.7)
        occ = np.asarray(cv2.GaussianBlur(occ, (0, 0), 0.35 / r), dtype=np.float32)
        light *= 1.0 - 0.6 * occ
        # worn tyre tracks: two soft darker bands along every aisle
        wear = np.zeros((h, w), np.float32)
        for aisle in self.world.aisles:
            a, b = np.asarray(aisle.a, float), np.asarray(aisle.b, float)
            d = b - a
            length = float(np.hypot(d[0], d[1]))
            if length < 1e-6:
                continue
            side = np.array([-d[1], d[0]]) / length
            for off in (-0.85, 0.85):
                p0 = np.round((a + side * off - origin) * scale).astype(int)
                p1 = np.round((b + side * off - origin) * scale).astype(int)
                cv2.line(wear, tuple(int(v) for v in p0), tuple(int(v) for v in p1), 1.0,
                         max(1, int(0.35 / r)))
        wear = np.asarray(cv2.GaussianBlur(wear, (0, 0), 0.25 / r), dtype=np.float32)
        light *= 1.0 - 0.12 * wear
        # darker towards the walls
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        dwall = np.minimum.reduce([xx * r, (w - 1 - xx) * r, yy * r, (h - 1 - yy) * r])
        light *= 0.8 + 0.2 * np.clip(dwall / 3.0, 0, 1)
        self._lightmap = np.clip(light * 128.0, 0, 255).astype(np.uint8)
        self._lightmap_A = np.array([[r, 0, xmin], [0, r, ymin], [0, 0, 1.0]])
        # brightness of things standing at a map point
        self._light_at = lambda p: float(
            ambient[int(np.clip(round((p[1] - ymin) / r), 0, h - 1)),
                  int(np.clip(round((p[0] - xmin) / r), 0, w - 1))]
        ) / 0.9

    def _build_rows(self) -> None:
        """Horizon, ceiling block and floor fog rows: for a camera without roll they
        depend on the row only."""
        R_vc = self.T_vc[:3, :3]  # camera axes in the vehicle frame
        up_c = R_vc.T @ np.array([0.0, 0.0, 1.0])  # vehicle up in camera coordinates
        if abs(up_c[0]) > 1e-6:
            raise SimulationError("FrontRenderer needs a camera mounted without roll")
        # ray through row v: d = ((u-cx)/fx, (v-cy)/fy, 1); up component = d . up_c
        v = np.arange(self.H, dtype=float)
        dy = (v - self._cy) / self._fy
        up = dy * up_c[1] + up_c[2]  # vertical component per unit optical depth
        # horizon: up == 0
        v_h = self._cy - up_c[2] / up_c[1] * self._fy
        self._v0 = int(np.clip(math.floor(v_h) - 1, 0, self.H))
        axis_v = R_vc[:, 2] * np.array([1.0, 1.0, 0.0])  # optical axis, level, vehicle frame
        fwd_c = R_vc.T @ (axis_v / (np.linalg.norm(axis_v) + 1e-12))
        horiz = dy * fwd_c[1] + fwd_c[2]  # forward component per unit optical depth
        with np.errstate(divide="ignore", invalid="ignore"):
            d_floor = np.where(up < -1e-9, self._cam_height / -up * horiz, 1e4)
            d_ceil = np.where(up > 1e-9, (CEILING_Z - self._cam_height) / up * horiz, 1e4)
        # floor fog rows (gain, 255 = 1) and a slightly warm tint
        fog_f = _fog(np.clip(d_floor[self._v0 :], 0, 1e4))
        self._floor_fog = np.repeat(
            np.clip(fog_f * 255.0, 0, 255).astype(np.uint8)[:, None], self.W, axis=1
        )
        # ceiling block: dark concrete, fading with distance, slight left-right falloff
        fog_c = _fog(np.clip(d_ceil[: self._v0], 0, 1e4))
        base = np.array([62.0, 64.0, 66.0])
        u = (np.arange(self.W) - self._cx) / self.W
        lateral = 1.0 - 0.25 * u * u
        block = (fog_c[:, None, None] * base + (1 - fog_c[:, None, None]) * HAZE) \
            * lateral[None, :, None]
        self._ceiling = np.clip(block, 0, 255).astype(np.uint8)

    def _build_objects(self) -> None:
        world = self.world
        rng = np.random.default_rng(world.seed + 7919)
        self._tags: list[Tag] = list(world.tags)
        solids = _FaceSet()
        # walls: 6 m segments, a coloured band below, light paint above
        band = np.array([60.0, 120.0, 40.0]) if rng.random() < 0.5 else np.array([150, 90, 30.0])
        paint = np.array([168.0, 170.0, 172.0])
        xmin, ymin, xmax, ymax = world.bounds
        centre = np.array([(xmin + xmax) / 2.0, (ymin + ymax) / 2.0])
        for wall in world.walls:
            a, b = np.asarray(wall.a, float), np.asarray(wall.b, float)
            d = b - a
            normal = np.array([-d[1], d[0], 0.0]) / (np.hypot(d[0], d[1]) + 1e-12)
            if np.dot(normal[:2], centre - (a + b) / 2.0) < 0:
                normal = -normal  # into the garage
            n_seg = max(1, int(math.ceil(np.hypot(d[0], d[1]) / 6.0)))
            for k in range(n_seg):
                p = a + d * k / n_seg
                q = a + d * (k + 1) / n_seg
                mid = (p + q) / 2.0
                light = 0.85 * self._light_at(mid + normal[:2] * 2.0) * rng.uniform(0.93, 1.05)
                faces = []
                for z0, z1, col in ((0.0, 1.0, band), (1.0, wall.height, paint)):
                    verts = np.array([[*p, z0], [*q, z0], [*q, z1], [*p, z1]])
                    faces.append(_Face(verts, normal, col * _shade(normal) * light))
                solids.add(faces, always=True)
        # light fixtures
        for p, yaw in self._lights:
            halo = _rect(p, yaw, 1.7, 0.55)
            tube = _rect(p, yaw, 1.25, 0.16)
            down = np.array([0.0, 0.0, -1.0])
            solids.add([
                _Face(np.column_stack([halo, np.full(4, LIGHT_Z + 0.01)]), down,
                      np.array([118.0, 122.0, 124.0])),
                _Face(np.column_stack([tube, np.full(4, LIGHT_Z)]), down,
                      np.array([246.0, 252.0, 252.0])),
            ])
        # a sprinkler pipe along every aisle, 1.6 m right of its centre line, 4 m pieces
        red_pipe = rng.random() < 0.5
        pipe_col = np.array([40.0, 40.0, 150.0]) if red_pipe else np.array([140.0, 140.0, 140.0])
        for aisle in world.aisles:
            a, b = np.asarray(aisle.a, float), np.asarray(aisle.b, float)
            d = b - a
            length = float(np.hypot(d[0], d[1]))
            if length < 1e-6:
                continue
            yaw = math.atan2(d[1], d[0])
            side = np.array([d[1], -d[0]]) / length * 1.6
            n = max(1, int(math.ceil(length / 4.0)))
            for k in range(n):
                mid = a + d * (k + 0.5) / n + side
                foot = _rect(mid, yaw, length / n, 0.1)
                light = self._light_at(mid)
                faces = _box(foot, 2.62, 2.72, pipe_col, None, light)
                faces.append(_Face(np.column_stack([foot[::-1], np.full(4, 2.62)]),
                                   np.array([0.0, 0.0, -1.0]), pipe_col * 0.7 * light))
                solids.add(faces)
        # pillars with their tags
        tags_by_pillar: dict[int, list[int]] = {}
        for ti, tag in enumerate(self._tags):
            p = np.asarray(tag.mTt[:2], float)
            dists = [np.linalg.norm(p - np.asarray(pl.centre)) for pl in world.pillars]
            k = int(np.argmin(dists)) if dists else -1
            if k >= 0 and dists[k] < world.pillars[k].side:
                tags_by_pillar.setdefault(k, []).append(ti)
            else:
                solids.add([self._tag_face(ti)])
        concrete = np.array([150.0, 152.0, 155.0])
        stripe = np.array([30.0, 170.0, 215.0]) if rng.random() < 0.6 else np.array([60, 60, 60.0])
        for k, pillar in enumerate(world.pillars):
            foot = np.asarray(pillar.footprint, float)
            light = self._light_at(np.asarray(pillar.centre))
            faces = _box(foot, 0.0, 0.9, stripe, None, light)
            faces += _box(foot, 0.9, pillar.height, concrete, None, light)
            faces += [self._tag_face(ti, light) for ti in tags_by_pillar.get(k, [])]
            solids.add(faces)
        # parked cars
        glass = np.array([92.0, 82.0, 72.0])
        for car in world.parked_cars:
            col = np.asarray(car.colour, float)
            c = np.asarray(car.centre, float)
            h, L, Wd = car.height, car.length, car.width
            fwd = np.array([math.cos(car.yaw), math.sin(car.yaw)])
            left = np.array([-fwd[1], fwd[0]])
            light = self._light_at(c)
            faces = _box(_rect(c, car.yaw, L * 0.9, Wd * 0.94), 0.0, 0.3 * h,
                         [18, 18, 18], None, light)
            faces += _box(_rect(c, car.yaw, L, Wd), 0.22 * h, 0.6 * h, col, col + 28.0, light)
            for end, lamp in ((1.0, [205.0, 215.0, 215.0]), (-1.0, [25.0, 25.0, 175.0])):
                for sgn in (-1.0, 1.0):
                    p = c + fwd * end * (L / 2.0 + 0.005) + left * sgn * Wd * 0.34
                    seg = np.array([p - left * Wd * 0.1, p + left * Wd * 0.1])
                    z0, z1 = 0.42 * h, 0.54 * h
                    verts = np.array([[*seg[0], z0], [*seg[1], z0], [*seg[1], z1], [*seg[0], z1]])
                    faces.append(_Face(verts, np.array([*(fwd * end), 0.0]),
                                       np.asarray(lamp) * (0.9 if end > 0 else 1.0)))
            cabin_lo = _rect(c - fwd * 0.05 * L, car.yaw, L * 0.56, Wd * 0.88)
            cabin_hi = _rect(c - fwd * 0.08 * L, car.yaw, L * 0.34, Wd * 0.74)
            faces += _frustum(cabin_lo, cabin_hi, 0.6 * h, h, glass, col * 0.95 + 22.0, light)
            solids.add(faces)
        # ceiling beams over the pillar lines, 4 m pieces
        self._add_beams(solids)
        solids.freeze()
        self._solids = solids
        # floor paint: line markings
        paint_col = np.asarray(world.line_colour, float) * 0.82
        floor = _FaceSet()
        up = np.array([0.0, 0.0, 1.0])
        for m in world.markings:
            a, b = np.asarray(m.a, float), np.asarray(m.b, float)
            d = b - a
            length = float(np.hypot(d[0], d[1]))
            if length < 1e-6:
                continue
            t = d / length
            nrm = np.array([-t[1], t[0]]) * m.width / 2.0
            a2, b2 = a - t * m.width / 2.0, b + t * m.width / 2.0  # square caps
            quad = np.array([a2 - nrm, b2 - nrm, b2 + nrm, a2 + nrm])
            floor.add([_Face(np.column_stack([quad, np.zeros(4)]), up, paint_col)])
        floor.freeze()
        self._floor = floor
        self._paint_colour = tuple(float(x) for x in paint_col)

    def _add_beams(self, solids: _FaceSet) -> None:
        """Ceiling beams along the lines the pillars stand on, wall to wall."""
        world = self.world
        xmin, ymin, xmax, ymax = world.bounds
        centres = np.array([np.asarray(p.centre, float) for p in world.pillars]).reshape(-1, 2)
        colour = np.array([92.0, 94.0, 97.0])
        lines: list[tuple[FloatArray, FloatArray]] = []
        for axis in (0, 1):  # beams along x at shared pillar y's, along y at shared x's
            vals = np.sort(centres[:, 1 - axis]) if len(centres) else np.zeros(0)
            groups: list[list[float]] = []
            for v in vals:
                if groups and v - groups[-1][-1] < 0.05:
                    groups[-1].append(float(v))
                else:
                    groups.append([float(v)])
            for g in groups:
                if len(g) < 2:
                    continue
                v = float(np.mean(g))
                if axis == 0:
                    lines.append((np.array([xmin, v]), np.array([xmax, v])))
                else:
                    lines.append((np.array([v, ymin]), np.array([v, ymax])))
        for a, b in lines:
            length = float(np.linalg.norm(b - a))
            n = max(1, int(math.ceil(length / 4.0)))
            yaw = math.atan2(b[1] - a[1], b[0] - a[0])
            for k in range(n):
                mid = a + (b - a) * (k + 0.5) / n
                foot = _rect(mid, yaw, length / n, 0.4)
                light = self._light_at(mid)
                faces = _box(foot, CEILING_Z - 0.45, CEILING_Z, colour, None, light)
                bottom = np.column_stack([foot[::-1], np.full(4, CEILING_Z - 0.45)])
                faces.append(_Face(bottom, np.array([0.0, 0.0, -1.0]), colour * 0.8 * light))
                solids.add(faces)

    def _tag_face(self, ti: int, light: float = 1.0) -> _Face:
        """The printed tag (with quiet border) as a quad TL, TR, BR, BL seen from the front."""
        tag = self._tags[ti]
        x, y, yaw = (float(v) for v in tag.mTt)
        cells = _TAG_BITS.get(tag.family, 6) + 2
        half = tag.size * (cells + 2) / cells / 2.0
        right = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
        upv = np.array([0.0, 0.0, 1.0])
        c = np.array([x, y, tag.height])
        verts = np.array([c - right * half + upv * half, c + right * half + upv * half,
                          c + right * half - upv * half, c - right * half - upv * half])
        normal = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        return _Face(verts, normal, np.array([light, light, light]), tag=ti)

    def _build_camera_effects(self) -> None:
        H, W = self.H, self.W
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        rx = (xx - self._cx) / self._fx
        ry = (yy - self._cy) / self._fy
        cos4 = 1.0 / (1.0 + rx * rx + ry * ry) ** 2
        vig = 0.55 + 0.45 * cos4 / cos4.max()  # milder than a raw cos^4 (lens is corrected)
        self._vignette = cv2.cvtColor((vig * 255.0).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        rng = np.random.default_rng(4242)
        self._noise_margin = 48
        noise = rng.normal(20.0, 4.0, (H + self._noise_margin, W + self._noise_margin, 3))
        self._noise = np.clip(noise, 0, 40).astype(np.uint8)

    # ------------------------------------------------------------------ per frame

    def _camera_in_map(self, mTv: ArrayLike) -> FloatArray:
        x, y, yaw = (float(v) for v in np.asarray(mTv, dtype=float).reshape(3))
        T_mv = np.eye(4)
        c, s = math.cos(yaw), math.sin(yaw)
        T_mv[:2, :2] = [[c, -s], [s, c]]
        T_mv[0, 3], T_mv[1, 3] = x, y
        return T_mv @ self.T_vc

    def _project_set(self, fs: _FaceSet, R: FloatArray, t: FloatArray, C: FloatArray,
                     sort: bool):
        """Cull, clip and project a face set. Returns (polygons, face indices, distances)
        with polygons as int32 fixed-point pixel arrays, drawing order far to near."""
        if len(fs.radius) == 0:
            return [], np.zeros(0, np.intp), np.zeros(0)
        oc = fs.centre @ R.T + t  # object centres, camera frame
        dist = np.linalg.norm(fs.centre - C, axis=1)
        tan_h = (self.W / 2.0 + 2) / self._fx
        cos_h = 1.0 / math.sqrt(1.0 + tan_h * tan_h)
        side = (np.abs(oc[:, 0]) - oc[:, 2] * tan_h) * cos_h  # distance outside the side plane
        keep = (oc[:, 2] + fs.radius > NEAR) & (side < fs.radius)
        keep &= fs.always | (dist - fs.radius < self.max_range)
        objs = np.flatnonzero(keep)
        if len(objs) == 0:
            return [], np.zeros(0, np.intp), np.zeros(0)
        if sort:
            key = np.where(fs.always[objs], np.inf, dist[objs])
            objs = objs[np.argsort(-key, kind="stable")]
        idx = np.concatenate([np.arange(fs.face_start[o], fs.face_stop[o]) for o in objs])
        visible = np.einsum("ij,ij->i", fs.normal[idx], C - fs.face_centre[idx]) > 1e-9
        idx = idx[visible]
        P = fs.verts[idx] @ R.T + t  # (n, 4, 3)
        z = P[:, :, 2]
        front = z >= NEAR
        all_in = front.all(axis=1)
        polys: list[NDArray[np.int32]] = []
        out_idx = []
        f = np.array([self._fx, self._fy])
        c = np.array([self._cx, self._cy])
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = P[:, :, :2] / z[:, :, None] * f + c
        fixed = np.round(uv * _SUB)
        any_in = front.any(axis=1)
        for k in range(len(idx)):
            if all_in[k]:
                polys.append(fixed[k].astype(np.int32))
            elif any_in[k]:
                q = _clip_near(P[k], NEAR)
                if len(q) < 3:
                    continue
                polys.append(np.round((q[:, :2] / q[:, 2:3] * f + c) * _SUB).astype(np.int32))
            else:
                continue
            out_idx.append(k)
        sel = idx[np.array(out_idx, dtype=np.intp)]
        fdist = np.linalg.norm(fs.face_centre[sel] - C, axis=1)
        return polys, sel, fdist

    def render(self, mTv: ArrayLike, seed: int) -> NDArray[np.uint8]:
        """The front image (H x W x 3 uint8 BGR) of a vehicle at pose ``mTv`` (x, y, yaw)
        in the map frame; ``seed`` drives the per-frame exposure, blur and noise."""
        pose_arr = np.asarray(mTv, dtype=float)
        if pose_arr.shape != (3,) or not np.isfinite(pose_arr).all():
            raise SimulationError(f"mTv must be a finite (x, y, yaw) array, got {pose_arr!r}")
        T_mc = self._camera_in_map(pose_arr)
        R = T_mc[:3, :3].T  # map -> camera
        C = T_mc[:3, 3]
        t = -R @ C
        H, W, v0 = self.H, self.W, self._v0
        img = np.empty((H, W, 3), np.uint8)
        hf = H - v0
        fwd = T_mc[:2, 2] / (np.linalg.norm(T_mc[:2, 2]) + 1e-12)

        # ---- ceiling: concrete x light map (both at half/quarter resolution: it is smooth)
        if v0 > 0:
            Pc = self.K @ np.column_stack([R[:, 0], R[:, 1], R[:, 2] * CEILING_Z + t])
            half = np.diag([0.5, 0.5, 1.0])
            wh, hh = (W + 1) // 2, (v0 + 1) // 2
            ctex = cv2.warpPerspective(self._tex, half @ Pc @ self._tex_A(C[:2] + fwd * 8.0, 2.0),
                                       (wh, hh), flags=cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=112)
            quarter = np.diag([0.25, 0.25, 1.0])
            clit = cv2.warpPerspective(self._ceil_lightmap, quarter @ Pc @ self._lightmap_A,
                                       ((W + 3) // 4, (v0 + 3) // 4), flags=cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_REPLICATE)
            clit = cv2.resize(clit, (wh, hh), interpolation=cv2.INTER_LINEAR)
            ctex = cv2.addWeighted(ctex, 0.6, ctex, 0.0, 112.0 * 0.4)  # smoother than the floor
            cg = cv2.resize(cv2.multiply(ctex, clit, scale=1.0 / 128.0), (W, v0),
                            interpolation=cv2.INTER_LINEAR)
            img[:v0] = cv2.multiply(self._ceiling, cv2.cvtColor(cg, cv2.COLOR_GRAY2BGR),
                                    scale=1.0 / 112.0)

        # ---- floor: texture x light map, markings, fog
        P = self.K @ np.column_stack([R[:, 0], R[:, 1], t])  # ground (X, Y, 1) -> image
        shift = np.array([[1.0, 0, 0], [0, 1.0, -v0], [0, 0, 1.0]])
        tex = cv2.warpPerspective(self._tex, shift @ P @ self._tex_A(C[:2] + fwd * 12.0, 1.0),
                                  (W, hf), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=112)
        quarter = np.diag([0.25, 0.25, 1.0])
        lit = cv2.warpPerspective(self._lightmap, quarter @ shift @ P @ self._lightmap_A,
                                  ((W + 3) // 4, (hf + 3) // 4), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REPLICATE)
        lit = cv2.resize(lit, (W, hf), interpolation=cv2.INTER_LINEAR)
        gain = cv2.multiply(lit, self._floor_fog, scale=1.0 / 255.0)
        floor3 = cv2.cvtColor(tex, cv2.COLOR_GRAY2BGR)
        polys, _, _ = self._project_set(self._floor, R, t, C, sort=False)
        paint = self._paint_colour
        for poly in polys:
            poly[:, 1] -= int(v0 * _SUB)
            cv2.fillConvexPoly(floor3, poly, paint, cv2.LINE_AA, SUBPIXEL_SHIFT)
        img[v0:] = cv2.multiply(floor3, cv2.cvtColor(gain, cv2.COLOR_GRAY2BGR), scale=1.0 / 128.0)

        # ---- walls, lights, pillars, tags, cars (far to near)
        polys, sel, fdist = self._project_set(self._solids, R, t, C, sort=True)
        fog = _fog(fdist)[:, None]
        colours = self._solids.colour[sel] * fog + HAZE * (1.0 - fog)
        colours = np.clip(colours, 0, 255).tolist()
        tags = self._solids.tag[sel]
        for k, poly in enumerate(polys):
            if tags[k] >= 0:
                self._draw_tag(img, int(tags[k]), R, t, float(fog[k, 0]),
                               self._solids.colour[sel[k], 0])
            else:
                cv2.fillConvexPoly(img, poly, colours[k], cv2.LINE_AA, SUBPIXEL_SHIFT)

        return self._camera_effects(img, seed)

    def _tex_A(self, centre: FloatArray, scale: float) -> FloatArray:
        """Texture pixel -> map point for the tiled texture at ``scale`` x its resolution,
        shifted by whole tiles so that map point ``centre`` lands in the middle tile."""
        n = TEXTURE_PX
        s = TEXTURE_M_PER_PX * scale
        off = np.floor(centre / (n * s)) * n - n  # texture px of the middle tile's origin
        return np.array([[s, 0, off[0] * s], [0, s, off[1] * s], [0, 0, 1.0]])

    def _draw_tag(self, img: NDArray[np.uint8], ti: int, R: FloatArray, t: FloatArray,
                  fog: float, light: float) -> None:
        """Warp tag ``ti`` into ``img`` from its exactly projected outer corners."""
        face = self._tag_face(ti)
        P = face.verts @ R.T + t
        if (P[:, 2] < NEAR).any():
            return
        uv = P[:, :2] / P[:, 2:3] * np.array([self._fx, self._fy]) + np.array([self._cx, self._cy])
        x0 = max(0, int(math.floor(uv[:, 0].min())) - 1)
        y0 = max(0, int(math.floor(uv[:, 1].min())) - 1)
        x1 = min(self.W, int(math.ceil(uv[:, 0].max())) + 2)
        y1 = min(self.H, int(math.ceil(uv[:, 1].max())) + 2)
        if x1 <= x0 or y1 <= y0:
            return
        tag = self._tags[ti]
        cells = _TAG_BITS.get(tag.family, 6) + 4  # code + quiet border
        side_px = max(np.linalg.norm(uv[i] - uv[(i + 1) % 4]) for i in range(4))
        cell_dst = side_px / cells
        # source no finer than the destination: bilinear magnification keeps every edge at
        # its exact sub-pixel place (minifying would snap edges to pixel borders)
        cell_src = max((c for c in _TAG_MIP_CELLS if c <= cell_dst), default=_TAG_MIP_CELLS[0])
        src = _tag_code_image(tag.family, tag.tag_id, cell_src)
        s = float(src.shape[0])
        src_pts = np.array([[-0.5, -0.5], [s - 0.5, -0.5], [s - 0.5, s - 0.5], [-0.5, s - 0.5]],
                           np.float32)
        dst_pts = (uv - np.array([x0, y0])).astype(np.float32)
        M = cv2.getPerspectiveTransform(src_pts, dst_pts)
        lum = light * fog
        white = TAG_WHITE * lum + HAZE[0] * (1 - fog)
        black = TAG_BLACK * lum + HAZE[0] * (1 - fog)
        shaded = cv2.convertScaleAbs(src, alpha=(white - black) / 255.0, beta=black)
        roi = np.ascontiguousarray(img[y0:y1, x0:x1])
        cv2.warpPerspective(shaded, M, (x1 - x0, y1 - y0), dst=roi, flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_TRANSPARENT)
        img[y0:y1, x0:x1] = roi

    def _camera_effects(self, img: NDArray[np.uint8], seed: int) -> NDArray[np.uint8]:
        rng = np.random.default_rng(seed)
        gain = rng.uniform(0.88, 1.12)
        sigma = rng.uniform(0.55, 0.85)
        beta = rng.uniform(0.7, 1.3)
        oy, ox = rng.integers(0, self._noise_margin + 1, 2)
        blurred = cv2.GaussianBlur(img, (3, 3), sigma)
        exposed = cv2.multiply(blurred, self._vignette, scale=gain * 1.15 / 255.0)
        noise = self._noise[oy : oy + self.H, ox : ox + self.W]
        return np.asarray(cv2.addWeighted(exposed, 1.0, noise, beta, -20.0 * beta), np.uint8)


@functools.lru_cache(maxsize=2)
def _cached_renderer(world: World, camera: Camera) -> FrontRenderer:
    return FrontRenderer(world, camera)


def render_front(world: World, camera: Camera, mTv: ArrayLike, seed: int = 0) -> NDArray[np.uint8]:
    """One front image of ``world`` from vehicle pose ``mTv`` (x, y, yaw in the map frame).

    Keeps the renderers of the last two (world, camera) pairs, so calling it frame after
    frame costs no more than :meth:`FrontRenderer.render`.
    """
    return _cached_renderer(world, camera).render(mTv, seed)


__all__ = ["FrontRenderer", "render_front"]
