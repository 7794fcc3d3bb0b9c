import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from semslam.config import OdometryNoiseConfig, SimulationConfig
from semslam.geometry import inverse_transform_points, transform_points, wrap_angle
from semslam.motion import integrate_odometry
from semslam.simulation.driver import odometry_with_errors
from semslam.simulation.scenario import simulate_drive


@pytest.fixture(scope="module")
def small_drive():
    return simulate_drive("small", 0, 0, SimulationConfig())


def test_drive_is_repeatable(small_drive):
    again = simulate_drive("small", 0, 0, SimulationConfig())
    assert np.array_equal(small_drive.record.poses, again.record.poses)
    assert np.array_equal(small_drive.record.odo_speed, again.record.odo_speed)
    a = [s.vCorners for f in small_drive.noisy for s in f.slots]
    b = [s.vCorners for f in again.noisy for s in f.slots]
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_another_drive_index_takes_another_route(small_drive):
    other = simulate_drive("small", 0, 1, SimulationConfig())
    assert not np.allclose(other.frame_poses[0], small_drive.frame_poses[0])
    assert [s.label for s in other.world.slots] == [s.label for s in small_drive.world.slots]


def test_speeds_and_rates(small_drive):
    rec = small_drive.record
    assert rec.speed.min() >= 0.99 and rec.speed.max() <= 3.01
    assert np.allclose(np.diff(small_drive.frame_times), 0.1)


def test_speeds_closer_than_the_knot_margin_still_drive():
    """min_speed within 0.3 m/s of max_speed (the speed knots' margin above the floor),
    or equal to it: the car drives between the two."""
    for low, high in ((2.9, 3.0), (1.5, 1.5)):
        cfg = SimulationConfig.model_validate(
            {"drive": {"min_speed": low, "max_speed": high, "max_duration": 20.0}})
        rec = simulate_drive("small", 0, 0, cfg).record
        assert rec.speed.max() <= high + 0.01 and np.median(rec.speed) >= low - 0.01


def test_true_odometry_reproduces_truth_with_ctrv(small_drive):
    rec = small_drive.record
    poses = integrate_odometry(rec.poses[0], rec.t, rec.speed, rec.yaw_rate)
    assert np.allclose(poses[:, :2], rec.poses[:, :2], atol=1e-6)
    assert np.allclose(wrap_angle(poses[:, 2] - rec.poses[:, 2]), 0.0, atol=1e-9)


def test_noisy_odometry_drifts_but_not_wildly(small_drive):
    rec = small_drive.record
    poses = integrate_odometry(rec.poses[0], rec.t, rec.odo_speed, rec.odo_yaw_rate)
    err = np.linalg.norm(poses[-1, :2] - rec.poses[-1, :2])
    assert 0.01 < err < 0.05 * np.sum(rec.speed) / 50.0


def test_odometry_errors_follow_their_model():
    n, dt = 20_000, 0.1
    speed, rate = np.full(n, 2.0), np.full(n, 0.05)
    none = OdometryNoiseConfig(speed_sigma=0, speed_scale_sigma=0, gyro_sigma=0,
                               gyro_bias_sigma=0, gyro_bias_walk=0)
    v, w = odometry_with_errors(speed, rate, dt, none, np.random.default_rng(0))
    assert np.array_equal(v, speed) and np.array_equal(w, rate)
    # one scale error per drive, one constant bias: the means carry them, white noise the spread
    only = OdometryNoiseConfig(speed_sigma=0.03, speed_scale_sigma=0.01, gyro_sigma=0.003,
                               gyro_bias_sigma=1e-3, gyro_bias_walk=0)
    v, w = odometry_with_errors(speed, rate, dt, only, np.random.default_rng(1))
    assert abs(np.std(v) - 0.03) < 0.002 and abs(np.std(w) - 0.003) < 0.0002
    assert 0 < abs(np.mean(v) / 2.0 - 1.0) < 0.05 and 0 < abs(np.mean(w) - 0.05) < 5e-3
    # the bias walk grows as sqrt(time); per-sample times work as a scalar does
    walk = OdometryNoiseConfig(speed_sigma=0, speed_scale_sigma=0, gyro_sigma=0,
                               gyro_bias_sigma=0, gyro_bias_walk=1e-4)
    ends = [odometry_with_errors(speed, rate, np.full(n, dt), walk,
                                 np.random.default_rng(k))[1][-1] - 0.05 for k in range(200)]
    assert np.std(ends) == pytest.approx(1e-4 * math.sqrt(n * dt), rel=0.2)


