"""The fisheye top view: one remap table from the rig, checked end to end on simulated images."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from semslam.errors import PerceptionError
from semslam.io import rig_from_dict, rig_to_dict
from semslam.perception.topview import DEFAULT_CAMERAS, TopviewBuilder
from semslam.rig import (
    CameraModel,
    default_fisheye_cameras,
    default_rig,
    fisheye_project,
    fisheye_unproject,
    surround_rig,
)
from semslam.simulation.render_fisheye import render_fisheye_rig
from semslam.simulation.topview_samples import random_aisle_pose
from semslam.simulation.world import make_world


@pytest.fixture(scope="module")
def builder() -> TopviewBuilder:
    return TopviewBuilder(surround_rig())


@pytest.fixture(scope="module")
def scene(builder: TopviewBuilder):
    """A small world, two poses on its aisle, and the top views built from the four
    rendered fisheye images (no tall things, so every painted line is visible)."""
    world = make_world("small", 1)
    rng = np.random.default_rng(5)
    rig = surround_rig()
    cams = [rig.cameras[n] for n in builder.cameras]
    out = []
    for k in range(2):
        mTv = random_aisle_pose(world, rng)
        images = render_fisheye_rig(world, mTv, 11 + k, cams, solids=False)
        out.append((mTv, builder.build(images)))
    return world, out


def _to_vehicle(mTv: np.ndarray, mP: np.ndarray) -> np.ndarray:
    c, s = math.cos(mTv[2]), math.sin(mTv[2])
    d = np.asarray(mP, float) - mTv[:2]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def _paint_mask(world, mTv: np.ndarray, builder: TopviewBuilder) -> np.ndarray:
    """The painted lines rasterised on the top-view grid from the true world."""
    n = builder.spec.size_px
    mask = np.zeros((n, n), np.uint8)
    for m in world.markings:
        a, b = np.asarray(m.a, float), np.asarray(m.b, float)
        t = (b - a) / np.linalg.norm(b - a)
        nrm = np.array([-t[1], t[0]]) * m.width / 2.0
        quad = _to_vehicle(mTv, np.array([a - nrm, b - nrm, b + nrm, a + nrm]))
        px = builder.spec.vehicle_to_pixel(quad)
        if np.abs(px - n / 2).max() < 3 * n:
            cv2.fillConvexPoly(mask, np.round(px * 16).astype(np.int32), 255, cv2.LINE_8, 4)
    return mask > 0


def test_painted_lines_land_on_paint(scene, builder: TopviewBuilder) -> None:
    """The true line mask matches the built image's paint best unshifted (within 1 px),
    with a clear contrast to the floor just beside the lines."""
    world, views = scene
    seen = builder.camera_index >= 0
    for mTv, top in views:
        lum = (top[..., 1].astype(float) + top[..., 2]) / 2.0  # (R + G) / 2: white or yellow
        mask = _paint_mask(world, mTv, builder)
        on = mask & seen
        assert on.sum() > 2000  # enough paint in view to mean something
        near = cv2.dilate(mask.astype(np.uint8), np.ones((17, 17), np.uint8)) > 0
        ring = near & ~(cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0) & seen
        assert lum[on].mean() - lum[ring].mean() > 40.0
        r = 4
        scores = np.zeros((2 * r + 1, 2 * r + 1))
        ys, xs = np.nonzero(on)
        n = builder.spec.size_px
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                scores[dy + r, dx + r] = lum[
                    np.clip(ys + dy, 0, n - 1), np.clip(xs + dx, 0, n - 1)
                ].mean()
        dy, dx = np.unravel_index(np.argmax(scores), scores.shape)
        assert abs(dy - r) <= 1 and abs(dx - r) <= 1, scores.round(1)


def test_marking_points_are_on_paint(scene, builder: TopviewBuilder) -> None:
    """Every entrance junction in view is on paint: brighter than the floor around it."""
    world, views = scene
    pts = np.array([mp.position for mp in world.marking_points], float)
    count = 0
    for mTv, top in views:
        lum = (top[..., 1].astype(float) + top[..., 2]) / 2.0
        mask = _paint_mask(world, mTv, builder)
        floor = builder.camera_index >= 0
        floor &= ~(cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0)
        px = builder.spec.vehicle_to_pixel(_to_vehicle(mTv, pts))
        ok = (px >= 3).all(axis=1) & (px <= builder.spec.size_px - 4).all(axis=1)
        for u, v in np.round(px[ok]).astype(int):
            if builder.camera_index[v, u] < 0:
                continue
            count += 1
            spot = lum[v - 1 : v + 2, u - 1 : u + 2].mean()
            win = np.s_[max(v - 20, 0) : v + 21, max(u - 20, 0) : u + 21]
            around = np.median(lum[win][floor[win]])
            assert spot > around + 25.0, (u, v, spot, around)
    assert count >= 6


def test_table_matches_opencv_projection(builder: TopviewBuilder) -> None:
    """Where the table takes a pixel from a camera looking at it from the front
    (< 90 deg), OpenCV's own fisheye projection of the ground point agrees."""
    rig = surround_rig()
    rng = np.random.default_rng(0)
    n = builder.spec.size_px
    uv = rng.integers(0, n, (400, 2))
    checked = 0
    for u, v in uv:
        i = int(builder.camera_index[v, u])
        if i < 0:
            continue
        cam = rig.cameras[builder.cameras[i]]
        vP = np.append(builder.spec.pixel_to_vehicle([[u, v]])[0], 0.0)
        np.testing.assert_allclose(builder.ground[v, u], vP[:2])
        T_cv = np.linalg.inv(cam.T_vehicle_camera)
        cP = T_cv[:3, :3] @ vP + T_cv[:3, 3]
        if cP[2] <= 0.05:
            continue
        ref, _ = cv2.fisheye.projectPoints(
            cP.reshape(1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D
        )
        np.testing.assert_allclose(builder.camera_pixels[v, u], ref.ravel(), atol=1e-3)
        checked += 1
    assert checked > 200


def test_a_spot_in_one_camera_lands_on_its_ground_point(builder: TopviewBuilder) -> None:
    rig = surround_rig()
    vP = np.array([3.2, -1.4])  # ahead and right of the car
    u0, v0 = builder.spec.vehicle_to_pixel(vP)[0]
    cam = rig.cameras[builder.cameras[builder.camera_index[round(v0), round(u0)]]]
    T_cv = np.linalg.inv(cam.T_vehicle_camera)
    cP = T_cv[:3, :3] @ np.append(vP, 0.0) + T_cv[:3, 3]
    cu, cv = fisheye_project(cam, cP)[0][0]
    images = {
        n: np.zeros((c.size[1], c.size[0], 3), np.uint8)
        for n, c in ((n, rig.cameras[n]) for n in builder.cameras)
    }
    cv2.circle(
        images[cam.name], (round(cu * 16), round(cv * 16)), 24, (255, 255, 255), -1, cv2.LINE_AA, 4
    )
    top = builder.build(images)
    w = top[..., 0].astype(float)
    assert w.max() > 200
    ys, xs = np.nonzero(w > 0.5 * w.max())
    wt = w[ys, xs]
    centre = np.array([np.average(xs, weights=wt), np.average(ys, weights=wt)])
    assert np.hypot(*(centre - (u0, v0))) < 1.0


def test_ego_box_is_black_and_everything_else_is_seen(builder: TopviewBuilder) -> None:
    spec = builder.spec
    g = builder.ground
    ego = (np.abs(g[..., 0]) <= spec.ego_length_m / 2) & (np.abs(g[..., 1]) <= spec.ego_width_m / 2)
    assert (builder.camera_index[ego] == -1).all()
    assert (builder.camera_index[~ego] >= 0).all()  # the four fisheyes cover the whole view
    assert set(np.unique(builder.camera_index[~ego])) == {0, 1, 2, 3}
    rig = surround_rig()
    images = {
        n: np.full((rig.cameras[n].size[1], rig.cameras[n].size[0], 3), 200, np.uint8)
        for n in builder.cameras
    }
    top = builder.build(images)
    assert top.shape == (600, 600, 3) and top.dtype == np.uint8
    assert (top[ego] == 0).all() and (top[~ego] == 200).all()


def _images(builder: TopviewBuilder) -> dict[str, np.ndarray]:
    rig = surround_rig()
    return {
        n: np.zeros((rig.cameras[n].size[1], rig.cameras[n].size[0], 3), np.uint8)
        for n in builder.cameras
    }


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.pop("fisheye_left"), r"^top view: no image for camera 'fisheye_left'$"),
        (
            lambda d: d.update(fisheye_rear=np.zeros((640, 960), np.uint8)),
            r"^top view: camera 'fisheye_rear' image must be \(640, 960, 3\) uint8, "
            r"got \(640, 960\) uint8$",
        ),
        (
            lambda d: d.update(fisheye_front=np.zeros((640, 960, 3), np.float32)),
            r"camera 'fisheye_front' image must be .* got \(640, 960, 3\) float32$",
        ),
        (
            lambda d: d.update(fisheye_right=np.zeros((320, 480, 3), np.uint8)),
            r"camera 'fisheye_right' image must be \(640, 960, 3\) uint8",
        ),
        (lambda d: d.update(fisheye_right=[[0]]), r"camera 'fisheye_right' .* got list$"),
    ],
)
def test_build_refuses_bad_images(builder: TopviewBuilder, mutate, message: str) -> None:
    images = _images(builder)
    mutate(images)
    with pytest.raises(PerceptionError, match=message):
        builder.build(images)


