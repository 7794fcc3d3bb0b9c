"""Synthetic ps2.0-style surround-view top views of a simulated garage.

The image is built the way a real surround-view system builds it, in cheap steps:

1. a sharp ground image ``S`` on the top-view grid of :class:`TopviewSpec` holding the
   world-anchored floor (a periodic texture, and a low-resolution map of stains, tyre
   marks, light pools and car shadows baked once per world), painted lines, slot numbers
   and drain grates, and the tall things (parked cars, pillars, walls) projected onto the
   ground from the camera whose region they fall in: a point at height h seen from a
   camera at height H above ground point c lands at ``c + (q - c) * H / (H - h)``, so
   they stretch away from the car as in real stitched views;
2. one small polar image per camera (rows = angle from the camera's nadir, columns =
   azimuth), resampled from ``S``. Rows are uniform in angle, so the ground resolution
   falls as (H^2 + r^2) / H with distance r: the radial smear of a fisheye resampled to
   the ground. Sensor effects happen there, where they are cheap and radial: per-camera
   gain and colour cast, vignetting, specular streaks of the ceiling lights, radial
   blur, noise, contrast;
3. one remap back to the top-view grid with hard diagonal seams between the cameras,
   the black ego box, and (optionally) a JPEG round trip.

World-anchored content depends only on ``world.seed``; ``seed`` drives the per-frame
variation. The same (world, mTv, seed) always gives the same bytes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from semslam.geometry import FloatArray, clip_segment
from semslam.rig import TopviewSpec
from semslam.simulation.world_types import World
from semslam.types import JunctionShape, SlotKind

_TEX = 480  # floor texture side, texels (periodic)
_TEX_M = 1.0 / 30.0  # metres per texel: the texture repeats every 16 m
_LOW = 150  # side of the per-frame low-resolution light/stain layer, px
_FMAX = 25.0  # clamp of the height stretch factor H / (H - h)
_SHIFT = 4  # fixed-point bits for antialiased polygons
_CAMS = ("front", "rear", "left", "right")
_DRHO0 = 0.018  # m: finest ground spacing of atlas rows (near the camera)
_DPHI = math.radians(0.6)  # atlas column step (azimuth)


@dataclass(frozen=True, eq=False)
class TopviewAnnotation:
    """Training labels of one rendered top view (pixel coordinates, u right, v down).

    Attributes:
        points: (N, 2) marking points inside the image and outside the ego box.
        directions: (N,) radians in image coordinates, atan2(dv, du), of the separator
            line from the junction into the slot (DMPR-PS convention).
        shapes: (N,) int, 0 = T junction, 1 = L junction (DMPR-PS convention).
        occluded: (N,) bool, True where a parked car, pillar or wall is drawn over the point.
        slots: (M, 4) int ``[i, j, type, angle_deg]``: 1-based indices into ``points`` of
            the slot's corners[0] and corners[1]; type 1 perpendicular, 2 parallel,
            3 slanted; angle between entrance line and separator in degrees (90 unless
            slanted).
        ids: per painted label in full view (inside the image, clear of the ego box, no
            car, pillar or wall drawn over its box): (slot_id, label, (4, 2) pixel corners
            of the text's rotated box: bottom-left, bottom-right, top-right, top-left as
            read).
    """

    points: FloatArray
    directions: FloatArray
    shapes: np.ndarray
    occluded: np.ndarray
    slots: np.ndarray
    ids: tuple[tuple[int, str, FloatArray], ...]


@dataclass(frozen=True)
class _Camera:
    position: FloatArray  # (2,) vehicle frame, m
    height: float  # m
    phi0: float  # azimuth of atlas column 0, rad (vehicle frame)
    rho: np.ndarray  # ground distance (m) of each atlas row
    row0: int  # first atlas row of this camera's block


def _periodic_noise(rng: np.random.Generator, n: int, beta: float, fmin: float) -> np.ndarray:
    """Zero-mean, unit-std periodic (n, n) noise with a 1/f^beta amplitude spectrum."""
    f = np.fft.fftfreq(n)
    r = np.hypot(f[:, None], f[None, :])
    amp = np.where(r < fmin / n, 0.0, 1.0 / np.maximum(r, 1.0 / n) ** beta)
    img = np.real(np.fft.ifft2(amp * np.exp(2j * np.pi * rng.random((n, n)))))
    return ((img - img.mean()) / (img.std() + 1e-9)).astype(np.float32)


def _area2(p: np.ndarray) -> float:
    """Twice the signed area of a polygon (N, 2)."""
    return float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


def _clip_convex(
    poly: list[tuple[float, float]], clip: list[tuple[float, float]]
) -> list[tuple[float, float]]:
    """Sutherland-Hodgman: ``poly`` clipped to the convex polygon ``clip`` (positive
    signed area); plain floats, fast for a handful of vertices."""
    out = poly
    m = len(clip)
    for k in range(m):
        if not out:
            break
        ax, ay = clip[k]
        bx, by = clip[(k + 1) % m]
        ex, ey = bx - ax, by - ay
        side = [ex * (py - ay) - ey * (px - ax) for px, py in out]
        res = []
        n = len(out)
        for i in range(n):
            j = (i + 1) % n
            sp, sq = side[i], side[j]
            if sp >= 0:
                res.append(out[i])
            if (sp >= 0) != (sq >= 0):
                t = sp / (sp - sq)
                (px, py), (qx, qy) = out[i], out[j]
                res.append((px + (qx - px) * t, py + (qy - py) * t))
        out = res
    return out


def _covered(points: np.ndarray, polys: list[np.ndarray]) -> np.ndarray:
    """(N,) bool: which pixel ``points`` (N, 2) lie strictly inside one of the drawn
    ``polys`` (pixel polygons of cars, pillars, walls)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    covered = np.zeros(len(points), bool)
    if not len(points) or not polys:
        return covered
    lo = np.array([poly.min(axis=0) for poly in polys])
    hi = np.array([poly.max(axis=0) for poly in polys])
    cand = ((points[:, None, :] >= lo[None]) & (points[:, None, :] <= hi[None])).all(axis=2)
    for i, k in zip(*np.nonzero(cand), strict=True):
        if not covered[i] and cv2.pointPolygonTest(
            polys[k], (float(points[i, 0]), float(points[i, 1])), False
        ) > 0:
            covered[i] = True
    return covered


