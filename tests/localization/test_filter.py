"""The localizer's measurement models and Kalman filter."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.geometry import between, compose, inverse_transform_points
from semslam.localization.filter import (
    CtrvFilter,
    Innovation,
    ProcessNoise,
    odometry_measurement,
)
from semslam.localization.measurements import (
    MarkingMeasurement,
    PointMeasurement,
    TagMeasurement,
    stack,
)
from semslam.motion import ctrv_predict

POSE = np.array([3.0, -2.0, 0.7])
NOISE = ProcessNoise(1.0, 0.5, 0.01, 0.001)


def numerical_jacobian(m, pose, eps=1e-6):
    J = np.zeros((len(m.z), 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        J[:, i] = -(m.residual(m.predict(pose + d)[0]) - m.residual(m.predict(pose - d)[0])) / (
            2 * eps
        )
    return J


def test_point_measurement_predicts_vehicle_frame_points_and_its_jacobian_is_right():
    mP = np.array([[5.0, 1.0], [4.0, -3.0]])
    m = PointMeasurement(np.zeros(4), np.eye(4), mP)
    np.testing.assert_allclose(m.predict(POSE)[0], inverse_transform_points(POSE, mP).ravel())
    np.testing.assert_allclose(m.jacobian(POSE), numerical_jacobian(m, POSE), atol=1e-7)


@pytest.mark.parametrize("turn", [0.0, 0.7, -2.5])
def test_point_measurement_linearises_as_its_residual_and_jacobian(turn):
    mP = np.array([[5.0, 1.0], [4.0, -3.0], [-1.0, 7.5]])
    m = PointMeasurement(np.arange(6.0), np.eye(6), mP, turn=turn)
    r, H = m.linearise(POSE)
    np.testing.assert_allclose(r, m.residual(m.predict(POSE)[0]), atol=1e-12)
    np.testing.assert_allclose(H, m.jacobian(POSE), atol=1e-12)
    np.testing.assert_allclose(H, numerical_jacobian(m, POSE), atol=1e-7)


def test_a_turned_point_measurement_is_the_vehicle_frame_one_turned():
    mP = np.array([[5.0, 1.0], [4.0, -3.0]])
    turn = 0.4
    turned = PointMeasurement(np.zeros(4), np.eye(4), mP, turn=turn)
    c, s = np.cos(turn), np.sin(turn)
    plain = inverse_transform_points(POSE, mP) @ np.array([[c, s], [-s, c]])  # R(turn) vP
    np.testing.assert_allclose(turned.predict(POSE)[0], plain.ravel(), atol=1e-12)


def test_the_ekf_update_is_the_same_in_a_turned_measurement_frame():
    mP = np.array([[5.0, 1.0], [4.0, -3.0], [-1.0, 7.5]])
    vR = np.diag([0.01, 0.02, 0.03, 0.01, 0.02, 0.05])
    z = inverse_transform_points(POSE + [0.1, -0.2, 0.03], mP).ravel()
    Q = np.kron(np.eye(3), np.array([[np.cos(POSE[2]), -np.sin(POSE[2])],
                                     [np.sin(POSE[2]), np.cos(POSE[2])]]))  # R(turn) per point
    results = []
    for m in (PointMeasurement(z, vR, mP),
              PointMeasurement(Q @ z, Q @ vR @ Q.T, mP, turn=POSE[2])):
        f = CtrvFilter(np.r_[POSE, 1.0, 0.1], np.diag([0.3, 0.3, 0.01, 0.1, 0.01]), NOISE)
        innovation = f.innovation([m], m.R)
        f.apply(innovation)
        results.append((innovation.nis, f.x, f.P))
    np.testing.assert_allclose(results[0][0], results[1][0], rtol=1e-9)
    np.testing.assert_allclose(results[0][1], results[1][1], atol=1e-12)
    np.testing.assert_allclose(results[0][2], results[1][2], atol=1e-12)


def test_tag_measurement_is_the_relative_pose_and_its_jacobian_is_right():
    mTt = np.array([8.0, 2.0, -2.9])
    m = TagMeasurement(np.zeros(3), np.eye(3), mTt)
    np.testing.assert_allclose(m.predict(POSE)[0], between(POSE, mTt), atol=1e-12)
    np.testing.assert_allclose(m.jacobian(POSE), numerical_jacobian(m, POSE), atol=1e-7)


@pytest.mark.parametrize("pose", [POSE, np.array([-1.0, 4.0, 3.1]), np.array([2.0, 2.0, -3.1])])
def test_tag_measurement_linearises_as_its_residual_and_jacobian(pose):
    m = TagMeasurement(np.array([1.0, -0.5, 3.0]), np.eye(3), np.array([8.0, 2.0, -2.9]))
    r, H = m.linearise(pose)
    np.testing.assert_allclose(r, m.residual(m.predict(pose)[0]), atol=1e-12)
    np.testing.assert_allclose(H, m.jacobian(pose), atol=1e-12)


def test_marking_measurement_measures_across_inside_and_the_end_point_beyond():
    a, b = np.array([[0.0, 0.0]]), np.array([[10.0, 0.0]])
    pose = np.array([2.0, 1.0, 0.3])
    inside = inverse_transform_points(pose, np.array([[4.0, 0.1]]))  # 0.1 m off the line
    m = MarkingMeasurement.build(pose, inside, a, b, 0.05)
    assert len(m.z) == 1 and not m.clamped[0]
    np.testing.assert_allclose(m.predict(pose)[0], [0.1], atol=1e-12)
    np.testing.assert_allclose(m.jacobian(pose), numerical_jacobian(m, pose), atol=1e-7)
    beyond = inverse_transform_points(pose, np.array([[11.0, 0.0]]))  # past the end b
    m = MarkingMeasurement.build(pose, beyond, a, b, 0.05)
    assert len(m.z) == 2 and m.clamped[0]
    np.testing.assert_allclose(m.residual(m.predict(pose)[0]), inverse_transform_points(
        pose, np.array([[11.0, 0.0]]))[0] - inverse_transform_points(pose, b)[0], atol=1e-12)
    np.testing.assert_allclose(m.jacobian(pose), numerical_jacobian(m, pose), atol=1e-7)


@pytest.mark.parametrize("pose", [POSE, np.array([-1.0, 4.0, 3.1])])
def test_marking_measurement_linearises_as_its_residual_and_jacobian(pose):
    # end points inside their marking (one row each) and beyond its end (two rows)
    vE = np.array([[1.0, 0.3], [4.0, 0.2], [6.5, -0.1], [2.0, 1.1]])
    mE = vE @ np.array([[np.cos(pose[2]), np.sin(pose[2])],
                        [-np.sin(pose[2]), np.cos(pose[2])]]) + pose[:2]
    a = mE + [[-1.0, 0.2], [-3.0, 0.1], [-6.0, 0.0], [0.5, -0.3]]
    b = mE + [[2.0, 0.1], [-1.0, 0.3], [-1.5, 0.2], [3.0, 0.1]]
    m = MarkingMeasurement.build(pose, vE, a, b, 0.05, margin=0.1, reach=3.0)
    assert m.clamped.any() and not m.clamped.all()
    r, H = m.linearise(pose)
    np.testing.assert_allclose(r, m.residual(m.predict(pose)[0]), atol=1e-12)
    np.testing.assert_allclose(H, m.jacobian(pose), atol=1e-12)


def test_marking_measurement_takes_a_sigma_per_end_point():
    a, b = np.array([[0.0, 0.0], [0.0, 0.0]]), np.array([[10.0, 0.0], [10.0, 0.0]])
    pose = np.zeros(3)
    ends = np.array([[4.0, 0.1], [11.0, 0.0]])  # one across, one clamped (two rows)
    m = MarkingMeasurement.build(pose, ends, a, b, np.array([0.05, 0.15]), margin=0.1)
    np.testing.assert_allclose(np.diag(m.R), [0.05**2, 0.15**2, 0.15**2])
    scalar = MarkingMeasurement.build(pose, ends, a, b, 0.05, margin=0.1)
    np.testing.assert_allclose(np.diag(scalar.R), [0.05**2] * 3)


def test_sigma_points_reproduce_mean_and_covariance():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 5))
    f = CtrvFilter(np.array([1, 2, 0.3, 2.0, 0.1]), A @ A.T + np.eye(5), NOISE, alpha=0.3)
    X, w = f.sigma_points()
    assert X.shape == (11, 5) and w.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(w @ X, f.x, atol=1e-12)
    d = X - f.x
    np.testing.assert_allclose((d * w[:, None]).T @ d, f.P, atol=1e-10)


@pytest.mark.parametrize("mode", ["ekf", "sigma"])
def test_update_with_points_pulls_the_pose_to_the_truth(mode):
    truth = np.array([0.0, 0.0, 0.0])
    mP = np.array([[3.0, 2.0], [3.0, -2.0], [6.0, 2.0], [6.0, -2.0]])
    z = inverse_transform_points(truth, mP).ravel()
    m = PointMeasurement(z, np.eye(8) * 0.02**2, mP)
    f = CtrvFilter(np.array([0.2, -0.1, 0.03, 1.0, 0.0]), np.diag([0.1, 0.1, 0.01, 1, 1]), NOISE)
    for _ in range(3):
        _, R, ms = stack([m])
        f.apply(f.innovation(ms, R, mode))
    np.testing.assert_allclose(f.pose, truth, atol=5e-3)
    assert np.all(np.linalg.eigvalsh(f.P) > 0)


def test_ekf_and_sigma_agree_on_a_small_step():
    mP = np.array([[5.0, 1.0], [4.0, -3.0]])
    pose = np.array([0.1, 0.0, 0.01])
    m = PointMeasurement(inverse_transform_points(np.zeros(3), mP).ravel(), np.eye(4) * 1e-2,
                         mP)
    f = CtrvFilter(np.array([*pose, 1.0, 0.0]), np.diag([1e-3, 1e-3, 1e-5, 1, 1]), NOISE)
    a = f.innovation([m], m.R, "ekf")
    b = f.innovation([m], m.R, "sigma")
    np.testing.assert_allclose(a.nu, b.nu, atol=1e-4)
    np.testing.assert_allclose(a.S, b.S, rtol=1e-2)
    np.testing.assert_allclose(a.C, b.C, atol=1e-6)


def test_prediction_follows_ctrv_and_grows_the_covariance():
    f = CtrvFilter(np.array([0, 0, 0, 2.0, 0.5]), np.eye(5) * 1e-4, NOISE)
    before = np.linalg.det(f.P[:3, :3])
    f.predict(1.0)
    expected = compose(np.zeros(3), [2 * np.sin(0.5) / 0.5, 2 * (1 - np.cos(0.5)) / 0.5, 0.5])
    np.testing.assert_allclose(f.pose, expected, atol=1e-12)
    assert np.linalg.det(f.P[:3, :3]) > before


def test_odometry_update_pulls_speed_and_yaw_rate():
    f = CtrvFilter(np.array([0, 0, 0, 1.0, 0.0]), np.eye(5), NOISE)
    f.update_odometry(2.0, 0.1, 0.01, 0.001)
    assert f.x[3] == pytest.approx(2.0, abs=1e-3) and f.x[4] == pytest.approx(0.1, abs=1e-5)


def test_covariance_stays_symmetric_positive_definite_over_a_long_drive():
    rng = np.random.default_rng(1)
    f = CtrvFilter(np.array([0, 0, 0, 2.0, 0.1]), np.eye(5) * 0.01, NOISE)
    mP = np.array([[3.0, 2.0], [3.0, -2.0]])
    for k in range(3000):
        f.predict(0.02)
        f.update_odometry(2.0 + rng.normal(0, 0.05), 0.1 + rng.normal(0, 0.005), 0.05, 0.005)
        if k % 5 == 0:
            world = compose(f.pose, [3.0, 0.0, 0.0])[None, :2] + mP - mP.mean(axis=0)
            z = inverse_transform_points(f.pose, world).ravel() + rng.normal(0, 0.03, 4)
            m = PointMeasurement(z, np.eye(4) * 0.03**2, world)
            f.apply(f.innovation([m], m.R, "ekf" if k % 2 else "sigma"))
    np.testing.assert_allclose(f.P, f.P.T, atol=0)
    assert np.all(np.linalg.eigvalsh(f.P) > 0)


def test_odometry_reading_and_its_jacobian_are_right_with_scale_and_bias():
    x = np.array([1.0, 2.0, 0.3, 2.5, 0.2, 0.03, -0.004])
    reading, H = odometry_measurement(x)
    np.testing.assert_allclose(reading, [2.5 * 1.03, 0.2 - 0.004])
    numeric = np.zeros((2, 7))
    for i in range(7):
        d = np.zeros(7)
        d[i] = 1e-6
        numeric[:, i] = (odometry_measurement(x + d)[0] - odometry_measurement(x - d)[0]) / 2e-6
    np.testing.assert_allclose(H, numeric, atol=1e-8)
    reading5, H5 = odometry_measurement(x[:5])  # the 5-state filter reads v and yaw_rate
    np.testing.assert_allclose(reading5, [2.5, 0.2])
    np.testing.assert_allclose(H5, np.eye(5)[3:5])


def test_sigma_points_of_the_seven_state_filter_reproduce_mean_and_covariance():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(7, 7))
    f = CtrvFilter(np.array([1, 2, 0.3, 2.0, 0.1, 0.01, 1e-3]), A @ A.T + np.eye(7), NOISE)
    X, w = f.sigma_points()
    assert X.shape == (15, 7) and w.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(w @ X, f.x, atol=1e-12)
    d = X - f.x
    np.testing.assert_allclose((d * w[:, None]).T @ d, f.P, atol=1e-10)


def test_a_filter_of_the_wrong_size_is_refused():
    with pytest.raises(ValueError, match="5 or 7"):
        CtrvFilter(np.zeros(6), np.eye(6), NOISE)


def _drive_with_fixes(x0, P0, scale, bias, fixes_until, seconds, seed=3):
    """A 2 m/s drive on a gentle S-curve: odometry at 50 Hz with a wheel-speed scale error
    and a gyro bias, the true position fixed to 2 cm at 10 Hz until ``fixes_until`` s, then
    dead reckoning. Returns the filter and the final position error (m)."""
    rng = np.random.default_rng(seed)
    noise = ProcessNoise(1.0, 0.5, 0.0, 0.0, 1e-4, 1e-5)
    truth = np.array([0.0, 0.0, 0.0, 2.0, 0.0])
    f = CtrvFilter(x0, P0, noise)
    for k in range(round(seconds * 50)):
        t = k / 50
        truth[4] = 0.15 * np.sin(0.3 * t)
        truth = ctrv_predict(truth, 0.02)
        f.predict(0.02)
        f.update_odometry(truth[3] * (1 + scale) + rng.normal(0, 0.03),
                          truth[4] + bias + rng.normal(0, 0.003), 0.03, 0.003)
        if k % 5 == 0 and t < fixes_until:
            mP = truth[None, :2] + np.array([[3.0, 2.0], [3.0, -2.0], [-2.0, 2.0]])
            z = inverse_transform_points(truth[:3], mP).ravel() + rng.normal(0, 0.02, 6)
            m = PointMeasurement(z, np.eye(6) * 0.02**2, mP)
            f.apply(f.innovation([m], m.R, "ekf"))
    return f, float(np.hypot(*(f.pose[:2] - truth[:2])))


def test_the_seven_state_filter_learns_the_wheel_scale_and_gyro_bias():
    scale, bias = 0.03, 0.004
    P7 = np.diag([1e-4, 1e-4, 1e-6, 0.01, 0.01, 0.05**2, 0.01**2])
    f7, coasted7 = _drive_with_fixes(np.array([0, 0, 0, 2.0, 0, 0, 0]), P7, scale, bias, 40, 40)
    assert f7.x[5] == pytest.approx(scale, abs=0.003)
    assert f7.x[6] == pytest.approx(bias, abs=5e-4)
    assert np.sqrt(f7.P[5, 5]) < 0.01 and np.sqrt(f7.P[6, 6]) < 2e-3
    # then 10 s without fixes: the learnt errors are taken out of the dead reckoning
    _, coasted7 = _drive_with_fixes(np.array([0, 0, 0, 2.0, 0, 0, 0]), P7, scale, bias, 40, 50)
    _, coasted5 = _drive_with_fixes(np.array([0, 0, 0, 2.0, 0]), P7[:5, :5], scale, bias, 40, 50)
    assert coasted7 < 0.25 * coasted5


@pytest.mark.parametrize("calibrated", [False, True])
def test_exact_odometry_samples_are_dead_reckoned_exactly(calibrated):
    """Wheel speed and gyro hold each sample until the next: a change of rate must not
    move the pose already travelled (noise entering at the start of the step would turn
    every change of the yaw rate into a heading error of dt times that change)."""
    dt, n = 0.02, 500
    t = np.arange(n) * dt
    speed, rate = 2.0 + 0.5 * np.sin(t), 0.4 * np.sin(1.3 * t)
    truth = np.array([0.0, 0.0, 0.0, speed[0], rate[0]])
    x0 = np.array([0.0, 0.0, 0.0, speed[0], rate[0], 0.0, 0.0][: 7 if calibrated else 5])
    P0 = np.diag([1e-6, 1e-6, 1e-8, 1e-4, 1e-4, 1e-4, 1e-6][: len(x0)])
    f = CtrvFilter(x0, P0, NOISE)
    for k in range(1, n):
        truth = ctrv_predict(np.array([*truth[:3], speed[k - 1], rate[k - 1]]), dt)
        f.predict(dt)
        f.update_odometry(speed[k], rate[k], 1e-4, 1e-5)
    # with scale and bias states, rate changes leak a little into them (the readings alone
    # cannot tell them apart): within 0.05 % of the 19 m driven and 1e-4 rad (noise at the
    # start of the step: 3e-3 rad here)
    np.testing.assert_allclose(f.pose[:2], truth[:2], atol=0.01 if calibrated else 2e-4)
    assert abs(f.pose[2] - truth[2]) < (1e-4 if calibrated else 1e-5)


def test_the_innovation_solves_positive_definite_and_indefinite_systems_alike():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(12, 12))
    C, nu = rng.normal(size=(5, 12)), rng.normal(size=12)
    for S in (A @ A.T + np.eye(12), A + A.T):  # Cholesky, and the LU fallback
        innovation = Innovation(nu, S, C)
        np.testing.assert_allclose(innovation.nis, nu @ np.linalg.solve(S, nu), rtol=1e-9)
        np.testing.assert_allclose(innovation.gain, C @ np.linalg.inv(S), rtol=1e-8, atol=1e-12)


def test_a_sigma_point_update_with_a_very_uncertain_heading_stays_positive_definite():
    """Sigma points more than pi from the mean in yaw (a lost filter): the offsets are not
    wrapped, so the update's cross-covariance is that of P and the posterior stays positive."""
    rng = np.random.default_rng(0)
    m = TagMeasurement(np.array([3.0, 1.0, 0.2]), np.diag([0.05**2, 0.05**2, 0.01**2]),
                       np.array([5.0, 4.0, 1.0]))
    for _ in range(20):
        A = rng.normal(size=(5, 5))
        P = A @ A.T * 0.5 + np.eye(5) * 1e-6
        P[2, :] *= 2
        P[:, 2] *= 2  # yaw sigma 2-5 rad
        f = CtrvFilter(np.array([0.0, 0.0, rng.uniform(-3, 3), 2.0, 0.1]), P, NOISE)
        f.apply(f.innovation([m], m.R, "sigma"))
        eigenvalues = np.linalg.eigvalsh(f.P)
        assert eigenvalues.min() > -1e-9 * eigenvalues.max()
