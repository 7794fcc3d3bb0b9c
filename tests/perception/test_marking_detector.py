"""Painted-line detector (Houben): synthetic bars with known answers, the mask path, a
rendered top view, the presegmentation, bad input and determinism."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from semslam.errors import SemslamError
from semslam.geometry import inverse_transform_points
from semslam.perception.markings import (
    FULL_SIZE,
    TUNED,
    MarkingDetector,
    MarkingInputError,
    MarkingParams,
)
from semslam.rig import TopviewSpec
from semslam.simulation.render_topview import TopviewRenderer
from semslam.simulation.world import make_world

SPEC = TopviewSpec()


def floor(seed: int = 0, size: int = 600) -> np.ndarray:
    """A gray-beige floor with smooth shading and pixel noise, BGR."""
    rng = np.random.default_rng(seed)
    shade = cv2.resize(rng.normal(0, 8, (6, 6)), (size, size), interpolation=cv2.INTER_CUBIC)
    g = 120 + shade[..., None] + rng.normal(0, 4, (size, size, 1))
    img = np.clip(g + np.array([-6.0, 0.0, 4.0]), 0, 255).astype(np.uint8)
    return img


def paint(img: np.ndarray, a, b, width: float, spec: TopviewSpec = SPEC, colour=(230, 230, 230)):
    """Draw a painted line from a to b (vehicle frame, m) of ``width`` m."""
    pa, pb = spec.vehicle_to_pixel(np.array([a, b], float))
    d = (pb - pa) / np.linalg.norm(pb - pa)
    # OpenCV's antialiased fill spreads about half a pixel beyond the polygon
    n = np.array([-d[1], d[0]]) * (width / spec.metres_per_px / 2.0 - 0.5)
    quad = np.array([pa - n, pb - n, pb + n, pa + n])
    cv2.fillPoly(img, [np.round(quad * 16).astype(np.int32)], colour, cv2.LINE_AA, 4)


def angle_between(u, v) -> float:
    c = abs(float(np.dot(u, v))) / (np.linalg.norm(u) * np.linalg.norm(v))
    return math.degrees(math.acos(min(1.0, c)))


def end_error(obs, a, b) -> float:
    """Largest end-point distance (m), whichever way round the detection runs."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    e1 = max(np.linalg.norm(obs.vA - a), np.linalg.norm(obs.vB - b))
    e2 = max(np.linalg.norm(obs.vA - b), np.linalg.norm(obs.vB - a))
    return min(e1, e2)


def test_two_painted_lines_give_two_segments():
    img = floor()
    lines = [((3.0, -3.5), (3.0, 0.5), 0.15), ((-1.0, 2.0), (-4.0, 3.5), 0.12)]
    for a, b, w in lines:
        paint(img, a, b, w)
    obs = MarkingDetector().detect(img, SPEC)
    assert len(obs) == 2
    for a, b, w in lines:
        best = min(obs, key=lambda o: end_error(o, a, b))
        assert end_error(best, a, b) <= 0.03
        assert angle_between(best.vB - best.vA, np.subtract(b, a)) <= 2.0
        assert abs(best.width - w) <= 0.03
        assert 0.0 <= best.confidence <= 1.0


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, 90.0, 125.0])
def test_single_bar_width_and_angle(angle_deg):
    img = floor(1)
    t = math.radians(angle_deg)
    c, u = np.array([0.0, 3.2]), np.array([math.cos(t), math.sin(t)])
    a, b = c - 1.2 * u, c + 1.2 * u
    paint(img, a, b, 0.18)
    # the default works at 30 px per metre (3.3 cm pixels): widths to 2.5 cm, not 2
    for params, width_tol in ((TUNED, 0.025), (FULL_SIZE, 0.02)):
        obs = MarkingDetector(params).detect(img, SPEC)
        assert len(obs) == 1
        assert angle_between(obs[0].vB - obs[0].vA, u) <= 1.0
        assert abs(obs[0].width - 0.18) <= width_tol
        assert end_error(obs[0], a, b) <= 0.04


def test_yellow_line_on_green_floor():
    img = floor(2)
    img[:] = np.clip(img.astype(int) + np.array([-10, 25, -20]), 0, 255).astype(np.uint8)
    paint(img, (-3.0, -2.5), (3.0, -2.5), 0.12, colour=(40, 200, 230))
    obs = MarkingDetector().detect(img, SPEC)
    assert len(obs) == 1
    assert end_error(obs[0], (-3.0, -2.5), (3.0, -2.5)) <= 0.04


@pytest.mark.parametrize("value", [0, 128, 255])
def test_flat_images_give_nothing(value):
    img = np.full((600, 600, 3), value, np.uint8)
    assert MarkingDetector().detect(img, SPEC) == ()
    assert MarkingDetector().detect(img[:, :, 0].copy(), SPEC) == ()


