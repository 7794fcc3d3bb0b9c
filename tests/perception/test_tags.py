"""Fiducial tags: IPPE with both solutions, ambiguity rejection, undistortion, the
covariance's Jacobian, bad input, a rendered frame, the real photos and `semslam tags`."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import stats
from typer.testing import CliRunner

from semslam.cli import app
from semslam.config import load_config, with_overrides
from semslam.geometry import inverse_transform_points, wrap_angle
from semslam.perception.tag_covariance import (
    TagNoiseModel,
    camera_covariance,
    vehicle_covariance,
    vehicle_pose_2d,
)
from semslam.perception.tag_detection import (
    REFERENCE_SETTINGS,
    DetectorSettings,
    PerceptionError,
    TagDetection,
    detect_tags,
)
from semslam.perception.tag_pose import estimate_pose, solve_ippe, square_object_points
from semslam.perception.tags import (
    TagSettings,
    estimate_tag,
    observe_tags,
    settings_from_config,
    size_mismatches,
    to_observations,
)
from semslam.perception.undistort import distort_pixels, undistort_pixels
from semslam.rig import Camera, CameraModel, default_front_camera
from semslam.simulation.render_front import FrontRenderer
from semslam.simulation.world_types import Pillar, Wall, World
from semslam.types import Tag, TagFamily, TagObservation

CAM = default_front_camera()
K = CAM.K
REAL = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "apriltag-photos"


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def project(R: np.ndarray, t: np.ndarray, size: float = 0.5, K_=K) -> np.ndarray:
    uv, _ = cv2.projectPoints(square_object_points(size), cv2.Rodrigues(R)[0], t, K_, None)
    return uv.reshape(4, 2)


def angle_between(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


def fake_detection(corners: np.ndarray, tag_id: int = 7) -> TagDetection:
    return TagDetection(TagFamily.TAG36H11, tag_id, corners, corners.mean(axis=0), 0, 50.0)


def camera_pose_of_vehicle_tag(vTt: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle-frame tag (x, y, yaw of its outward normal; centre height) in the camera."""
    x, y, yaw = vTt
    R_vt = np.column_stack([[-math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, -1.0],
                            [-math.cos(yaw), -math.sin(yaw), 0.0]])
    T_cv = np.linalg.inv(CAM.T_vehicle_camera)
    return T_cv[:3, :3] @ np.array([x, y, height]) + T_cv[:3, 3], T_cv[:3, :3] @ R_vt


# --------------------------------------------------------------------------- PnP


def test_ippe_recovers_a_known_pose_and_keeps_the_other_solution() -> None:
    R, t = rot_y(math.radians(35.0)), np.array([0.4, -0.2, 6.0])
    best, other = solve_ippe(project(R, t), 0.5, K)
    assert angle_between(best.R, R) < 1e-4 and np.allclose(best.t, t, atol=1e-6)
    assert best.error < 1e-6
    assert angle_between(other.R, R) > 10.0  # a genuinely different pose...
    assert 0.05 < other.error < 5.0  # ...that explains the corners almost as well
    pose = estimate_pose(project(R, t), 0.5, K)
    assert pose is not None and pose.ambiguity < 1e-3


def test_corners_between_the_two_poses_are_ambiguous_and_rejected() -> None:
    # a small, nearly head-on tag; move its corners halfway towards the other solution
    R, t = rot_y(math.radians(8.0)), np.array([0.3, 0.1, 15.0])
    uv = project(R, t)
    _, other = solve_ippe(uv, 0.5, K)
    halfway = (uv + project(other.R, other.t)) / 2
    est = estimate_tag(fake_detection(halfway), CAM, TagSettings())
    assert est is not None and est.pose.ambiguity > 0.8
    assert est.flip_probability > 0.1
    assert to_observations([est], CAM, TagSettings()) == ()
    # either test alone drops it: the ambiguity ratio, or the flip probability
    assert to_observations([est], CAM, TagSettings(max_ambiguity=1.0)) == ()
    assert to_observations([est], CAM, TagSettings(max_flip_probability=1.0)) == ()
    kept = to_observations([est], CAM, TagSettings(max_ambiguity=1.0, max_flip_probability=1.0))
    assert len(kept) == 1
    # the covariance is the chosen solution's, not widened to cover the flip (which it was,
    # moment-matched: above 0.4 of it here)
    yaw_best = vehicle_pose_2d(est.pose.best.t, est.pose.best.R, CAM.T_vehicle_camera)[0][2]
    yaw_other = vehicle_pose_2d(other.t, other.R, CAM.T_vehicle_camera)[0][2]
    assert math.sqrt(kept[0].covariance[2, 2]) < 0.35 * abs(wrap_angle(yaw_best - yaw_other))