def _fixed(p: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(p) * (1 << _SHIFT)).astype(np.int32)


class TopviewRenderer:
    """Renders top views of one world; everything per-world is built once here.

    Args:
        world: the garage.
        spec: the top-view grid.
        jpeg: finish every frame with a JPEG round trip (quality 60-92, per frame).
    """

    def __init__(self, world: World, spec: TopviewSpec | None = None, jpeg: bool = True) -> None:
        self.world = world
        self.spec = spec = spec or TopviewSpec()
        self.jpeg = jpeg
        rng = np.random.default_rng([world.seed, 9017])
        self._build_floor(rng)
        self._build_rig(rng)
        self._build_items(rng)
        self._build_low_map(rng)

    # ------------------------------------------------------------------ per-world setup

    def _build_floor(self, rng: np.random.Generator) -> None:
        """The periodic floor texture (uint8, 128 = gain 1) and the floor colour."""
        kind = str(rng.choice(["concrete", "painted", "pavers"], p=[0.6, 0.25, 0.15]))
        self.floor_kind = kind
        low = _periodic_noise(rng, _TEX, 1.6, 2.0)
        mid = _periodic_noise(rng, _TEX, 1.0, 8.0)
        fine = _periodic_noise(rng, _TEX, 0.5, 30.0)
        if kind == "painted":
            tex = 1.0 + 0.05 * low + 0.03 * mid + 0.02 * fine
            base = np.array(
                [[115, 150, 105], [135, 150, 120], [150, 150, 150], [110, 120, 130]][
                    int(rng.integers(4))
                ],
                float,
            )
            base += rng.normal(0, 8, 3)
        else:
            tex = 1.0 + 0.07 * low + 0.04 * mid + 0.025 * fine
            gray = rng.uniform(115, 160)
            warm = rng.uniform(-5, 25)  # beige cast
            base = np.array([gray - warm, gray, gray + 0.6 * warm])
            if kind == "pavers":
                yy, xx = np.mgrid[0:_TEX, 0:_TEX]
                bw, bh = 6, 3  # 0.2 m x 0.1 m bricks, running bond
                off = (yy // bh) % 2 * (bw // 2)
                joint = ((yy % bh) == 0) | (((xx + off) % bw) == 0)
                brick = rng.normal(0, 0.05, (_TEX // bh + 1, _TEX // bw + 2))
                tex = tex + brick[yy // bh, (xx + off) // bw] - 0.12 * joint
        specks = rng.random((_TEX, _TEX))
        tex = tex - 0.2 * (specks < 0.0015) + 0.1 * (specks > 0.999)
        self._tex = np.clip(tex * 128.0, 0, 255).astype(np.uint8)
        n = self.spec.size_px
        self._floor_img = np.empty((n, n, 3), np.uint8)
        self._floor_img[:] = np.clip(base, 0, 255).astype(np.uint8)
        wear = rng.uniform(0.88, 1.0)
        self._paint_bgr = tuple(float(v) * wear for v in self.world.line_colour)
        own = self.world.marking_colours  # per marking, BGR: the line colour or its own
        self._mark_bgr = [
            self._paint_bgr if k >= len(own) or own[k] is None
            else tuple(float(v) * wear for v in own[k])
            for k in range(len(self.world.markings))
        ]

    def _build_rig(self, rng: np.random.Generator) -> None:
        """Four cameras, the diagonal seams, and the polar atlas maps (both directions)."""
        spec = self.spec
        n, s, c = spec.size_px, spec.metres_per_px, spec.centre_px
        L2, W2 = spec.ego_length_m / 2.0, spec.ego_width_m / 2.0
        # cameras sit inside the ego box so every region is within +-90 deg of their axis
        pos = {
            "front": (L2 - 0.05, 0.0),
            "rear": (-L2 + 0.1, 0.0),
            "left": (L2 * rng.uniform(0.2, 0.45), W2 - 0.05),
            "right": (L2 * rng.uniform(0.2, 0.45), -W2 + 0.05),
        }
        heights = {
            "front": rng.uniform(0.6, 0.85),
            "rear": rng.uniform(0.8, 1.0),
            "left": rng.uniform(0.95, 1.1),
            "right": rng.uniform(0.95, 1.1),
        }
        yaws = {"front": 0.0, "rear": math.pi, "left": math.pi / 2, "right": -math.pi / 2}
        af = math.radians(rng.uniform(18, 40))  # seam angle from the forward axis
        ar = math.radians(rng.uniform(12, 35))  # seam angle from the rearward axis
        far = 50.0
        fl, fr, rl, rr = (np.array(p) for p in ((L2, W2), (L2, -W2), (-L2, W2), (-L2, -W2)))
        dfl, dfr = np.array([math.cos(af), math.sin(af)]), np.array([math.cos(af), -math.sin(af)])
        drl, drr = np.array([-math.cos(ar), math.sin(ar)]), np.array([-math.cos(ar), -math.sin(ar)])
        regions_v = {
            "front": [fl, fl + far * dfl, fr + far * dfr, fr],
            "rear": [rl, rr, rr + far * drr, rl + far * drl],
            "left": [fl, rl, rl + far * drl, fl + far * dfl],
            "right": [fr, fr + far * dfr, rr + far * drr, rr],
        }
        self._regions: dict[str, list[tuple[float, float]]] = {}
        self._planes: dict[str, np.ndarray] = {}
        for k, v in regions_v.items():
            px = spec.vehicle_to_pixel(np.array(v))
            px = px if _area2(px) > 0 else px[::-1]
            self._regions[k] = [(float(a), float(b)) for a, b in px]
            e = np.roll(px, -1, axis=0) - px  # inside: e x (p - a) >= 0 for every edge
            self._planes[k] = np.stack(
                [-e[:, 1], e[:, 0], e[:, 1] * px[:, 0] - e[:, 0] * px[:, 1]], axis=1
            )
        vv, uu = np.mgrid[0:n, 0:n].astype(np.float64)
        x, y = (c - vv) * s, (c - uu) * s
        front = (x >= L2) & (np.abs(y) - W2 <= (x - L2) * math.tan(af))
        rear = (x <= -L2) & (np.abs(y) - W2 <= (-L2 - x) * math.tan(ar))
        label = np.where(front, 0, np.where(rear, 1, np.where(y >= 0, 2, 3)))
        label[(np.abs(x) < L2) & (np.abs(y) < W2)] = -1  # the ego box: drawn black
        self._cams: dict[str, _Camera] = {}
        dtheta = rng.uniform(0.0035, 0.005)  # effective angular resolution of the fisheyes
        row0 = 0
        back_x = np.full((n, n), -10.0, np.float32)
        back_y = np.full((n, n), -10.0, np.float32)
        self._source_spacing = np.full((n, n), np.nan, np.float32)
        fwd: list[tuple[np.ndarray, np.ndarray]] = []
        for ci, name in enumerate(_CAMS):
            cp, H, yaw = np.array(pos[name]), float(heights[name]), yaws[name]
            m = label == ci
            rx, ry = x[m] - cp[0], y[m] - cp[1]
            phi = np.mod(np.arctan2(ry, rx) - yaw + math.pi, 2 * math.pi) - math.pi
            dist = np.hypot(rx, ry)
            phi0 = float(phi.min()) - 3 * _DPHI
            cols = int(math.ceil((float(phi.max()) + 3 * _DPHI - phi0) / _DPHI))
            # rows: ground spacing _DRHO0 near the camera, growing like a fisheye's
            # (H^2 + r^2) / H * dtheta farther out
            grid = np.linspace(0.0, float(dist.max()) + 0.3, 4000)
            step = np.maximum(_DRHO0, dtheta * (H * H + grid**2) / H)
            w = np.concatenate([[0.0], np.cumsum(np.diff(grid) / step[1:])])
            nrows = int(math.ceil(w[-1])) + 1
            rho_rows = np.interp(np.arange(nrows), w, grid)
            self._cams[name] = _Camera(cp, H, phi0 + yaw, rho_rows, row0)
            self._source_spacing[m] = np.maximum(
                np.maximum(_DRHO0, dtheta * (H * H + dist**2) / H), dist * _DPHI
            )
            back_x[m] = (phi - phi0) / _DPHI
            back_y[m] = np.interp(dist, grid, w) + row0
            rho = rho_rows[:, None]
            ph = (phi0 + yaw + np.arange(cols) * _DPHI)[None, :]
            gx, gy = cp[0] + rho * np.cos(ph), cp[1] + rho * np.sin(ph)
            fwd.append(((c - gy / s).astype(np.float32), (c - gx / s).astype(np.float32)))
            row0 += nrows + 2
        width = max(fx.shape[1] for fx, _ in fwd)
        self._atlas_shape = (row0, width)
        fx_all = np.full(self._atlas_shape, -10.0, np.float32)
        fy_all = np.full(self._atlas_shape, -10.0, np.float32)
        for name, (fx, fy) in zip(_CAMS, fwd, strict=True):
            r0 = self._cams[name].row0
            fx_all[r0 : r0 + fx.shape[0], : fx.shape[1]] = fx
            fy_all[r0 : r0 + fy.shape[0], : fy.shape[1]] = fy
        self._fwd = cv2.convertMaps(fx_all, fy_all, cv2.CV_16SC2)
        self._back = cv2.convertMaps(back_x, back_y, cv2.CV_16SC2)
        vig = np.ones(self._atlas_shape, np.float32)
        for cam in self._cams.values():
            t = np.arctan(cam.rho / cam.height) / (math.pi / 2)
            nr = len(cam.rho)
            vig[cam.row0 : cam.row0 + nr] = (1.0 - rng.uniform(0.2, 0.45) * t**4)[:, None]
            # faint camera-anchored radial streaks (vertical in the atlas), stronger far out
            prof = cv2.GaussianBlur(
                rng.normal(0.0, 1.0, (1, width)).astype(np.float32), (0, 0), 1.5
            )[0]
            vig[cam.row0 : cam.row0 + nr] *= 1.0 + 0.06 * (t**1.5)[:, None] * prof[None, :]
        self._vignette = cv2.cvtColor(
            np.clip(vig * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR
        )
        nrng = np.random.default_rng(12345)  # sensor-noise bank, uint8 around 128
        bank = nrng.normal(0.0, 20.0, (row0 + 64, width + 64, 3))
        bank += nrng.normal(0.0, 12.0, (row0 + 64, width + 64, 1))
        self._noise = np.clip(bank + 128.0, 0, 255).astype(np.uint8)
        # ego box (rows v0:v1, cols u0:u1) and the ego car's soft shadow on the low layer
        hu, hv = W2 / s, L2 / s
        self._ego = (
            int(math.ceil(c - hv)),
            int(math.floor(c + hv)) + 1,
            int(math.ceil(c - hu)),
            int(math.floor(c + hu)) + 1,
        )
        g = (np.arange(_LOW) + 0.5) * (n / _LOW) - 0.5
        gv, gu = np.meshgrid(g, g, indexing="ij")
        d = np.hypot(
            np.maximum(np.abs(c - gv) * s - L2, 0.0), np.maximum(np.abs(c - gu) * s - W2, 0.0)
        )
        shadow = 1.0 - rng.uniform(0.35, 0.7) * np.exp(-((d / rng.uniform(0.12, 0.3)) ** 2))
        self._ego_shadow = np.clip(shadow * 255.0, 0, 255).astype(np.uint8)

    def _build_items(self, rng: np.random.Generator) -> None:
        """World-frame geometry of everything drawn per frame, with centres and radii
        for the proximity query."""
        world = self.world
        quads = []
        for m in world.markings:
            a, b, w = np.asarray(m.a, float), np.asarray(m.b, float), float(m.width)
            ln = float(np.hypot(*(b - a)))
            t = (b - a) / ln if ln > 1e-9 else np.array([1.0, 0.0])
            nrm = np.array([-t[1], t[0]]) * w / 2.0
            ext = t * (w / 2.0 if ln < 1e-9 else 0.0)
            quads.append([a - nrm - ext, b - nrm + ext, b + nrm + ext, a + nrm - ext])
        self._mark_quads = np.array(quads, float).reshape(-1, 4, 2)
        # painted labels: a white-on-black glyph patch and its box in the world
        self._labels: list[tuple[int, str, np.ndarray]] = []
        self._glyphs: list[list[np.ndarray]] = []
        boxes = []
        for p in world.slot_paint:
            label = world.slots[p.slot_id].label or ""
            patch = self._text_patch(label, rng)
            h = p.text_height
            w = h * patch.shape[1] / patch.shape[0]
            up = np.array([math.cos(p.up), math.sin(p.up)])
            right = np.array([up[1], -up[0]])  # reading direction for a viewer facing `up`
            c = np.asarray(p.centre, float)
            boxes.append(
                [
                    c - right * w / 2 - up * h / 2,
                    c + right * w / 2 - up * h / 2,
                    c + right * w / 2 + up * h / 2,
                    c - right * w / 2 + up * h / 2,
                ]
            )
            self._labels.append((int(p.slot_id), label, patch))
            self._glyphs.append(self._outlines(patch))
        self._label_boxes = np.array(boxes, float).reshape(-1, 4, 2)
        self._car_fp = np.array([c.footprint for c in world.parked_cars], float).reshape(-1, 4, 2)
        self._car_bands = []
        for car in world.parked_cars:
            col = np.array(car.colour, float) * rng.uniform(0.8, 1.15, 3)
            hi = np.minimum(col * 1.25 + 45, 255)
            layers: list[tuple[float, float, np.ndarray]] = [
                (0.0, 0.1, np.array([15.0, 15, 17])),
                (0.1, 0.3, col * 0.25 + 20),
                (0.3, 0.44, col * 0.8),
                (0.44, 0.49, hi),
                (0.49, 0.72, col),
                (0.72, 0.78, col * 0.55),
                (0.78, 0.86, hi * 0.9),
                (0.86, 0.93, np.array([28.0, 28, 30])),
                (0.93, 5.0, np.array([75.0, 66, 60]) + rng.normal(0, 12, 3)),
            ]
            self._car_bands.append(
                [(h0, h1, tuple(float(np.clip(v, 0, 255)) for v in c)) for h0, h1, c in layers]
            )
        self._wall_stripe = (
            (40.0, 160.0, 200.0),
            (90.0, 140.0, 60.0),
            (150.0, 150.0, 150.0),
            (60.0, 60.0, 60.0),
        )[int(rng.integers(4))]
        self._pillar_bands = [
            (0.0, 0.2, (40.0, 170.0, 200.0)),
            (0.2, 0.4, (40.0, 40.0, 40.0)),
            (0.4, 0.6, (40.0, 170.0, 200.0)),
            (0.6, 5.0, (165.0, 168.0, 170.0)),
        ]
        self._pillar_fp = np.array([p.footprint for p in world.pillars], float).reshape(-1, 4, 2)
        self._pts = np.array([mp.position for mp in world.marking_points], float).reshape(-1, 2)
        self._pt_dir = np.array([mp.direction for mp in world.marking_points], float)
        self._pt_shape = np.array(
            [0 if mp.shape == JunctionShape.T else 1 for mp in world.marking_points], int
        )
        # each slot's entrance corners as marking-point indices (-1: none within 1 cm)
        self._slot_pts = np.full((len(world.slots), 2), -1, int)
        for k, slot in enumerate(world.slots):
            for j in range(2):
                if len(self._pts):
                    d = np.hypot(*(self._pts - np.asarray(slot.corners[j], float)).T)
                    if d.min() <= 0.01:
                        self._slot_pts[k, j] = int(d.argmin())
        # drain grates
        xmin, ymin, xmax, ymax = world.bounds
        area = (xmax - xmin) * (ymax - ymin)
        grates = []
        for _ in range(int(area * rng.uniform(0.002, 0.006))):
            gp = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
            size, ang = rng.uniform(0.3, 0.6), rng.uniform(0, np.pi / 2)
            R = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
            grates.append((np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * size / 2) @ R.T + gp)
        self._grates = np.array(grates, float).reshape(-1, 4, 2)

    def _build_low_map(self, rng: np.random.Generator) -> None:
        """World-anchored low-resolution gain map (uint8, 128 = 1): light pools under the
        ceiling lights, stains, oil spots, tyre marks and the shadows of parked cars."""
        world = self.world
        res = 10.0 / _LOW  # m per low-map px (same as the per-frame low layer)
        xmin, ymin, xmax, ymax = world.bounds
        self._low_origin = np.array([xmin - 6.0, ymin - 6.0])
        W = int(math.ceil((xmax - xmin + 12.0) / res))
        H = int(math.ceil((ymax - ymin + 12.0) / res))

        def px(p: np.ndarray) -> np.ndarray:
            return (np.asarray(p) - self._low_origin) / res

        # ceiling lights along the aisles
        pitch = rng.uniform(4.5, 7.5)
        lights = []
        for a in world.aisles:
            a0, a1 = np.asarray(a.a, float), np.asarray(a.b, float)
            length = float(np.linalg.norm(a1 - a0))
            d = (a1 - a0) / max(length, 1e-9)
            offsets = (-1.5, 1.5) if rng.random() < 0.4 else (0.0,)
            for t in np.arange(rng.uniform(0, pitch), length, pitch):
                for o in offsets:
                    lights.append(a0 + d * t + o * np.array([-d[1], d[0]]))
        self._lights = np.array(lights, float).reshape(-1, 2)
        self._light_height = float(rng.uniform(2.4, 3.0))
        k = len(self._lights)  # each light's specular streak: half-width, length ratio, level
        self._light_streak = np.stack(
            [rng.uniform(0.8, 2.5, k), rng.uniform(1.5, 3.0, k), rng.uniform(70, 230, k)], axis=1
        )
        gain = np.full((H, W), 0.95, np.float32)
        sig = rng.uniform(1.6, 2.6) / res
        strength = rng.uniform(0.15, 0.4)
        gx, gy = np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)
        for q in px(self._lights):  # separable Gaussians, each on its own window
            x0, x1 = max(int(q[0] - 3 * sig), 0), min(int(q[0] + 3 * sig) + 1, W)
            y0, y1 = max(int(q[1] - 3 * sig), 0), min(int(q[1] + 3 * sig) + 1, H)
            if x1 > x0 and y1 > y0:
                ex = np.exp(-0.5 * ((gx[x0:x1] - q[0]) / sig) ** 2)
                ey = np.exp(-0.5 * ((gy[y0:y1] - q[1]) / sig) ** 2)
                gain[y0:y1, x0:x1] += strength * ey[:, None] * ex[None, :]
        dark = np.zeros((H, W), np.float32)
        area = (xmax - xmin) * (ymax - ymin)
        for _ in range(int(area * rng.uniform(0.04, 0.12))):
            kind = rng.choice(3, p=[0.55, 0.3, 0.15])  # oil spot, water stain, tyre arc
            q = px(np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)]))
            ang = rng.uniform(0, 180)
            s = rng.uniform(0.3, 1.0)
            centre = (int(q[0] * 16), int(q[1] * 16))
            if kind == 2:
                r = rng.uniform(2.0, 6.0) / res
                cv2.ellipse(
                    dark,
                    centre,
                    (int(r * 16), int(r * 16 * rng.uniform(0.3, 1.0))),
                    ang,
                    0,
                    rng.uniform(25, 60),
                    0.25 * s,
                    max(1, int(0.22 / res)),
                    cv2.LINE_AA,
                    4,
                )
            else:
                r = (rng.uniform(0.08, 0.45) if kind == 0 else rng.uniform(0.5, 2.2)) / res
                cv2.ellipse(
                    dark,
                    centre,
                    (max(int(r * 16), 8), max(int(r * 16 * rng.uniform(0.6, 1.0)), 8)),
                    ang,
                    0,
                    360,
                    (0.35 if kind == 0 else 0.12) * s,
                    -1,
                    cv2.LINE_AA,
                    4,
                )
        for fp in self._car_fp:
            cv2.fillPoly(dark, [np.round(px(fp) * 16).astype(np.int32)], 0.5, cv2.LINE_AA, 4)
        blurred = cv2.GaussianBlur(dark, (0, 0), 1.5)
        self._low_map = np.clip(gain * (1.0 - blurred) * 128.0, 0, 255).astype(np.uint8)
        self._low_res = res

    def _text_patch(self, label: str, rng: np.random.Generator) -> np.ndarray:
        """The label's glyphs as a tight uint8 alpha patch (a Hershey font)."""
        font = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_PLAIN)[
            int(rng.integers(3))
        ]
        scale = 3.0 if font == cv2.FONT_HERSHEY_PLAIN else 2.0
        thick = int(rng.integers(3, 6))
        (w, h), _ = cv2.getTextSize(label or " ", font, scale, thick)
        pad = thick + 2
        patch = np.zeros((h + 2 * pad, w + 2 * pad), np.uint8)
        cv2.putText(patch, label, (pad, pad + h), font, scale, 255, thick, cv2.LINE_AA)
        ys, xs = np.nonzero(patch > 40)
        if len(ys) == 0:
            return patch
        return patch[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]

    @staticmethod
    def _outlines(patch: np.ndarray) -> list[np.ndarray]:
        """Glyph contours (outer and holes) of a patch in box units: (x, y) with x in
        [0, 1] left to right and y in [0, 1] bottom to top."""
        ph, pw = patch.shape
        contours, _ = cv2.findContours(
            (patch > 127).astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE
        )
        out = []
        for cnt in contours:
            c = cv2.approxPolyDP(cnt, 0.6, True)[:, 0].astype(float)
            if len(c) >= 3:
                out.append(np.stack([(c[:, 0] + 0.5) / pw, 1.0 - (c[:, 1] + 0.5) / ph], axis=1))
        return out

    # ------------------------------------------------------------------ per frame

    def render(self, mTv: np.ndarray, seed: int) -> tuple[np.ndarray, TopviewAnnotation]:
        """The (size, size, 3) BGR uint8 top view at vehicle pose ``mTv`` (x, y, yaw in the
        map frame) and its labels; ``seed`` picks the per-frame variation."""
        mTv = np.asarray(mTv, dtype=float)
        rng = np.random.default_rng([self.world.seed, int(seed) & 0x7FFFFFFF, 77])
        P = self._world_to_pixel(mTv)
        S = self._floor_img.copy()
        self._draw_grates(S, P, mTv)
        self._draw_markings(S, P, mTv)
        self._draw_labels(S, P, mTv)
        S = self._modulate_floor(S, P)
        polys = self._draw_solids(S, P, mTv)
        img = self._camera_pipeline(S, mTv, rng)
        return img, self._annotate(P, mTv, polys)

    def source_spacing_m(self, uv: np.ndarray) -> np.ndarray:
        """Ground metres per sample of the camera image each top-view pixel is resampled
        from: the coarser of its radial and tangential spacing (radial: the fisheye's
        (H^2 + r^2) / H growth at distance r from the camera, tangential: r times the
        azimuth step). How sharp the floor can be there, before any blur.

        Args:
            uv: (N, 2) top-view pixels (u right, v down), rounded to the nearest.

        Returns:
            (N,) metres; NaN in the ego box and outside the image.
        """
        n = self.spec.size_px
        px = np.rint(np.asarray(uv, float).reshape(-1, 2)).astype(int)
        inside = ((px >= 0) & (px < n)).all(axis=1)
        out = np.full(len(px), np.nan)
        out[inside] = self._source_spacing[px[inside, 1], px[inside, 0]]
        return out

    def _world_to_pixel(self, mTv: np.ndarray) -> np.ndarray:
        """(3, 3) homogeneous map-frame metres -> top-view pixels."""
        spec = self.spec
        x, y, yaw = mTv
        cy, sy = math.cos(yaw), math.sin(yaw)
        vTm = np.array([[cy, sy, -(cy * x + sy * y)], [-sy, cy, sy * x - cy * y], [0, 0, 1]])
        s, c = spec.metres_per_px, spec.centre_px
        pTv = np.array([[0.0, -1.0 / s, c], [-1.0 / s, 0.0, c], [0, 0, 1]])
        return pTv @ vTm

    @staticmethod
    def _apply(P: np.ndarray, pts: np.ndarray) -> np.ndarray:
        return pts @ P[:2, :2].T + P[:2, 2]

    def _near(self, items: np.ndarray, mTv: np.ndarray, radius: float) -> np.ndarray:
        """Indices of (K, m, 2) world polygons whose bounding boxes come within ``radius``
        (metres, per axis) of the vehicle. The box, not the vertices: a line painted along
        a whole row has its vertices at the row's ends, far from a car beside its middle."""
        if len(items) == 0:
            return np.zeros(0, int)
        p = mTv[:2]
        gap = np.maximum(np.maximum(items.min(axis=1) - p, p - items.max(axis=1)), 0.0)
        return np.nonzero(gap.max(axis=1) < radius)[0]

    def _draw_markings(self, S: np.ndarray, P: np.ndarray, mTv: np.ndarray) -> None:
        idx = self._near(self._mark_quads, mTv, 30.0)
        if len(idx):
            px = self._apply(P, self._mark_quads[idx])
            lo, hi = px.min(axis=1), px.max(axis=1)
            n = self.spec.size_px
            keep = (hi > -2).all(axis=1) & (lo < n + 1).all(axis=1)
            # one fill per quad: a single fillPoly of all of them would leave the overlap
            # at every T / L junction unpainted (even-odd rule)
            for k, quad in zip(idx[keep], _fixed(px[keep]), strict=True):
                cv2.fillConvexPoly(S, quad, self._mark_bgr[k], cv2.LINE_AA, _SHIFT)

    def _draw_labels(self, S: np.ndarray, P: np.ndarray, mTv: np.ndarray) -> None:
        """All nearby labels as one antialiased even-odd fill of their glyph outlines."""
        n = self.spec.size_px
        polys: list[np.ndarray] = []
        for i in self._near(self._label_boxes, mTv, 8.0):
            box = self._apply(P, self._label_boxes[i])
            lo, hi = box.min(axis=0), box.max(axis=0)
            if hi[0] < 0 or hi[1] < 0 or lo[0] > n or lo[1] > n:
                continue
            # glyph outline (x, y) in units of the box: x along bottom edge, y up the left edge
            g = self._glyphs[i]
            o, ex, ey = box[0], box[1] - box[0], box[3] - box[0]
            polys.extend(_fixed(o + c[:, :1] * ex + c[:, 1:] * ey) for c in g)
        if polys:
            cv2.fillPoly(S, polys, self._paint_bgr, cv2.LINE_AA, _SHIFT)

    def _draw_grates(self, S: np.ndarray, P: np.ndarray, mTv: np.ndarray) -> None:
        for i in self._near(self._grates, mTv, 7.5):
            px = self._apply(P, self._grates[i])
            cv2.fillPoly(S, [_fixed(px)], (70, 72, 75), cv2.LINE_AA, _SHIFT)
            for k in range(1, 5):
                a = px[0] + (px[1] - px[0]) * k / 5
                b = px[3] + (px[2] - px[3]) * k / 5
                cv2.line(
                    S, tuple(_fixed(a)), tuple(_fixed(b)), (125, 127, 130), 2, cv2.LINE_AA, _SHIFT
                )

    def _modulate_floor(self, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Multiply by the world-anchored texture and low-resolution gain map."""
        n = self.spec.size_px
        Pinv = np.linalg.inv(P)  # pixel -> map metres
        half = n // 2
        D2 = np.array([[2.0, 0, 0.5], [0, 2.0, 0.5], [0, 0, 1]])  # half-res px -> full-res px
        M = (Pinv @ D2)[:2] / _TEX_M
        M[:, 2] %= _TEX
        tex = cv2.warpAffine(
            self._tex,
            M,
            (half, half),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_WRAP,
        )
        f = n / _LOW
        D4 = np.array([[f, 0, (f - 1) / 2], [0, f, (f - 1) / 2], [0, 0, 1]])
        Ml = (Pinv @ D4)[:2]
        Ml[:, 2] -= self._low_origin
        Ml /= self._low_res
        low = cv2.warpAffine(
            self._low_map,
            Ml,
            (_LOW, _LOW),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=122,
        )
        low = cv2.multiply(low, self._ego_shadow, scale=1.0 / 255.0)
        low = cv2.resize(low, (half, half), interpolation=cv2.INTER_LINEAR)
        gain = cv2.resize(
            cv2.multiply(tex, low, scale=1.0 / 128.0), (n, n), interpolation=cv2.INTER_LINEAR
        )
        return cv2.multiply(S, cv2.cvtColor(gain, cv2.COLOR_GRAY2BGR), scale=1.0 / 128.0)

    # ------------------------------------------------------------------ tall things

    def _draw_solids(self, S: np.ndarray, P: np.ndarray, mTv: np.ndarray) -> list[np.ndarray]:
        """Draw cars, pillars and walls stretched away from each camera, clipped to its
        region. Returns the drawn pixel polygons (for the occlusion flags)."""
        spec = self.spec
        n = spec.size_px
        solids = []  # (footprint (k, 2) pixels, bands [(h0, h1, bgr)], floor colour)

        def visible(fp: np.ndarray) -> bool:
            lo, hi = fp.min(axis=0), fp.max(axis=0)
            return bool(hi[0] > -2 and hi[1] > -2 and lo[0] < n + 1 and lo[1] < n + 1)

        for i in self._near(self._car_fp, mTv, 8.0):
            fp = self._apply(P, self._car_fp[i])
            if visible(fp):
                solids.append((fp, self._car_bands[i], (18.0, 18.0, 20.0)))
        for i in self._near(self._pillar_fp, mTv, 8.0):
            fp = self._apply(P, self._pillar_fp[i])
            if visible(fp):
                solids.append((fp, self._pillar_bands, (150.0, 150.0, 150.0)))
        for w in self.world.walls:
            seg = clip_segment(*self._apply(P, np.array([w.a, w.b], float)), -30.0, n + 30.0)
            if seg is not None:
                a, b = seg
                d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
                nrm = np.array([-d[1], d[0]]) * (0.1 / spec.metres_per_px)
                bands = [
                    (0.0, 0.15, (70.0, 75.0, 80.0)),
                    (0.15, 0.45, self._wall_stripe),
                    (0.45, 5.0, (175.0, 178.0, 180.0)),
                ]
                solids.append(
                    (np.array([a - nrm, b - nrm, b + nrm, a + nrm]), bands, (160.0, 160.0, 160.0))
                )
        drawn: list[np.ndarray] = []
        if not solids:
            return drawn
        fps = np.stack([fp for fp, _, _ in solids])  # (N, 4, 2) pixels
        for name, cam in self._cams.items():
            region = self._regions[name]
            cx, cy = (float(v) for v in spec.vehicle_to_pixel(cam.position)[0])
            cpx = np.array([cx, cy])
            planes = self._planes[name]  # (E, 3): inside where a*u + b*v + c >= 0
            wedges = np.concatenate([fps, cpx + (fps - cpx) * _FMAX], axis=1)  # (N, 8, 2)
            side = wedges @ planes[:, :2].T + planes[:, 2]
            # skip solids whose whole wedge lies outside one edge of this camera's region
            seen = ~(side < 0).all(axis=1).any(axis=1)
            dist = np.hypot(fps[..., 0] - cx, fps[..., 1] - cy).min(axis=1)
            for j in np.argsort(dist)[::-1]:  # far to near: nearer things cover farther
                if not seen[j]:
                    continue
                fp, bands, top = solids[j]
                fs = [
                    (self._stretch(cam.height, h0), self._stretch(cam.height, h1), colour)
                    for h0, h1, colour in bands
                    if h0 < cam.height * 0.98
                ]
                quads, colours = [fp], [top]
                area = _area2(fp)
                for e in range(len(fp)):
                    p, q = fp[e], fp[(e + 1) % len(fp)]
                    # a face is seen when the camera is on its outer side
                    if ((q[0] - p[0]) * (cy - p[1]) - (q[1] - p[1]) * (cx - p[0])) * area >= 0:
                        continue
                    dp, dq = p - cpx, q - cpx
                    for f0, f1, colour in fs:
                        quads.append(
                            np.array([cpx + dp * f0, cpx + dq * f0, cpx + dq * f1, cpx + dp * f1])
                        )
                        colours.append(colour)
                Q = np.stack(quads)  # (K, 4, 2)
                sides = Q @ planes[:, :2].T + planes[:, 2]  # (K, 4, E)
                inside = (sides >= 0).all(axis=(1, 2))
                outside = (sides < 0).all(axis=1).any(axis=1)
                for k in range(len(Q)):
                    if outside[k]:
                        continue
                    if inside[k]:
                        arr = Q[k].astype(np.float32)
                    else:
                        clipped = _clip_convex([(float(u), float(v)) for u, v in Q[k]], region)
                        if len(clipped) < 3:
                            continue
                        arr = np.array(clipped, np.float32)
                    cv2.fillPoly(S, [_fixed(arr)], colours[k], cv2.LINE_AA, _SHIFT)
                    drawn.append(arr)
        return drawn

    @staticmethod
    def _stretch(H: float, h: float) -> float:
        return _FMAX if h >= H * (1.0 - 1.0 / _FMAX) else H / (H - h)

    def _camera_pipeline(
        self, S: np.ndarray, mTv: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        A = cv2.remap(
            S, self._fwd[0], self._fwd[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )
        rows, cols = self._atlas_shape
        temp, glob = rng.normal(0.0, 0.04), rng.uniform(0.8, 1.15)
        for cam in self._cams.values():  # per-camera gain and colour cast
            g = (
                glob
                * (1.0 + rng.normal(0.0, 0.07))
                * (1.0 + np.array([temp, 0.0, -temp]) + rng.normal(0.0, 0.02, 3))
            )
            blk = A[cam.row0 : cam.row0 + len(cam.rho) + 2]
            gain4 = (float(g[0]), float(g[1]), float(g[2]), 0.0)
            cv2.multiply(blk, gain4, dst=blk)  # type: ignore[call-overload]
        A = cv2.multiply(A, self._vignette, scale=1.0 / 255.0)
        # specular streaks of the ceiling lights, drawn in polar space at quarter size
        # (vertical = radial): a light at height L mirrors at c + (l - c) * H / (H + L)
        sl = np.zeros((rows // 4 + 1, cols // 4 + 1), np.uint8)
        near = np.abs(self._lights - mTv[:2]).max(axis=1) < 14.0
        lights, streak = self._lights[near], self._light_streak[near]
        if len(lights):
            P = self._world_to_pixel(mTv)
            lv = self.spec.pixel_to_vehicle(self._apply(P, lights))
            for cam in self._cams.values():
                rel = (lv - cam.position) * (cam.height / (cam.height + self._light_height))
                dist = np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 0.7)  # not at the lens
                idx = np.arange(len(cam.rho))
                r_in = np.interp(dist, cam.rho, idx, right=1e9)
                r_out = np.interp(dist * streak[:, 1], cam.rho, idx, right=len(cam.rho) + 40)
                ph = np.mod(np.arctan2(rel[:, 1], rel[:, 0]) - cam.phi0, 2 * np.pi)
                for r0, r1, p, (hw, _, val) in zip(r_in, r_out, ph, streak, strict=True):
                    col = p / _DPHI
                    if 0 <= col < cols and r0 < len(cam.rho) - 2:
                        # from the mirror point outward, in quarter-size atlas units
                        hl = max((r1 - r0) / 2.0, 3.0) * 4.0
                        cv2.ellipse(
                            sl,
                            (int(col * 4), int((cam.row0 + (r0 + r1) / 2) * 4)),
                            (int(hw * 16), int(hl)),
                            0,
                            0,
                            360,
                            int(val),
                            -1,
                            cv2.LINE_AA,
                            4,
                        )
        if rng.random() < 0.15:  # occasional strong glare
            cam = self._cams[_CAMS[int(rng.integers(4))]]
            cv2.ellipse(
                sl,
                (
                    int(rng.uniform(0, cols) * 4),
                    int((cam.row0 + rng.uniform(0.2, 0.9) * len(cam.rho)) * 4),
                ),
                (int(rng.uniform(2.5, 8) * 16), int(rng.uniform(8, 20) * 16)),
                0,
                0,
                360,
                255,
                -1,
                cv2.LINE_AA,
                4,
            )
        sl = cv2.GaussianBlur(sl, (0, 0), sigmaX=0.8, sigmaY=2.0)
        sl = cv2.resize(sl, (cols, rows), interpolation=cv2.INTER_LINEAR)
        A = cv2.scaleAdd(cv2.cvtColor(sl, cv2.COLOR_GRAY2BGR), float(rng.uniform(0.3, 0.7)), A)
        # radial smear (vertical in the atlas), a little tangential blur
        A = cv2.blur(A, (int(rng.integers(1, 3)), int(rng.integers(1, 4))))
        # sensor noise (a random window of a fixed bank) and contrast in one pass
        nr, nc = self._noise.shape[:2]
        oy, ox = int(rng.integers(0, nr - rows)), int(rng.integers(0, nc - cols))
        con, ns = float(rng.uniform(0.85, 1.2)), float(rng.uniform(0.05, 0.2))
        A = cv2.addWeighted(
            A,
            con,
            self._noise[oy : oy + rows, ox : ox + cols],
            ns,
            128.0 * (1.0 - con) - 128.0 * ns,
        )
        img = cv2.remap(A, self._back[0], self._back[1], cv2.INTER_LINEAR)
        v0, v1, u0, u1 = self._ego
        img[v0:v1, u0:u1] = 0
        quality = int(rng.integers(60, 92))
        if self.jpeg:
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
            img = np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR))
            img[v0:v1, u0:u1] = 0
        return img

    # ------------------------------------------------------------------ labels

    def _annotate(
        self, P: np.ndarray, mTv: np.ndarray, polys: list[np.ndarray]
    ) -> TopviewAnnotation:
        n = self.spec.size_px
        v0, v1, u0, u1 = self._ego
        q = self._apply(P, self._pts) if len(self._pts) else np.zeros((0, 2))
        inside = (q[:, 0] >= 0) & (q[:, 0] <= n - 1) & (q[:, 1] >= 0) & (q[:, 1] <= n - 1)
        in_ego = (
            (q[:, 0] >= u0 - 0.5)
            & (q[:, 0] <= u1 - 0.5)
            & (q[:, 1] >= v0 - 0.5)
            & (q[:, 1] <= v1 - 0.5)
        )
        sel = np.nonzero(inside & ~in_ego)[0]
        points = q[sel]
        a = self._pt_dir[sel] - mTv[2]  # direction in the vehicle frame
        # image u = -y_v, v = -x_v  =>  atan2(dv, du) = atan2(-cos a, -sin a)
        directions = np.arctan2(-np.cos(a), -np.sin(a))
        occluded = _covered(points, polys)
        index = np.full(len(self._pts) + 1, 0, int)  # world point -> 1-based annotation index
        index[sel] = np.arange(1, len(sel) + 1)
        ij = index[self._slot_pts]  # (-1 maps to the last entry, which stays 0)
        code = {SlotKind.PERPENDICULAR: 1, SlotKind.PARALLEL: 2, SlotKind.SLANTED: 3}
        slots = []
        for k in np.nonzero((ij[:, 0] > 0) & (ij[:, 1] > 0))[0]:
            slot = self.world.slots[k]
            angle = 90
            if slot.kind is SlotKind.SLANTED:
                cn = np.asarray(slot.corners, float)
                e, sep = cn[1] - cn[0], cn[3] - cn[0]
                cosang = np.dot(e, sep) / (np.linalg.norm(e) * np.linalg.norm(sep))
                angle = int(round(math.degrees(math.acos(float(np.clip(cosang, -1.0, 1.0))))))
            slots.append([int(ij[k, 0]), int(ij[k, 1]), code[slot.kind], angle])
        ids = []
        for i in self._near(self._label_boxes, mTv, 8.0):
            box = self._apply(P, self._label_boxes[i])
            if box.min() < 0 or box.max() > n - 1:
                continue
            (bx0, by0), (bx1, by1) = box.min(axis=0), box.max(axis=0)
            if bx1 >= u0 - 0.5 and bx0 <= u1 - 0.5 and by1 >= v0 - 0.5 and by0 <= v1 - 0.5:
                continue  # touches the ego box (conservative: its bounding box)
            if _covered(np.vstack([box, box.mean(axis=0)]), polys).any():
                continue  # a car, pillar or wall drawn over part of it
            slot_id, label, _ = self._labels[i]
            ids.append((slot_id, label, box))
        return TopviewAnnotation(
            points,
            directions,
            self._pt_shape[sel].copy(),
            occluded,
            np.array(slots, int).reshape(-1, 4),
            tuple(ids),
        )


_CACHE: dict[tuple[int, TopviewSpec], TopviewRenderer] = {}


def render_topview(
    world: World, mTv: np.ndarray, seed: int, spec: TopviewSpec | None = None
) -> tuple[np.ndarray, TopviewAnnotation]:
    """Render the BGR uint8 top view of ``world`` at vehicle pose ``mTv`` (map frame).

    A thin wrapper over :class:`TopviewRenderer` that keeps a few renderers (by world).
    """
    spec = spec or TopviewSpec()
    key = (id(world), spec)
    r = _CACHE.get(key)
    if r is None or r.world is not world:
        if len(_CACHE) >= 4:
            _CACHE.clear()
        r = _CACHE[key] = TopviewRenderer(world, spec)
    return r.render(mTv, seed)


__all__ = ["TopviewAnnotation", "TopviewRenderer", "render_topview"]
