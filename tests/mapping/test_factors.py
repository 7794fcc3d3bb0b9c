import gtsam
import numpy as np
import pytest

from semslam.mapping.factors import (
    calibrated_odometry_residual,
    custom_factor,
    marking_observation_residual,
    point_in_pose,
    same_line_residual,
    slot_observation_residual,
    slot_shape_residual,
)
from semslam.mapping.odometry import calibration_jacobian, odometry_between
from semslam.motion import ctrv_jacobian, ctrv_predict, integrate_odometry

X, C = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.C


def _numerical(residual, values, key, eps=1e-6):
    base = values
    if values.exists(key) and isinstance(_value(values, key), gtsam.Pose2):
        dim, step = 3, lambda v, d: v.retract(d)
    else:
        dim, step = 2, lambda v, d: np.asarray(v) + d
    cols = []
    for k in range(dim):
        d = np.zeros(dim)
        d[k] = eps
        vp, vm = gtsam.Values(base), gtsam.Values(base)
        vp.update(key, step(_value(base, key), d))
        vm.update(key, step(_value(base, key), -d))
        cols.append((residual(vp, False)[0] - residual(vm, False)[0]) / (2 * eps))
    return np.stack(cols, axis=1)


def _value(values, key):
    for getter in (values.atPose2, values.atPoint2, values.atVector):
        try:
            return getter(key)
        except RuntimeError:
            continue
    raise KeyError(key)


@pytest.fixture
def slot_values():
    rng = np.random.default_rng(0)
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose2(1.0, -2.0, 0.7))
    corners = np.array([[3.0, 1.0], [5.5, 1.1], [5.4, 6.0], [2.9, 6.1]]) + rng.normal(
        0, 0.05, (4, 2)
    )
    for k in range(4):
        values.insert(C(k), corners[k])
    return values


def test_point_in_pose_matches_gtsam(slot_values):
    pose = slot_values.atPose2(X(0))
    q, _, _ = point_in_pose(pose, slot_values.atPoint2(C(0)))
    assert np.allclose(q, pose.transformTo(slot_values.atPoint2(C(0))))


def test_slot_observation_jacobians_are_numerically_right(slot_values):
    z = np.zeros((4, 2))
    res = slot_observation_residual(X(0), [C(k) for k in range(4)], z)
    _, J = res(slot_values, True)
    for key in [X(0)] + [C(k) for k in range(4)]:
        assert np.allclose(J[key], _numerical(res, slot_values, key), atol=1e-6)


@pytest.mark.parametrize("right_angles", [True, False])
def test_slot_shape_jacobians_are_numerically_right(slot_values, right_angles):
    res = slot_shape_residual([C(k) for k in range(4)], right_angles, 2.5, 5.0)
    r, J = res(slot_values, True)
    assert r.shape == ((5,) if right_angles else (4,))
    for k in range(4):
        assert np.allclose(J[C(k)], _numerical(res, slot_values, C(k)), atol=1e-6)


def test_shape_residual_zero_for_a_perfect_rectangle():
    values = gtsam.Values()
    for k, c in enumerate([[0, 0], [2.5, 0], [2.5, 5], [0, 5]]):
        values.insert(C(k), np.array(c, dtype=float))
    r, _ = slot_shape_residual([C(k) for k in range(4)], True, 2.5, 5.0)(values, False)
    assert np.allclose(r, 0.0)


def test_custom_factor_linearizes_with_the_analytic_jacobian(slot_values):
    z = np.array([[2.0, 1.0], [2.0, -1.5], [7.0, -1.5], [7.0, 1.0]])
    res = slot_observation_residual(X(0), [C(k) for k in range(4)], z)
    factor = custom_factor(
        [X(0)] + [C(k) for k in range(4)], res, gtsam.noiseModel.Isotropic.Sigma(8, 0.05)
    )
    r, _ = res(slot_values, False)
    assert factor.error(slot_values) == pytest.approx(0.5 * np.sum((r / 0.05) ** 2))


def test_odometry_between_matches_dead_reckoning_and_grows():
    t = np.arange(0, 10.0, 0.02)
    v = np.full_like(t, 2.0)
    w = np.where(t < 5, 0.0, 0.3)
    poses = integrate_odometry([0, 0, 0], t, v, w)
    i, j = 100, 400
    rel, cov = odometry_between(t, v, w, t[i], t[j], 0.03, 0.01, 0.003)
    expected = gtsam.Pose2(*poses[i]).between(gtsam.Pose2(*poses[j]))
    assert np.allclose(rel, [expected.x(), expected.y(), expected.theta()], atol=1e-9)
    _, cov_short = odometry_between(t, v, w, t[i], t[i + 50], 0.03, 0.01, 0.003)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert np.trace(cov) > np.trace(cov_short)