def test_clear_tag_becomes_an_observation_at_its_vehicle_pose_and_far_ones_are_dropped() -> None:
    vTt, height = np.array([9.0, 1.5, math.radians(200.0)]), 1.7
    p, R = camera_pose_of_vehicle_tag(vTt, height)
    est = estimate_tag(fake_detection(project(R, p)), CAM, TagSettings())
    (obs,) = to_observations([est], CAM, TagSettings())
    assert np.allclose(obs.vTt[:2], vTt[:2], atol=1e-6)
    assert abs(wrap_angle(obs.vTt[2] - vTt[2])) < 1e-6 and abs(obs.height - height) < 1e-6
    assert np.allclose(obs.covariance, obs.covariance.T)
    assert np.linalg.eigvalsh(obs.covariance).min() > 0
    near = with_overrides(load_config(), mapping={"tag_range_limit": 5.0})
    assert to_observations([est], CAM, settings_from_config(near)) == ()
    far_p, far_R = camera_pose_of_vehicle_tag(np.array([25.0, 0.0, math.pi]), 1.5)
    far = estimate_tag(fake_detection(project(far_R, far_p)), CAM, TagSettings())
    assert to_observations([far], CAM, TagSettings(range_limit=20.0, min_side_px=10)) == ()
    assert len(to_observations([far], CAM, TagSettings(range_limit=30.0, min_side_px=10))) == 1
    assert to_observations([far], CAM, TagSettings(range_limit=30.0)) == ()  # 12.8 px < 18


def test_a_code_with_an_unread_ring_side_is_widened_or_dropped() -> None:
    vTt, height = np.array([9.0, 1.5, math.radians(200.0)]), 1.7
    p, R = camera_pose_of_vehicle_tag(vTt, height)
    det = fake_detection(project(R, p))
    full = replace(det, ring_cells=(3, 4, 4, 3))
    unread = replace(det, ring_cells=(4, 3, 2, 0))
    assert full.ring_sides == 4 and unread.ring_sides == 3 and det.ring_sides == -1
    (a,), (b,) = (to_observations([estimate_tag(d, CAM)], CAM) for d in (full, unread))
    k = TagNoiseModel().unread_side_factor
    assert k > 1 and np.allclose(b.covariance, k**2 * a.covariance)
    strict = TagSettings(full_ring=True)
    assert to_observations([estimate_tag(unread, CAM, strict)], CAM, strict) == ()
    assert len(to_observations([estimate_tag(full, CAM, strict)], CAM, strict)) == 1


def test_tag_cut_by_the_image_border_is_not_observed() -> None:
    p, R = camera_pose_of_vehicle_tag(np.array([5.0, 0.0, math.pi]), 1.5)
    uv = project(R, p)
    shift = np.array([CAM.size[0] - 2.0 - uv[:, 0].max(), 0.0])  # 1 px from the right edge
    det = TagDetection(TagFamily.TAG36H11, 3, uv + shift, (uv + shift).mean(axis=0), 0, 80.0,
                       CAM.size)
    assert 0.5 < det.border_distance < 1.5
    est = estimate_tag(det, CAM)
    assert to_observations([est], CAM) == ()
    assert len(to_observations([est], CAM, TagSettings(min_border_cells=0.0))) == 1


