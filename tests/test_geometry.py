import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from semslam.geometry import (
    between,
    compose,
    inverse,
    inverse_transform_points,
    quaternion_to_yaw,
    rotate_pose_covariance,
    rotation_variance,
    transform_points,
    wrap_angle,
    yaw_to_quaternion,
)

coord = st.floats(-100, 100, allow_nan=False)
angle = st.floats(-20, 20, allow_nan=False)
poses = st.tuples(coord, coord, angle).map(lambda p: np.array(p))


@given(angle)
def test_wrap_angle_range_and_equivalence(a):
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_wrap_angle_boundaries():
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    assert np.allclose(
        wrap_angle(np.array([0.0, 3 * math.pi, -3 * math.pi])), [0, math.pi, math.pi]
    )


@given(poses, poses)
def test_compose_inverse_round_trip(a, b):
    c = compose(a, b)
    back = compose(inverse(a), c)
    assert np.allclose(back[:2], b[:2], atol=1e-9)
    assert math.isclose(wrap_angle(back[2] - b[2]), 0.0, abs_tol=1e-9)
    assert np.allclose(between(a, c)[:2], b[:2], atol=1e-9)


@given(poses, st.lists(st.tuples(coord, coord), min_size=1, max_size=5))
def test_transform_points_round_trip(p, pts):
    pts = np.array(pts)
    there = transform_points(p, pts)
    assert np.allclose(inverse_transform_points(p, there), pts, atol=1e-9)
    # distances are preserved
    assert np.allclose(
        np.linalg.norm(there - there[0], axis=1), np.linalg.norm(pts - pts[0], axis=1)
    )


def test_transform_matches_compose():
    a = np.array([1.0, 2.0, 0.7])
    b = np.array([3.0, -1.0, 0.2])
    assert np.allclose(transform_points(a, b[:2]), compose(a, b)[:2])


@given(angle)
def test_quaternion_round_trip(a):
    assert math.isclose(wrap_angle(quaternion_to_yaw(*yaw_to_quaternion(a)) - a), 0.0, abs_tol=1e-9)


def test_clip_segment_to_square():
    from semslam.geometry import clip_segment

    a, b = clip_segment([-2.0, 0.0], [2.0, 0.0], -1.0, 1.0)
    assert np.allclose(a, [-1.0, 0.0]) and np.allclose(b, [1.0, 0.0])
    assert clip_segment([2.0, 2.0], [3.0, 3.0], -1.0, 1.0) is None
    inside = clip_segment([0.1, 0.2], [0.3, -0.4], -1.0, 1.0)
    assert np.allclose(inside[0], [0.1, 0.2]) and np.allclose(inside[1], [0.3, -0.4])


def test_rotation_variance_of_independent_and_of_rigidly_rotated_points():
    corners = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])
    spread = np.sum((corners - corners.mean(axis=0)) ** 2)  # 4 * (1.25^2 + 2.5^2)
    independent = np.tile(np.eye(2) * 0.05**2, (4, 1, 1))
    assert rotation_variance(corners, independent) == pytest.approx(0.05**2 / spread)
    # errors that are one rigid rotation of 0.002 rad (1-sigma) about the centroid
    a = corners - corners.mean(axis=0)
    J = np.column_stack([-a[:, 1], a[:, 0]]).reshape(-1, 1)
    assert rotation_variance(corners, J @ J.T * 0.002**2) == pytest.approx(0.002**2)
    # and a common shift turns nothing
    shift = np.tile(np.eye(2), (4, 4)) * 0.1**2
    assert rotation_variance(corners, shift) == pytest.approx(0.0, abs=1e-15)
    with pytest.raises(ValueError, match="distinct points"):
        rotation_variance(np.zeros((4, 2)), independent)


