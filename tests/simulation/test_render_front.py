"""The front-camera renderer: shape, determinism, and tags that a real detector reads
at their true pose."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from semslam.errors import SimulationError
from semslam.perception.tag_detection import DetectorSettings, configured_detector
from semslam.rig import default_front_camera
from semslam.simulation.render_front import FrontRenderer, render_front
from semslam.simulation.world import make_world
from semslam.simulation.world_types import Wall, World
from semslam.types import Tag, TagFamily

pupil_apriltags = pytest.importorskip("pupil_apriltags")

CAMERA = default_front_camera()
CAM_FORWARD = float(CAMERA.T_vehicle_camera[0, 3])  # 1.2 m ahead of the vehicle centre


@pytest.fixture(scope="module")
def small_world() -> World:
    return make_world("small", 0)


@pytest.fixture(scope="module")
def renderer(small_world: World) -> FrontRenderer:
    return FrontRenderer(small_world, CAMERA)


@pytest.fixture
def detector():
    """The process-wide detector with semslam's settings, set for each test: the C
    library's settings belong to the one detector, and other tests change them."""
    return configured_detector("tag36h11", DetectorSettings())


def pose_facing(tag: Tag, distance: float) -> np.ndarray:
    """Vehicle pose whose camera sits ``distance`` m in front of the tag, looking at it."""
    x, y, yaw = (float(v) for v in tag.mTt)
    cam = np.array([x, y]) + distance * np.array([math.cos(yaw), math.sin(yaw)])
    heading = yaw + math.pi
    centre = cam - CAM_FORWARD * np.array([math.cos(heading), math.sin(heading)])
    return np.array([centre[0], centre[1], math.atan2(math.sin(heading), math.cos(heading))])


def camera_pose_in_map(mTv: np.ndarray) -> np.ndarray:
    x, y, yaw = mTv
    T = np.eye(4)
    T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    T[:2, 3] = x, y
    return T @ CAMERA.T_vehicle_camera


def tag_corners_map(tag: Tag) -> np.ndarray:
    """Black-square corners in the AprilTag detector's order: bottom-left, bottom-right,
    top-right, top-left as seen from the front."""
    x, y, yaw = (float(v) for v in tag.mTt)
    right = np.array([-math.sin(yaw), math.cos(yaw), 0.0]) * tag.size / 2
    up = np.array([0.0, 0.0, 1.0]) * tag.size / 2
    c = np.array([x, y, tag.height])
    return np.array([c - right - up, c + right - up, c + right + up, c - right + up])


def project_map_points(mTv: np.ndarray, mP: np.ndarray) -> np.ndarray:
    x, y, yaw = mTv
    d = mP[:, :2] - [x, y]
    c, s = math.cos(yaw), math.sin(yaw)
    vP = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], mP[:, 2]])
    uv, z = CAMERA.project_vehicle_points(vP)
    assert (z > 0).all()
    return uv


def test_shape_dtype_and_determinism(renderer: FrontRenderer, small_world: World) -> None:
    pose = pose_facing(small_world.tags[0], 8.0)
    a = renderer.render(pose, seed=3)
    b = renderer.render(pose.copy(), seed=3)
    w, h = CAMERA.size
    assert a.shape == (h, w, 3) and a.dtype == np.uint8
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != renderer.render(pose, seed=4).tobytes()  # exposure and noise differ
    assert 40 < float(a.mean()) < 200  # neither black nor blown out
    assert render_front(small_world, CAMERA, pose, 3).tobytes() == a.tobytes()