def test_vehicle_covariance_is_the_first_order_propagation() -> None:
    p, R = camera_pose_of_vehicle_tag(np.array([6.0, -2.0, math.radians(160.0)]), 1.6)

    def f(x: np.ndarray) -> np.ndarray:  # x: position error, left rotation error (camera)
        v, _ = vehicle_pose_2d(p + x[:3], cv2.Rodrigues(x[3:])[0] @ R, CAM.T_vehicle_camera)
        return v

    J = np.zeros((3, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = 1e-6
        J[:, k] = (f(d) - f(-d)) / 2e-6
    A = np.random.default_rng(0).normal(size=(6, 6))
    cov6 = A @ A.T * 1e-3
    assert np.allclose(vehicle_covariance(R, cov6, CAM.T_vehicle_camera), J @ cov6 @ J.T,
                       rtol=1e-5, atol=1e-12)


def test_a_tag_that_stands_out_less_gets_a_larger_covariance() -> None:
    R, t = rot_y(math.radians(30.0)), np.array([0.5, 0.1, 8.0])
    pose = estimate_pose(project(R, t), 0.5, K)
    model = TagNoiseModel(contrast_ref=170.0, contrast_power=0.5)
    bright, dim = (camera_covariance(pose, 40.0, 800.0, model, contrast=c) for c in (170, 85))
    assert np.allclose(dim, 2.0**0.5 * 2.0**0.5 * bright)  # pixel errors x 2^0.5: variances x 2
    unknown = camera_covariance(pose, 40.0, 800.0, model)  # NaN contrast: no factor
    assert np.allclose(unknown, bright)


# --------------------------------------------------------------------------- camera models


@pytest.mark.parametrize("model, D", [(CameraModel.FISHEYE, [0.05, -0.01, 0.003, -0.001]),
                                      (CameraModel.PINHOLE, [-0.12, 0.02, 0.001, -0.001, 0.0])])
def test_undistortion_round_trip(model: CameraModel, D: list[float]) -> None:
    Kf = np.array([[320.0, 0.0, 640.0], [0.0, 320.0, 400.0], [0.0, 0.0, 1.0]])
    uv = np.random.default_rng(1).uniform([200, 150], [1080, 650], (40, 2))
    raw = distort_pixels(uv, Kf, D, model)
    assert np.abs(raw - uv).max() > 5.0  # the model does distort
    assert np.abs(undistort_pixels(raw, Kf, D, model) - uv).max() < 1e-6


def test_an_ideal_fisheye_still_distorts_and_no_points_are_no_points() -> None:
    """A fisheye with D = 0 is the equidistant model (r = f theta), not a pinhole."""
    Kf = np.array([[320.0, 0.0, 640.0], [0.0, 320.0, 400.0], [0.0, 0.0, 1.0]])
    D = np.zeros(4)
    uv = np.array([[1100.0, 399.5], [300.0, 650.0]])
    expected = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), Kf, D, P=Kf).reshape(-1, 2)
    np.testing.assert_allclose(undistort_pixels(uv, Kf, D, CameraModel.FISHEYE), expected,
                               atol=1e-6)
    assert np.abs(expected - uv).max() > 50.0
    np.testing.assert_allclose(distort_pixels(expected, Kf, D, CameraModel.FISHEYE), uv,
                               atol=1e-6)
    for model, coefficients in ((CameraModel.FISHEYE, [0.05, 0.0, 0.0, 0.0]),
                                (CameraModel.PINHOLE, [-0.1, 0.0, 0.0, 0.0, 0.0])):
        for function in (undistort_pixels, distort_pixels):
            assert function(np.zeros((0, 2)), Kf, coefficients, model).shape == (0, 2)


def test_fisheye_tag_pose_from_distorted_corners() -> None:
    Kf = np.array([[330.0, 0.0, 640.0], [0.0, 330.0, 400.0], [0.0, 0.0, 1.0]])
    D = np.array([0.08, -0.02, 0.004, -0.001])
    fisheye = Camera("fish", CameraModel.FISHEYE, Kf, D, (1280, 800), np.eye(4))
    R, t = rot_y(math.radians(30.0)), np.array([1.5, 0.3, 3.0])
    raw, _ = cv2.fisheye.projectPoints(square_object_points(0.5).reshape(-1, 1, 3),
                                       cv2.Rodrigues(R)[0], t, Kf, D)
    est = estimate_tag(fake_detection(raw.reshape(4, 2)), fisheye, TagSettings())
    assert est is not None
    assert np.allclose(est.pose.position, t, atol=1e-5)
    assert angle_between(est.pose.rotation, R) < 1e-3


# --------------------------------------------------------------------------- bad input


def test_bad_images_and_families_give_one_line_errors_or_nothing() -> None:
    assert detect_tags(np.zeros((800, 1280), np.uint8)) == ()
    assert detect_tags(np.full((100, 100, 3), 255, np.uint8)) == ()
    cases = [(np.zeros((50, 50), np.float32), "uint8"),
             (np.zeros((50, 50, 2), np.uint8), "shape"),
             (np.zeros(50, np.uint8), "shape"),
             (np.zeros((4, 4), np.uint8), "too small"),
             ([[0, 1], [1, 0]], "numpy array")]
    for image, words in cases:
        with pytest.raises(PerceptionError, match=words) as info:
            detect_tags(image)
        assert "\n" not in str(info.value)
    with pytest.raises(PerceptionError, match="tag99h99"):
        detect_tags(np.zeros((50, 50), np.uint8), "tag99h99")
    with pytest.raises(PerceptionError, match="size"):
        solve_ippe(project(np.eye(3), np.array([0, 0, 5.0])), -1.0, K)