def test_noise_gives_nothing_confident():
    img = floor(3)
    assert MarkingDetector().detect(img, SPEC) == ()


@pytest.mark.parametrize(
    "image, fragment",
    [
        (np.zeros((600, 600), np.float32), "dtype uint8"),
        (np.zeros((600, 600, 4), np.uint8), "shape (H, W) or (H, W, 3)"),
        (np.zeros((500, 500), np.uint8), "600 x 600"),
        (np.zeros(600, np.uint8), "shape"),
        ([[0, 1], [2, 3]], "numpy array"),
    ],
)
def test_bad_images_are_refused_in_one_line(image, fragment):
    with pytest.raises(MarkingInputError) as err:
        MarkingDetector().detect(image, SPEC)
    msg = str(err.value)
    assert fragment in msg and "\n" not in msg
    assert isinstance(err.value, ValueError) and isinstance(err.value, SemslamError)


def test_bad_masks_and_priors_are_refused():
    det = MarkingDetector()
    with pytest.raises(ValueError, match="2-D"):
        det.detect_mask(np.zeros((100, 100, 3), np.uint8), 0.01, (50, 50))
    with pytest.raises(ValueError, match="bool or integer"):
        det.detect_mask(np.zeros((100, 100), np.float64), 0.01, (50, 50))
    with pytest.raises(ValueError, match="metres_per_pixel"):
        det.detect_mask(np.zeros((100, 100), bool), 0.0, (50, 50))
    with pytest.raises(ValueError, match="prior_segments"):
        det.detect(floor(), SPEC, prior_segments=np.zeros((3, 4)))
    with pytest.raises(ValueError, match="unknown field"):
        MarkingParams.from_dict({"grad_min": 3.0, "nonsense": 1})
    with pytest.raises(ValueError, match="weights"):
        MarkingParams(weights=(1.0, 2.0))


def test_params_round_trip():
    assert MarkingParams.from_dict(TUNED.to_dict()) == TUNED
    assert MarkingParams.from_dict(FULL_SIZE.to_dict()) == FULL_SIZE
    with pytest.raises(ValueError, match="work_px_per_m"):
        MarkingParams(work_px_per_m=0.0)
    assert TUNED.shrink_factor(SPEC.metres_per_px) == 2  # 60 px per metre -> 30
    assert FULL_SIZE.shrink_factor(SPEC.metres_per_px) == 1
    assert TUNED.shrink_factor(0.03) == 1 and TUNED.shrink_factor(0.01) == 3


def test_shrunk_view_gives_lines_in_the_views_pixels():
    """The default settings work on the view shrunk twice; the lines come back in the
    view's own pixels and agree with the full-size settings' lines."""
    img = floor(6)
    a, b = np.array([4.0, -2.0]), np.array([1.5, 2.5])
    paint(img, a, b, 0.15)
    small = MarkingDetector(TUNED).detect_lines(img, SPEC)
    full = MarkingDetector(FULL_SIZE).detect_lines(img, SPEC)
    assert len(small.a) == len(full.a) == 1
    assert small.metres_per_px == full.metres_per_px == SPEC.metres_per_px
    assert small.centre_px == full.centre_px
    ends = sorted(np.vstack([small.a, small.b]).tolist())
    ends_full = sorted(np.vstack([full.a, full.b]).tolist())
    assert np.abs(np.subtract(ends, ends_full)).max() <= 2.0  # px of the view
    assert abs(small.width_px[0] - full.width_px[0]) <= 1.5
    (obs,) = small.observations()
    assert end_error(obs, a, b) <= 0.04


def test_presegmentation_keeps_only_lines_near_the_prior():
    img = floor(4)
    paint(img, (3.0, -3.5), (3.0, 0.5), 0.15)
    paint(img, (-3.0, 1.5), (-3.0, 4.0), 0.15)
    det = MarkingDetector()
    assert len(det.detect(img, SPEC)) == 2
    prior = np.array([[[3.05, -3.0], [3.05, 0.0]]])  # the first line, 5 cm off
    obs = det.detect(img, SPEC, prior_segments=prior)
    assert len(obs) == 1 and abs(obs[0].vA[0] - 3.0) < 0.03
    assert det.detect(img, SPEC, prior_segments=np.zeros((0, 2, 2))) == ()



def test_a_prior_a_kilometre_long_is_cut_to_the_view_not_bent():
    img = floor(4)
    paint(img, (1.0, -3.5), (4.0, -0.5), 0.15)  # a diagonal line
    det = MarkingDetector()
    d = np.array([1.0, 1.0]) / np.sqrt(2.0)
    long_prior = np.array([[np.array([1.0, -3.5]) - 700 * d, np.array([4.0, -0.5]) + 700 * d]])
    (obs,) = det.detect(img, SPEC, prior_segments=long_prior)
    assert np.hypot(*(obs.vB - obs.vA)) > 3.5


