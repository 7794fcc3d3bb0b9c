"""Simulated surround-view fisheye images: deterministic, the right geometry, sensible content."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semslam.rig import default_fisheye_cameras, default_front_camera, fisheye_project
from semslam.simulation.render_fisheye import render_fisheye, render_fisheye_rig
from semslam.simulation.world import make_world

MTV = np.array([20.0, 7.5, 0.3])  # on the small world's aisle, slots on both sides


@pytest.fixture(scope="module")
def world():
    return make_world("small", 1)


@pytest.fixture(scope="module")
def cams():
    return default_fisheye_cameras()


def test_deterministic_and_per_camera(world, cams) -> None:
    cam = cams["fisheye_front"]
    a = render_fisheye(world, MTV, 3, cam)
    assert a.shape == (640, 960, 3) and a.dtype == np.uint8
    assert np.array_equal(a, render_fisheye(world, MTV, 3, cam))
    # the same bytes whichever other cameras share the frame
    assert np.array_equal(a, render_fisheye_rig(world, MTV, 3, cams.values())[cam.name])
    assert not np.array_equal(a, render_fisheye(world, MTV, 4, cam))


def test_ceiling_body_and_floor_where_the_rays_say(world, cams) -> None:
    """Above the horizon: the dark ceiling; the ground under the car: its body; beside
    the car: the brighter floor."""
    cam = cams["fisheye_left"]
    img = render_fisheye(world, MTV, 3, cam, solids=False).astype(float).mean(axis=2)
    T_cv = np.linalg.inv(cam.T_vehicle_camera)

    def mean_at(vP):
        cP = T_cv[:3, :3] @ np.asarray(vP, float) + T_cv[:3, 3]
        u, v = np.round(fisheye_project(cam, cP)[0][0]).astype(int)
        return img[v - 2 : v + 3, u - 2 : u + 3].mean()

    assert mean_at([0.5, 50.0, 11.0]) < 60  # above the horizon
    assert mean_at([0.5, 0.5, 0.0]) < 60  # under the car
    assert mean_at([0.5, 2.0, 0.0]) > 90  # beside the car


def test_painted_junctions_are_bright(world, cams) -> None:
    """The world's marking points, projected through each camera, sit on paint."""
    images = render_fisheye_rig(world, MTV, 5, cams.values(), solids=False)
    pts = np.array([mp.position for mp in world.marking_points], float)
    c, s = math.cos(MTV[2]), math.sin(MTV[2])
    d = pts - MTV[:2]
    vP = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], np.zeros(len(d))])
    checked = 0
    for name, cam in cams.items():
        lum = (images[name][..., 1].astype(float) + images[name][..., 2]) / 2.0
        T_cv = np.linalg.inv(cam.T_vehicle_camera)
        cP = vP @ T_cv[:3, :3].T + T_cv[:3, 3]
        uv, theta = fisheye_project(cam, cP)
        dist = np.hypot(*(vP[:, :2] - cam.T_vehicle_camera[:2, 3]).T)
        w, h = cam.size
        for (u, v), th, r in zip(uv, theta, dist, strict=True):
            if th > math.radians(75) or r > 4.0 or not (20 <= u < w - 20 and 20 <= v < h - 20):
                continue
            ui, vi = round(u), round(v)
            spot = lum[vi - 1 : vi + 2, ui - 1 : ui + 2].mean()
            around = np.percentile(lum[vi - 30 : vi + 31, ui - 30 : ui + 31], 25)
            assert spot > around + 25.0, (name, u, v, spot, around)
            checked += 1
    assert checked >= 4


def test_parked_cars_cover_the_floor(world, cams) -> None:
    cam = cams["fisheye_left"]
    with_cars = render_fisheye(world, MTV, 3, cam)
    without = render_fisheye(world, MTV, 3, cam, solids=False)
    changed = np.abs(with_cars.astype(int) - without.astype(int)).max(axis=2) > 40
    assert changed.mean() > 0.01


def test_refuses_a_pinhole_camera(world) -> None:
    with pytest.raises(ValueError, match="not a fisheye camera"):
        render_fisheye(world, MTV, 3, default_front_camera())