def test_size_mismatch_is_reported() -> None:
    mapped = [Tag(TagFamily.TAG36H11, 7, 0.5, np.zeros(3), 1.5, np.eye(3)),
              Tag(TagFamily.TAG36H11, 8, 0.5, np.zeros(3), 1.5, np.eye(3))]
    seen = [TagObservation(TagFamily.TAG36H11, i, size, np.zeros(3), 1.5, np.eye(3))
            for i, size in ((7, 0.5), (8, 0.3), (9, 0.2))]
    (bad,) = size_mismatches(seen, mapped)
    assert (bad.tag_id, bad.observed, bad.mapped) == (8, 0.3, 0.5)


# --------------------------------------------------------------------------- rendered frame


@pytest.fixture(scope="module")
def rendered() -> tuple[np.ndarray, Tag, np.ndarray]:
    """A 0.5 m tag 8 m from the camera, seen 25 deg off its normal, off the image centre."""
    c = [np.array(p, float) for p in ((-30, -20), (30, -20), (30, 20), (-30, 20))]
    tag = Tag(TagFamily.TAG36H11, 42, 0.5, np.array([0.305, 0.0, 0.0]), 1.7, np.zeros((3, 3)))
    world = World(preset="test", seed=0, slots=(), tags=(tag,), markings=(), marking_points=(),
                  slot_paint=(), pillars=(Pillar(np.zeros(2), 0.6, 3.0),),
                  walls=tuple(Wall(c[i], c[(i + 1) % 4], 3.0) for i in range(4)),
                  parked_cars=(), aisles=(), bounds=(-30.0, -20.0, 30.0, 20.0),
                  line_colour=(235, 235, 235))
    view, bearing = math.radians(25.0), math.radians(12.0)
    cam_xy = tag.mTt[:2] + 8.0 * np.array([math.cos(view), math.sin(view)])
    heading = view + math.pi + bearing
    centre = cam_xy - CAM.T_vehicle_camera[0, 3] * np.array([math.cos(heading), math.sin(heading)])
    mTv = np.array([centre[0], centre[1], wrap_angle(heading)])
    return FrontRenderer(world, CAM).render(mTv, seed=5), tag, mTv


def test_rendered_tag_is_observed_within_its_covariance(rendered) -> None:
    image, tag, mTv = rendered
    (obs,) = observe_tags(image, CAM)
    true_xy = inverse_transform_points(mTv, tag.mTt[:2]).ravel()
    err = np.array([*(obs.vTt[:2] - true_xy), wrap_angle(obs.vTt[2] - (tag.mTt[2] - mTv[2]))])
    assert err @ np.linalg.solve(obs.covariance, err) < stats.chi2.ppf(0.999, 3)
    cam = CAM.T_vehicle_camera[:2, 3]
    rng_true = np.linalg.norm(true_xy - cam)
    assert abs(np.linalg.norm(obs.vTt[:2] - cam) - rng_true) <= 0.01 * rng_true + 0.02
    bearing = [math.atan2(*(v - cam)[::-1]) for v in (obs.vTt[:2], true_xy)]
    assert abs(math.degrees(bearing[0] - bearing[1])) < 0.3
    assert abs(obs.height - tag.height) < 0.05
    # corners in OpenCV's pixel convention: where K projects the true corners (the
    # AprilTag library's own are 0.5 px off)
    (det,) = detect_tags(image)
    p, R = camera_pose_of_vehicle_tag(np.array([*true_xy, tag.mTt[2] - mTv[2]]), tag.height)
    assert np.abs(det.corners - project(R, p)).max() < 0.3


# --------------------------------------------------------------------------- real photos