@pytest.mark.parametrize("distance", [5.0, 7.5, 10.0])
def test_tag_ahead_is_detected_at_its_true_pose(
    renderer: FrontRenderer, small_world: World, detector, distance: float
) -> None:
    tag = small_world.tags[0]
    pose = pose_facing(tag, distance)
    gray = cv2.cvtColor(renderer.render(pose, seed=int(distance * 10)), cv2.COLOR_BGR2GRAY)
    found = [d for d in detector.detect(gray) if d.tag_id == tag.tag_id]
    assert len(found) == 1
    corners = np.asarray(found[0].corners, dtype=float)
    # the corners are where the true tag corners project (exact rendering, sub-pixel);
    # the AprilTag library puts pixel centres at +0.5 where OpenCV (and K) put them at 0
    truth = project_map_points(pose, tag_corners_map(tag))
    assert np.abs(corners - 0.5 - truth).max() < 0.4
    s = tag.size
    obj = np.array([[-s / 2, s / 2, 0], [s / 2, s / 2, 0], [s / 2, -s / 2, 0], [-s / 2, -s / 2, 0]])
    ok, rvec, tvec = cv2.solvePnP(obj, corners, CAMERA.K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    assert ok
    T_mc = camera_pose_in_map(pose)
    true_dist = np.linalg.norm(np.array([*tag.mTt[:2], tag.height]) - T_mc[:3, 3])
    assert abs(np.linalg.norm(tvec) / true_dist - 1.0) < 0.02
    # upright as the AprilTag library defines it: tag z (into the face) = -outward normal
    R, _ = cv2.Rodrigues(rvec)
    normal_map = np.array([math.cos(tag.mTt[2]), math.sin(tag.mTt[2]), 0.0])
    into_cam = T_mc[:3, :3].T @ -normal_map
    assert np.degrees(np.arccos(np.clip(R[:, 2] @ into_cam, -1, 1))) < 10.0
    assert R[1, 1] > 0.95  # tag y (down) along image down: not rotated in its plane


def _bare_world(tags: tuple[Tag, ...]) -> World:
    corners = [np.array(c, float) for c in ((-10, -10), (30, -10), (30, 10), (-10, 10))]
    return World(
        preset="test", seed=0, slots=(), tags=tags, markings=(), marking_points=(),
        slot_paint=(), pillars=(), walls=tuple(Wall(corners[i], corners[(i + 1) % 4], 3.0)
                                               for i in range(4)),
        parked_cars=(), aisles=(), bounds=(-10.0, -10.0, 30.0, 10.0),
        line_colour=(235, 235, 235),
    )


@pytest.mark.parametrize("yaw, visible", [(math.pi, True), (0.0, False)])
def test_tag_is_drawn_only_from_its_front(detector, yaw: float, visible: bool) -> None:
    # a free-standing tag 8 m ahead of the camera; yaw pi faces the camera, 0 faces away
    tag = Tag(TagFamily.TAG36H11, 42, 0.5, np.array([8.0 + CAM_FORWARD, 0.0, yaw]), 1.5,
              np.zeros((3, 3)))
    pose = np.zeros(3)
    with_tag = FrontRenderer(_bare_world((tag,)), CAMERA).render(pose, seed=1)
    without = FrontRenderer(_bare_world(()), CAMERA).render(pose, seed=1)
    ids = [d.tag_id for d in detector.detect(cv2.cvtColor(with_tag, cv2.COLOR_BGR2GRAY))]
    assert (ids == [42]) is visible
    assert (with_tag.tobytes() == without.tobytes()) is not visible


def test_near_plane_clipping_anywhere() -> None:
    # poses inside cars, against walls and pillars, outside the garage: never fails
    world = make_world("small", 1)
    r = FrontRenderer(world, CAMERA)
    rng = np.random.default_rng(0)
    xmin, ymin, xmax, ymax = world.bounds
    for k in range(12):
        pose = np.array([rng.uniform(xmin - 2, xmax + 2), rng.uniform(ymin - 2, ymax + 2),
                         rng.uniform(-math.pi, math.pi)])
        img = r.render(pose, seed=k)
        assert img.shape == (CAMERA.size[1], CAMERA.size[0], 3)


def test_bad_pose_is_refused(renderer: FrontRenderer) -> None:
    with pytest.raises(SimulationError):
        renderer.render(np.array([1.0, 2.0]), seed=0)
