import math

import gtsam
import numpy as np
import pytest

from semslam.mapping.maxmix import (
    Component,
    MaxMixture,
    NullHypothesis,
    choose_component,
    component_constants,
    is_null_chosen,
    mixture_cost,
    null_hypothesis_loss,
    null_hypothesis_noise,
)

X = gtsam.symbol_shorthand.X


def test_constants_use_log_det_and_weight_once():
    c = component_constants([0.5, 0.25], [math.log(4.0), math.log(4.0)])
    assert c == pytest.approx([0.0, math.log(2.0)])
    c = component_constants([0.5, 0.5], [0.0, math.log(100.0)])
    assert c == pytest.approx([0.0, 0.5 * math.log(100.0)])


def test_choice_minimises_negative_log_likelihood():
    assert choose_component([1.0, 100.0], [0.0, 5.0]) == 0
    assert choose_component([100.0, 1.0], [0.0, 5.0]) == 1
    assert choose_component([12.0, 0.0], [0.0, 5.0]) == 1  # 6 > 5


def test_null_loss_is_continuous_and_matches_mixture_cost():
    null = NullHypothesis(0.01, 1e-4)
    weight, loss = null_hypothesis_loss(null, 3)
    consts = component_constants([0.99, 0.01], [0.0, -3 * math.log(1e-4)])
    for r in np.linspace(0, 30, 301):
        assert loss(r) == pytest.approx(mixture_cost([r * r, 1e-4 * r * r], consts))
    switch = math.sqrt(null.switch_chi2(3))
    assert loss(switch - 1e-6) == pytest.approx(loss(switch + 1e-6), abs=1e-5)
    assert weight(switch - 0.01) == 1.0 and weight(switch + 0.01) == pytest.approx(1e-4)


def _offset_residual(key_a, key_b, measured):
    """r = (b - a) - measured for Point2 variables: J_a = -I, J_b = I."""

    def residual(values, want):
        r = values.atPoint2(key_b) - values.atPoint2(key_a) - measured
        return r, ({key_a: -np.eye(2), key_b: np.eye(2)} if want else None)

    return residual


def _numerical_jacobian(mix, values, key, eps=1e-6):
    num = np.zeros((mix.dim + 1, 2))
    for k in range(2):
        d = np.zeros(2)
        d[k] = eps
        vp, vm = gtsam.Values(values), gtsam.Values(values)
        vp.update(key, values.atPoint2(key) + d)
        vm.update(key, values.atPoint2(key) - d)
        num[:, k] = (mix.evaluate(vp, False)[1] - mix.evaluate(vm, False)[1]) / (2 * eps)
    return num


def test_mixture_factor_error_continuous_and_jacobian_numerical():
    m = np.array([1.0, 0.0])
    comps = [
        Component(_offset_residual(X(0), X(1), m), np.eye(2) * 10, 0.9),
        Component(_offset_residual(X(0), X(2), m), np.eye(2) * 10, 0.09),
        Component(_offset_residual(X(0), X(1), m), np.eye(2) * 0.01, 0.01),
    ]
    mix = MaxMixture([X(0), X(1), X(2)], [2, 2, 2], comps)
    factor = mix.factor()
    values = gtsam.Values()
    values.insert(X(0), np.array([0.0, 0.0]))
    values.insert(X(1), np.array([1.02, 0.01]))
    values.insert(X(2), np.array([1.0, 0.0]))
    assert mix.chosen(values) == 0
    _, _, H = mix.evaluate(values, True)
    for key in (X(0), X(1), X(2)):
        assert np.allclose(H[key], _numerical_jacobian(mix, values, key), atol=1e-6)
    assert np.allclose(H[X(2)], 0.0)  # not used by the chosen component
    # the gtsam factor reports the same error as the mixture cost
    assert factor.error(values) == pytest.approx(0.5 * 100 * (0.02**2 + 0.01**2))
    # moving X1 away switches to X2, then moving X2 away to null; the error stays continuous
    errors = []
    for x in np.linspace(1.0, 6.0, 2001):
        values.update(X(1), np.array([x, 0.0]))
        errors.append(factor.error(values))
    assert np.max(np.abs(np.diff(errors))) < 0.3
    assert mix.chosen(values) == 1
    values.update(X(2), np.array([30.0, 0.0]))
    assert mix.chosen(values) == 2


def test_null_noise_model_on_native_factor_rejects_outlier():
    graph = gtsam.NonlinearFactorGraph()
    prior = gtsam.noiseModel.Isotropic.Sigma(3, 0.01)
    graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), prior))
    cov = np.diag([0.1, 0.1, 0.01]) ** 2
    null = NullHypothesis(0.01, 1e-6)
    graph.add(
        gtsam.BetweenFactorPose2(
            X(0), X(1), gtsam.Pose2(1, 0, 0), gtsam.noiseModel.Gaussian.Covariance(cov)
        )
    )
    outlier = gtsam.BetweenFactorPose2(
        X(0), X(1), gtsam.Pose2(5, 3, 1), null_hypothesis_noise(cov, null)
    )
    inlier = gtsam.BetweenFactorPose2(
        X(0), X(1), gtsam.Pose2(1.05, 0, 0), null_hypothesis_noise(cov, null)
    )
    graph.add(outlier)
    graph.add(inlier)
    init = gtsam.Values()
    init.insert(X(0), gtsam.Pose2())
    init.insert(X(1), gtsam.Pose2(1, 0, 0))
    result = gtsam.LevenbergMarquardtOptimizer(graph, init).optimize()
    assert result.atPose2(X(1)).x() == pytest.approx(1.025, abs=1e-3)
    assert is_null_chosen(outlier, result, null)
    assert not is_null_chosen(inlier, result, null)