def test_exact_slot_observations_are_the_world_seen_from_the_true_pose(small_drive):
    labels = {s.label: s for s in small_drive.world.slots}
    n = 0
    for pose, frame in zip(small_drive.frame_poses, small_drive.exact, strict=True):
        for obs in frame.slots:
            truth = labels[obs.label]
            assert np.allclose(transform_points(pose, obs.vCorners), truth.corners, atol=1e-9)
            assert np.all(np.abs(obs.vCorners[:2]) <= 5.0)
            n += 1
    assert n > 100


def test_exact_tag_observations_match_world(small_drive):
    tags = {t.tag_id: t for t in small_drive.world.tags}
    seen = 0
    for pose, frame in zip(small_drive.frame_poses, small_drive.exact, strict=True):
        for obs in frame.tags:
            tag = tags[obs.tag_id]
            assert np.allclose(inverse_transform_points(pose, tag.mTt[:2]), obs.vTt[:2], atol=1e-9)
            assert math.isclose(wrap_angle(tag.mTt[2] - pose[2] - obs.vTt[2]), 0.0, abs_tol=1e-9)
            assert np.hypot(*obs.vTt[:2]) <= 25.0 + 1.3
            assert np.all(np.linalg.eigvalsh(obs.covariance) > 0)
            seen += 1
    assert seen > 10


def test_noisy_observations_follow_the_configured_rates():
    sim = simulate_drive("garage", 1, 0, SimulationConfig())
    exact = sum(len(f.slots) for f in sim.exact)
    labels = {s.label: s for s in sim.world.slots}
    kept = false = wrong = readable = 0
    errors = []
    centres = cKDTree(np.array([s.corners.mean(axis=0) for s in sim.world.slots]))
    for pose, frame in zip(sim.frame_poses, sim.noisy, strict=True):
        for obs in frame.slots:
            centre = transform_points(pose, obs.vCorners).mean(axis=0)
            nearest = sim.world.slots[int(centres.query(centre)[1])]
            d = transform_points(pose, obs.vCorners) - nearest.corners
            if np.abs(d).max() > 0.3:
                false += 1
                continue
            kept += 1
            errors.append(d)
            if obs.label is not None:
                readable += 1
                wrong += obs.label != nearest.label
    assert 0.74 < kept / exact < 0.86  # 20 % missed
    assert 0.03 < false / (kept + false) < 0.08  # 5 % false
    assert 0.16 < wrong / readable < 0.24  # 20 % wrong IDs
    assert 0.045 < np.std(np.concatenate(errors)) < 0.055  # 5 cm corner noise
    assert labels  # world labels exist


def test_a_placed_tag_ahead_of_the_car_is_seen():
    """A tag placed 8 m ahead of the start, facing the car, is in the first frames'
    exact tag observations; the route and the world's own tags are unchanged."""
    cfg = SimulationConfig()
    cfg = cfg.model_copy(update={"drive": cfg.drive.model_copy(update={"max_duration": 5.0})})
    bare = simulate_drive("small", 2, 0, cfg)
    x, y, yaw = bare.frame_poses[0]
    ahead = np.array([[x + 8 * math.cos(yaw), y + 8 * math.sin(yaw), wrap_angle(yaw + math.pi)]])
    placed = simulate_drive("small", 2, 0, cfg, ahead)
    new_id = placed.world.tags[-1].tag_id
    assert len(placed.world.tags) == len(bare.world.tags) + 1
    np.testing.assert_array_equal(placed.frame_poses, bare.frame_poses)
    assert any(t.tag_id == new_id for t in placed.exact[0].tags)
    assert not any(t.tag_id == new_id for f in bare.exact for t in f.tags)