def test_builder_refuses_unknown_cameras() -> None:
    with pytest.raises(PerceptionError, match=r"camera 'fisheye_front' is not in the rig"):
        TopviewBuilder(default_rig())
    with pytest.raises(PerceptionError, match="repeated camera names"):
        TopviewBuilder(surround_rig(), cameras=("fisheye_front", "fisheye_front"))


def test_fisheye_model_matches_opencv_and_inverts() -> None:
    cam = default_fisheye_cameras()["fisheye_left"]
    rng = np.random.default_rng(1)
    P = rng.normal(size=(500, 3))
    front = P[:, 2] > 0.05
    uv, theta = fisheye_project(cam, P)
    ref, _ = cv2.fisheye.projectPoints(
        P[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D
    )
    np.testing.assert_allclose(uv[front], ref.reshape(-1, 2), atol=1e-6)
    wide = theta < math.radians(100)  # past 90 deg too, where OpenCV's formula folds back
    rays = fisheye_unproject(cam, uv[wide])
    np.testing.assert_allclose(rays, P[wide] / np.linalg.norm(P[wide], axis=1)[:, None], atol=1e-9)


def test_surround_rig_round_trips_through_rig_json() -> None:
    rig = surround_rig()
    assert list(default_rig().cameras) == ["front"]
    assert list(rig.cameras) == ["front", *DEFAULT_CAMERAS]
    document = json.loads(json.dumps(rig_to_dict(rig)))
    loaded = rig_from_dict(document)
    assert rig_to_dict(loaded) == document
    for name in DEFAULT_CAMERAS:
        cam = loaded.cameras[name]
        assert cam.model is CameraModel.FISHEYE and cam.size == (960, 640)
        np.testing.assert_array_equal(cam.T_vehicle_camera, rig.cameras[name].T_vehicle_camera)


def test_cameras_too_wide_for_one_remap_table_are_refused() -> None:
    """Four 8800 px fisheyes side by side pass OpenCV's 16-bit remap table: refused in one
    line, not read from the wrong place."""
    from semslam.rig import Rig

    base = surround_rig()
    wide = default_fisheye_cameras(size=(8800, 5000))
    rig = Rig(cameras={**base.cameras, **wide}, topview=base.topview, vehicle=base.vehicle)
    with pytest.raises(PerceptionError, match=r"35200 x 5000 px; the remap takes less than"):
        TopviewBuilder(rig)