def test_mask_path_in_the_vehicle_frame():
    # 1 cm/px mask like the real garage drive: vehicle at (W/2, H/2), x forward = up
    H, W, mpp = 1200, 900, 0.01
    mask = np.zeros((H, W), np.uint8)
    # a line 2 m ahead across the car (y from +2 to -2 m), 12 cm wide
    v = int(H / 2 - 2.0 / mpp)
    mask[v - 6 : v + 6, int(W / 2 - 2.0 / mpp) : int(W / 2 + 2.0 / mpp)] = 1
    # a line 3 m to the right along x from -4 to +1 m, 10 cm wide
    u = int(W / 2 + 3.0 / mpp)
    mask[int(H / 2 - 1.0 / mpp) : int(H / 2 + 4.0 / mpp), u - 5 : u + 5] = 1
    # a filled blob (a segmentation error): too wide to be a line
    mask[50:250, 550:850] = 1
    obs = MarkingDetector().detect_mask(mask.astype(bool), mpp, (W / 2, H / 2))
    assert len(obs) == 2
    across = min(obs, key=lambda o: abs(o.vA[0] - 2.0))
    assert end_error(across, (2.0, 2.0), (2.0, -2.0)) <= 0.05
    assert abs(across.width - 0.12) <= 0.03
    along = min(obs, key=lambda o: abs(o.vA[1] + 3.0))
    assert end_error(along, (1.0, -3.0), (-4.0, -3.0)) <= 0.05


def test_mask_of_nothing_gives_nothing():
    assert MarkingDetector().detect_mask(np.zeros((300, 300), bool), 0.01, (150, 150)) == ()


def test_deterministic():
    img = floor(5)
    paint(img, (2.0, -3.0), (4.0, 1.0), 0.14)
    det = MarkingDetector()
    o1, o2 = det.detect(img, SPEC), MarkingDetector().detect(img.copy(), SPEC)
    assert len(o1) == len(o2) >= 1
    for p, q in zip(o1, o2, strict=True):
        assert np.array_equal(p.vA, q.vA) and np.array_equal(p.vB, q.vB)
        assert p.width == q.width and p.confidence == q.confidence


def test_rendered_top_view():
    """On a simulated view, confident detections lie on true markings (5 deg, 10 cm)."""
    world = make_world("small", 3)
    mTv = np.array([20.0, world.aisles[0].a[1] + 0.3, 0.05])
    img, _ = TopviewRenderer(world, SPEC).render(mTv, 11)
    obs = MarkingDetector().detect(img, SPEC)
    assert len(obs) >= 3
    A = inverse_transform_points(mTv, np.array([m.a for m in world.markings]))
    B = inverse_transform_points(mTv, np.array([m.b for m in world.markings]))

    def on_truth(o) -> bool:
        d = B - A
        ok = []
        for p in (o.vA, o.vB):
            t = np.clip(np.einsum("ij,ij->i", p - A, d) / np.einsum("ij,ij->i", d, d), 0, 1)
            ok.append(np.linalg.norm(A + t[:, None] * d - p, axis=1) <= 0.10)
        u = (o.vB - o.vA) / np.linalg.norm(o.vB - o.vA)
        cosang = np.abs(d @ u) / np.linalg.norm(d, axis=1)
        return bool((ok[0] & ok[1] & (cosang >= math.cos(math.radians(5.0)))).any())

    correct = sum(on_truth(o) for o in obs)
    assert correct >= 0.8 * len(obs)


def test_line_ends_run_on_through_points_no_segment_took():
    """Stage 6b on hand-made points: the end follows free points on its axis until the
    first gap wider than link_radius_px; off-axis or crossing points do not move it."""
    from semslam.perception.markings.segments import _extend_ends

    p = FULL_SIZE  # link_radius_px 4.28, trim_px 2.24
    cen, dirs = np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]])
    tlo, thi = np.array([-10.0]), np.array([10.0])
    free = np.array(
        [
            [12.0, 0.3], [15.0, -0.2], [18.5, 0.0],  # a chain past the far end
            [30.0, 0.0],  # beyond a gap of 11.5 px: not taken
            [-12.0, 3.0],  # off the axis
            [-13.0, 0.0],  # on the axis, but crossing (orientation 90 deg)
        ]
    )
    angle = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 90.0])
    st = {"c2": np.cos(np.radians(2 * angle)), "s2": np.sin(np.radians(2 * angle))}
    lo, hi = _extend_ends(free, st, cen, dirs, tlo, thi, p)
    assert hi[0] == pytest.approx(18.5) and lo[0] == pytest.approx(-10.0)
    lo, hi = _extend_ends(np.zeros((0, 2)), {"c2": np.zeros(0), "s2": np.zeros(0)},
                          cen, dirs, tlo, thi, p)
    assert (lo[0], hi[0]) == (-10.0, 10.0)