def test_rotation_variance_matches_sampled_rotations():
    rng = np.random.default_rng(0)
    corners = np.array([[0.0, 0.0], [2.5, 0.3], [2.4, 5.0], [0.1, 4.8]])
    A = rng.normal(size=(8, 8)) * 0.02
    C = A @ A.T
    samples = rng.multivariate_normal(np.zeros(8), C, 20000).reshape(-1, 4, 2)
    a = corners - corners.mean(axis=0)
    angles = []
    for e in samples:  # least-squares rotation of the displaced corners
        b = a + e - e.mean(axis=0)
        H = a.T @ b
        angles.append(math.atan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1]))
    assert rotation_variance(corners, C) == pytest.approx(np.var(angles), rel=0.05)


def test_wrap_angle_of_a_float_is_the_array_arithmetic():
    angles = np.r_[np.random.default_rng(0).uniform(-50, 50, 2000), 0.0, -0.0, 1e-17, -1e-17,
                   math.pi, -math.pi, 2 * math.pi, 7 * math.pi]
    one_by_one = [wrap_angle(float(a)) for a in angles]
    assert all(type(w) is float for w in one_by_one)
    np.testing.assert_array_equal(one_by_one, wrap_angle(angles))


def test_poses_and_points_compose_as_worked_out_by_hand():
    """A car at (1, 2) facing +y (yaw 90 deg): 1 m ahead of it is (1, 3), 1 m to its left
    (vehicle +y) is (0, 2); seen from it, the map point (1, 5) is 3 m straight ahead."""
    car = np.array([1.0, 2.0, math.pi / 2])
    np.testing.assert_allclose(compose(car, [1.0, 0.0, 0.0]), [1.0, 3.0, math.pi / 2],
                               atol=1e-12)
    np.testing.assert_allclose(transform_points(car, [[1.0, 0.0], [0.0, 1.0]]),
                               [[1.0, 3.0], [0.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(inverse_transform_points(car, [[1.0, 5.0]]), [[3.0, 0.0]],
                               atol=1e-12)
    np.testing.assert_allclose(inverse(car), [-2.0, 1.0, -math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(between(car, [1.0, 5.0, math.pi]), [3.0, 0.0, math.pi / 2],
                               atol=1e-12)


def test_wrap_angle_keeps_an_angle_an_ulp_above_pi_at_pi():
    above = math.nextafter(math.pi, 4.0)
    assert wrap_angle(above) == math.pi
    assert np.all(wrap_angle(np.array([above, -math.pi])) == math.pi)


def test_a_pose_covariance_turned_is_the_spread_of_turned_samples():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(3, 3))
    C = A @ A.T * 1e-2
    yaw = 2.2
    samples = rng.multivariate_normal(np.zeros(3), C, size=200_000)
    turned = np.column_stack([samples[:, :2] @ np.array(
        [[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]]), samples[:, 2]])
    np.testing.assert_allclose(rotate_pose_covariance(C, yaw), np.cov(turned.T), atol=3e-4)
    np.testing.assert_allclose(rotate_pose_covariance(rotate_pose_covariance(C, yaw), -yaw), C,
                               atol=1e-15)


def test_the_between_noise_of_a_relative_pose_measured_along_its_start():
    """gtsam's BetweenFactorPose2 compares along the end's axes: measurement noise drawn
    along the start's axes spreads its errors as rotate_pose_covariance(C, -yaw)."""
    import gtsam

    rng = np.random.default_rng(4)
    C = np.diag([0.02, 0.001, 0.0004])
    C[0, 2] = C[2, 0] = 0.0005
    delta = np.array([1.0, 0.3, 1.1])
    factor = gtsam.BetweenFactorPose2(1, 2, gtsam.Pose2(*delta), gtsam.noiseModel.Unit.Create(3))
    values = gtsam.Values()
    values.insert(1, gtsam.Pose2(0.0, 0.0, 0.0))
    errors = []
    for noise in rng.multivariate_normal(np.zeros(3), C, size=20_000):
        values.update(2, gtsam.Pose2(*(delta + noise))) if values.exists(2) else values.insert(
            2, gtsam.Pose2(*(delta + noise)))
        errors.append(factor.unwhitenedError(values))
    np.testing.assert_allclose(np.cov(np.array(errors).T), rotate_pose_covariance(C, -delta[2]),
                               atol=6e-4)