def _covariance_by_5x5_jacobians(t, v, w, t_start, t_end, sv0, s_scale, sw):
    """The odometry covariance propagated with full CTRV Jacobian matrices, step by step
    (what :func:`odometry_between` writes out in floats)."""
    first = max(int(np.searchsorted(t, t_start, side="right")) - 1, 0)
    state, P, now, i = np.zeros(5), np.zeros((3, 3)), t_start, first
    while now < t_end - 1e-12 and i < len(t):
        nxt = t[i + 1] if i + 1 < len(t) else t_end
        dt = min(nxt, t_end) - now
        state[3:] = v[i], w[i]
        F5 = ctrv_jacobian(state, dt)
        F, G = F5[:3, :3], F5[:3, 3:]
        sv = np.hypot(sv0, s_scale * v[i])
        P = F @ P @ F.T + G @ np.diag([sv * sv, sw * sw]) @ G.T
        state = ctrv_predict(state, dt)
        now, i = min(nxt, t_end), i + 1
    return P


@pytest.mark.parametrize("t_start, t_end", [(1.01, 7.33), (0.0, 0.5), (9.5, 10.4), (3.0, 3.0)])
def test_odometry_covariance_is_the_ctrv_jacobian_propagation(t_start, t_end):
    t = np.arange(0, 10.0, 0.02)
    v = 2.0 + np.sin(t)
    w = 0.4 * np.sin(0.7 * t)
    _, cov = odometry_between(t, v, w, t_start, t_end, 0.03, 0.01, 0.003)
    expected = _covariance_by_5x5_jacobians(t, v, w, t_start, t_end, 0.03, 0.01, 0.003)
    assert np.allclose(cov, expected + np.eye(3) * 1e-10, rtol=1e-9, atol=1e-15)


def test_calibrated_odometry_jacobians_and_zero_at_truth():
    K = gtsam.symbol_shorthand.K
    t = np.arange(0, 1.0, 0.02)
    v, w = np.full_like(t, 2.0), np.full_like(t, 0.4)
    delta, _ = odometry_between(t, v, w, 0.0, 0.5, 0, 0, 0)
    J = calibration_jacobian(t, v, w, 0.0, 0.5)
    true_scale, true_bias = 1.02, 0.01
    true_delta, _ = odometry_between(t, v * true_scale, w - true_bias, 0.0, 0.5, 0, 0, 0)
    values = gtsam.Values()
    a = gtsam.Pose2(1.0, 2.0, 0.3)
    values.insert(X(0), a)
    values.insert(X(1), a.compose(gtsam.Pose2(*true_delta)))
    values.insert(K(0), np.array([true_scale, true_bias]))
    res = calibrated_odometry_residual(X(0), X(1), K(0), delta, J)
    r, H = res(values, True)
    assert np.allclose(r, 0.0, atol=2e-4)  # first-order model of the calibration
    values.update(X(1), a.compose(gtsam.Pose2(0.9, 0.1, 0.25)))
    _, H = res(values, True)
    for key in (X(0), X(1)):
        assert np.allclose(H[key], _numerical(res, values, key), atol=1e-6)
    eps = 1e-6
    num = np.zeros((3, 2))
    for k in range(2):
        d = np.zeros(2)
        d[k] = eps
        vp, vm = gtsam.Values(values), gtsam.Values(values)
        vp.update(K(0), values.atVector(K(0)) + d)
        vm.update(K(0), values.atVector(K(0)) - d)
        num[:, k] = (res(vp, False)[0] - res(vm, False)[0]) / (2 * eps)
    assert np.allclose(H[K(0)], num, atol=1e-6)


L = gtsam.symbol_shorthand.L


def test_marking_observation_jacobians_are_numerically_right_and_zero_on_the_line():
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose2(1.0, -2.0, 0.7))
    anchor = np.array([4.0, 3.0])
    values.insert(L(0), np.array([0.4, 0.3]))
    e = np.array([[2.0, 1.5], [6.0, -0.5]])
    res = marking_observation_residual(X(0), L(0), anchor, e)
    r, J = res(values, True)
    for key in (X(0), L(0)):
        assert np.allclose(J[key], _numerical(res, values, key), atol=1e-6)
    # end points placed exactly on the line give zero residual
    pose, n = gtsam.Pose2(1.0, -2.0, 0.7), np.array([np.cos(0.4), np.sin(0.4)])
    foot, u = anchor + 0.3 * n, np.array([-n[1], n[0]])
    on_line = np.array([pose.transformTo(foot + s * u) for s in (-2.0, 5.0)])
    r, _ = marking_observation_residual(X(0), L(0), anchor, on_line)(values, False)
    assert np.allclose(r, 0, atol=1e-12)


@pytest.mark.parametrize("theta_b", [0.45, 0.45 + np.pi])
def test_same_line_jacobians_are_numerically_right_for_both_normal_directions(theta_b):
    values = gtsam.Values()
    values.insert(L(0), np.array([0.4, 0.3]))
    values.insert(L(1), np.array([theta_b, -0.2]))
    res = same_line_residual(L(0), np.array([4.0, 3.0]), L(1), np.array([9.0, 1.0]))
    r, J = res(values, True)
    assert abs(r[0]) < 0.1  # flipped normals are the same line direction
    for key in (L(0), L(1)):
        assert np.allclose(J[key], _numerical(res, values, key), atol=1e-6)