def test_duckietown_rotation_set_beats_apriltag3() -> None:
    # at full resolution, as `semslam tags` runs (AprilTag 3's estimate: 8.3 mm, 3.0 deg)
    folder = REAL / "duckietown"
    if not folder.is_dir():
        pytest.skip(f"real photos not found at {folder}")
    Kd = np.array([[329.8729619143081, 0, 528.0], [0, 332.94611303946357, 396.0], [0, 0, 1]])
    camera = Camera("duckie", CameraModel.PINHOLE, Kd, np.zeros(5), (1056, 792), np.eye(4))
    angles = np.arange(-70, 71, 10)
    positions, turns = [], []
    for a in angles:
        gray = cv2.imread(str(folder / f"test_image_rotation_{a}.png"), cv2.IMREAD_GRAYSCALE)
        (est,) = [e for e in _estimates(gray, camera)]
        positions.append(est.pose.position)
        R = est.pose.rotation
        turns.append(math.degrees(math.atan2(-R[0, 2], R[2, 2])))
    p = np.array(positions)
    residual = np.array(turns) - angles
    assert np.linalg.norm(p - p.mean(axis=0), axis=1).max() <= 0.0083  # AprilTag 3: 8.3 mm
    assert np.abs(residual - residual.mean()).max() <= 3.0  # AprilTag 3: 3.0 deg


def _estimates(gray: np.ndarray, camera: Camera):
    from semslam.perception.tags import estimate_tags

    return estimate_tags(gray, camera, TagSettings(
        size=0.065, detector=DetectorSettings(quad_decimate=1.0)))


def test_regression_photos_find_every_reference_tag() -> None:
    folder = REAL / "apriltag-regression"
    if not folder.is_dir():
        pytest.skip(f"real photos not found at {folder}")
    for txt in sorted(folder.glob("*.txt")):
        image = cv2.imread(str(txt.with_suffix(".jpg")))
        # the reference's settings; AprilTag's pixel centres are at +0.5
        found = [d.corners + 0.5 for d in detect_tags(image, settings=REFERENCE_SETTINGS)]
        for line in txt.read_text().splitlines():
            nums = line.replace("(", " ").replace(")", " ").replace(",", " ").split()
            ref = np.array(nums[1:9], dtype=float).reshape(4, 2)
            assert min(np.abs(f - ref).max() for f in found) <= 1.0, (txt.name, line)


# --------------------------------------------------------------------------- command


def test_tags_command_prints_poses_as_json(rendered, tmp_path: Path) -> None:
    image, tag, mTv = rendered
    path = tmp_path / "front.png"
    cv2.imwrite(str(path), image)
    runner = CliRunner()
    k = f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"
    result = runner.invoke(app, ["tags", str(path), "--intrinsics", k, "--tag-size", "0.5",
                                 "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    (det,) = doc["images"][0]["detections"]
    assert det["family"] == "tag36h11" and det["id"] == 42
    assert np.array(det["corners"]).shape == (4, 2) and np.array(det["covariance"]).shape == (6, 6)
    assert 20 < det["contrast"] <= 255 and det["ring_sides_read"] in (0, 1, 2, 3, 4)
    p, R = camera_pose_of_vehicle_tag(
        np.array([*inverse_transform_points(mTv, tag.mTt[:2]).ravel(), tag.mTt[2] - mTv[2]]),
        tag.height)
    assert np.linalg.norm(np.array(det["position"]) - p) < 0.02 * np.linalg.norm(p)
    assert angle_between(np.array(det["rotation"]), R) < 5.0
    for args, words in ((["--intrinsics", "640,640,639.5"], "--intrinsics"),
                        (["--intrinsics", k, "--family", "nope"], "nope"),
                        (["--intrinsics", k, "--fisheye"], "--fisheye")):
        bad = runner.invoke(app, ["tags", str(path), "--tag-size", "0.5", *args])
        assert bad.exit_code == 2 and words in bad.output and bad.output.count("\n") == 1
    missing = runner.invoke(app, ["tags", str(tmp_path / "none.png"), "--intrinsics", k,
                                  "--tag-size", "0.5"])
    assert missing.exit_code == 2 and "none.png" in missing.output
    folder = runner.invoke(app, ["tags", str(tmp_path), "--intrinsics", k, "--tag-size", "0.5",
                                 "--json"])  # a folder: its images
    assert folder.exit_code == 0, folder.output
    assert [e["image"] for e in json.loads(folder.stdout)["images"]] == [str(path)]


def test_a_decimation_that_leaves_almost_no_image_is_refused_not_crashed() -> None:
    # the AprilTag library kills the process on a decimated image of 2 px a side
    image = np.full((16, 16), 200, np.uint8)
    with pytest.raises(PerceptionError, match="decimate 8 leaves a 2 x 2 px image"):
        detect_tags(image, settings=DetectorSettings(quad_decimate=8.0))
    assert detect_tags(image, settings=DetectorSettings(quad_decimate=2.0)) == ()
