import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from semslam.motion import ctrv_jacobian, ctrv_predict, integrate_odometry


def _numerical_jacobian(f, x, eps=1e-6):
    J = np.zeros((len(f(x)), len(x)))
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        diff = f(x + d) - f(x - d)
        diff[2] = (diff[2] + math.pi) % (2 * math.pi) - math.pi
        J[:, i] = diff / (2 * eps)
    return J


@pytest.mark.parametrize("w", [0.5, -0.3, 1e-3, 1e-9, 0.0])
def test_ctrv_against_numerical_integration(w):
    state = np.array([1.0, -2.0, 0.4, 2.0, w])
    dt = 0.7

    def rhs(_, s):
        return [s[3] * math.cos(s[2]), s[3] * math.sin(s[2]), s[4], 0.0, 0.0]

    sol = solve_ivp(rhs, (0, dt), state, rtol=1e-11, atol=1e-12)
    assert np.allclose(ctrv_predict(state, dt)[:2], sol.y[:2, -1], atol=1e-8)


@given(st.floats(-3, 3), st.floats(0, 3), st.floats(-1.0, 1.0), st.sampled_from([0.02, 0.1, 0.5]))
def test_ctrv_jacobian_matches_numerical(yaw, v, w, dt):
    state = np.array([0.5, 1.5, yaw, v, w])
    J = ctrv_jacobian(state, dt)
    Jn = _numerical_jacobian(lambda s: ctrv_predict(s, dt), state)
    assert np.allclose(J, Jn, atol=1e-5)


def test_ctrv_jacobian_continuous_through_zero_turn():
    s = np.array([0.0, 0.0, 0.3, 2.0, 0.0])
    a = ctrv_jacobian(s, 0.1)
    b = ctrv_jacobian(s + [0, 0, 0, 0, 1e-4], 0.1)
    assert np.allclose(a, b, atol=1e-4)


def test_integrate_odometry_full_circle():
    # 1 m/s at 0.5 rad/s for one full turn comes back to the start
    n = 1001
    dt = 2 * math.pi / 0.5 / (n - 1)
    t = np.arange(n) * dt
    poses = integrate_odometry([1.0, 2.0, 0.0], t, np.ones(n), np.full(n, 0.5))
    assert np.allclose(poses[-1, :2], [1.0, 2.0], atol=1e-6)
    radius = np.linalg.norm(poses[:, :2] - [1.0, 4.0], axis=1)
    assert np.allclose(radius, 2.0, atol=1e-9)


@pytest.mark.parametrize("w", [5e-6, 1e-4, 3e-3, 2e-2])
def test_ctrv_jacobian_accurate_for_tiny_turns(w):
    # found by hypothesis: a turn of 2.5e-6 rad over the step lost the yaw-rate column
    state = np.array([0.5, 1.5, 1.0, 1.0, w])
    J = ctrv_jacobian(state, 0.5)
    Jn = _numerical_jacobian(lambda s: ctrv_predict(s, 0.5), state)
    assert np.allclose(J, Jn, atol=1e-7)
