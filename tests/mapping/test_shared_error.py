"""The covariance of slot corners mapped from detections whose error every sighting shares."""

import gtsam
import numpy as np
import pytest

from semslam.mapping.factors import custom_factor, slot_observation_residual
from semslam.mapping.graph import VAGUE_SIGMA, Graph
from semslam.mapping.shared_error import (
    SlotSightingFactor,
    has_shared_error,
    own_sigma,
    sandwich_covariances,
)
from semslam.types import SlotKind, SlotObservation

X = gtsam.symbol_shorthand.X
C = gtsam.symbol_shorthand.C

CORNERS = np.array([[4.0, 1.0], [4.0, -1.5], [9.0, -1.5], [9.0, 1.0]])  # map frame, m


def _four(sigma):
    return None if sigma is None else (sigma,) * 4 if np.isscalar(sigma) else tuple(sigma)


def _seen_from(weights, own=None, shared=None, slots: int = 1, pose_sigma: float = 1e-6,
               headings=None):
    """A graph whose keyframes (one per entry of ``weights``, known to ``pose_sigma``, headed
    ``headings[k]``, default 0) each see ``slots`` slots (the same corners, landmarks
    0..slots-1) with corner sigma ``weights[k]``; and the sightings."""
    graph = Graph()
    sightings = []
    headings = np.zeros(len(weights)) if headings is None else np.asarray(headings, float)
    poses = [np.array([0.3 * k, 0.0, headings[k]]) for k in range(len(weights))]
    for k, pose in enumerate(poses):
        graph.add_pose(X(k), pose)
        graph.add_factor(gtsam.PriorFactorPose2(X(k), gtsam.Pose2(*pose),
                                                gtsam.noiseModel.Isotropic.Sigma(3, pose_sigma)))
    for slot in range(slots):
        keys = [C(4 * slot + c) for c in range(4)]
        for key, corner in zip(keys, CORNERS, strict=True):
            graph.add_point(key, corner)
        for k, weight in enumerate(weights):
            c, s = np.cos(poses[k][2]), np.sin(poses[k][2])
            seen = (CORNERS - poses[k][:2]) @ np.array([[c, -s], [s, c]])  # keyframe k's frame
            obs = SlotObservation(seen, SlotKind.PERPENDICULAR, None, 0.0, 1.0, weight,
                                  corner_sigma_own=_four(own), corner_sigma_shared=_four(shared))
            index = graph.add_factor(custom_factor(
                [X(k), *keys], slot_observation_residual(X(k), keys, seen),
                gtsam.noiseModel.Isotropic.Sigma(8, weight)))
            sightings.append(SlotSightingFactor(index, k, slot, obs, weight))
    graph.optimize_batch()
    return graph, sightings


VAGUE = VAGUE_SIGMA**-2  # the information of the vague prior every unknown gets


def _weighted_mean_variance(weights, own, shared) -> np.ndarray:
    """Per corner: the variance of a mean weighted by w_i^-2 of sightings with own noise o_i
    (per corner) and a shared error s, beside the vague prior (a measurement of sigma
    VAGUE_SIGMA whose residual, like the others', spreads as it says)."""
    inv = np.asarray(weights, float) ** -2
    own = np.broadcast_to(np.asarray(own, float), (len(inv), 4))
    spread = (inv**2) @ own**2 + np.asarray(shared, float) ** 2 * inv.sum() ** 2 + VAGUE
    return spread / (inv.sum() + VAGUE) ** 2


def _sandwich(graph, sightings, landmarks=(0,), resolve=lambda i: i, chunk=256):
    other, columns = graph.jacobian([s.index for s in sightings])
    return sandwich_covariances(sightings, other, columns, graph.estimate, X, C, resolve,
                                list(landmarks), chunk)


def test_with_the_weights_the_truth_the_sandwich_is_the_graphs_marginal():
    """No shared error and each sighting's own sigma its weight: H^-1 M H^-1 = H^-1, the
    marginal gtsam computes (here with poses known only to 0.05 m / rad)."""
    graph, sightings = _seen_from([0.05, 0.08, 0.12], pose_sigma=0.05)
    joint = graph.marginals().jointMarginalCovariance([C(c) for c in range(4)]).fullMatrix()
    np.testing.assert_allclose(_sandwich(graph, sightings)[0], joint, rtol=1e-6, atol=1e-12)


def test_a_shared_error_does_not_average_away():
    """Weighted alike, n sightings with own noise o and a shared error s: their mean, whose
    variance is o^2 / n + s^2 per axis, however large the weight."""
    n, own, shared = 25, 0.04, 0.03
    graph, sightings = _seen_from([0.30] * n, own, shared)
    cov = _sandwich(graph, sightings)[0]
    assert np.diag(cov) == pytest.approx(own**2 / n + shared**2, rel=3e-3)
    expected = _weighted_mean_variance([0.3] * n, own, shared)
    np.testing.assert_allclose(np.diag(cov), np.repeat(expected, 2), rtol=1e-6)
    alone = _sandwich(*_seen_from([0.30] * n, own, None))[0]
    assert np.diag(alone) == pytest.approx(own**2 / n, rel=3e-3)


def test_the_shared_error_is_one_in_the_map_frame_from_every_side():
    """Sightings from opposite sides see the slot's shared (map-frame) error turned by 180
    degrees in their own frames; it does not cancel in their mean."""
    n, own, shared = 8, 0.02, 0.03
    both_ways = _seen_from([0.3] * n, own, shared, headings=[0.0, np.pi] * (n // 2))
    cov = _sandwich(*both_ways)[0]
    expected = _weighted_mean_variance([0.3] * n, own, shared)
    np.testing.assert_allclose(np.diag(cov), np.repeat(expected, 2), rtol=1e-6)
    turned = _sandwich(*_seen_from([0.3] * n, own, shared, headings=[0.7] * n))[0]
    np.testing.assert_allclose(turned, cov, rtol=1e-6, atol=1e-12)


def test_unequal_weights_give_the_weighted_means_variance():
    """Weights w_i, own noise o_i: the estimate is the mean weighted by 1 / w_i^2, its
    variance sum a_i^2 o_i^2 + s^2 with a_i = w_i^-2 / sum w^-2."""
    weights, own, shared = np.array([0.1, 0.2, 0.4]), np.array([0.05, 0.01, 0.02]), 0.02
    graph, sightings = _seen_from(list(weights), None, shared)
    sightings = [SlotSightingFactor(s.index, s.keyframe, s.landmark,
                                    SlotObservation(s.observation.vCorners, s.observation.kind,
                                                    None, 0.0, 1.0, s.sigma,
                                                    corner_sigma_own=(o,) * 4,
                                                    corner_sigma_shared=(shared,) * 4), s.sigma)
                 for s, o in zip(sightings, own, strict=True)]
    expected = _weighted_mean_variance(weights, own[:, None], shared)
    np.testing.assert_allclose(np.diag(_sandwich(graph, sightings)[0]), np.repeat(expected, 2),
                               rtol=1e-6)


def test_each_corner_has_its_own_errors():
    """Rear corners with larger errors (placed by the slot's depth) get larger variances;
    the corners of one slot are uncorrelated when the poses are known."""
    own, shared = (0.02, 0.02, 0.04, 0.04), (0.01, 0.01, 0.03, 0.0)
    cov = _sandwich(*_seen_from([0.3] * 4, own, shared))[0]
    expected = _weighted_mean_variance([0.3] * 4, own, shared)
    np.testing.assert_allclose(np.diag(cov), np.repeat(expected, 2), rtol=1e-6)
    np.testing.assert_allclose(cov - np.diag(np.diag(cov)), 0.0, atol=1e-9)


def test_merged_landmarks_share_one_error_and_chunks_change_nothing():
    """Two landmarks of one slot, tied as the mapper merges duplicates (0.005 m): with one
    shared error between their sightings (resolve) it does not average over the two as two
    errors would; solving one landmark at a time gives the same covariances."""
    n, own, shared = 6, 0.02, 0.03
    graph, sightings = _seen_from([0.3] * n, own, shared, slots=2)
    tie = gtsam.noiseModel.Isotropic.Sigma(2, 0.005)
    for c in range(4):
        graph.add_factor(gtsam.BetweenFactorPoint2(C(c), C(4 + c), np.zeros(2), tie))
    graph.optimize_batch()
    separate = _sandwich(graph, sightings, (0, 1))
    merged = _sandwich(graph, sightings, (0, 1), resolve=lambda i: 0)
    assert np.diag(separate[0]) == pytest.approx(own**2 / (2 * n) + shared**2 / 2, rel=0.02)
    assert np.diag(merged[0]) == pytest.approx(own**2 / (2 * n) + shared**2, rel=0.02)
    one_at_a_time = _sandwich(graph, sightings, (0, 1), resolve=lambda i: 0, chunk=1)
    for i in (0, 1):
        np.testing.assert_allclose(one_at_a_time[i], merged[i], rtol=1e-6, atol=1e-12)


def test_sightings_on_the_null_hypothesis_weigh_nothing():
    graph, sightings = _seen_from([0.3] * 10, 0.04, None)
    half = [SlotSightingFactor(s.index, s.keyframe, None if s.keyframe >= 5 else 0,
                               s.observation, s.sigma) for s in sightings]
    np.testing.assert_allclose(np.diag(_sandwich(graph, half)[0]),
                               np.repeat(_weighted_mean_variance([0.3] * 5, 0.04, 0.0), 2),
                               rtol=1e-6)


def test_own_sigma_is_the_declared_one_else_the_weight():
    """A sighting weighted at 0.3 / sqrt(0.5) (its confidence) declaring an own error of
    0.05 m: 0.05 m (a measured error, over detections of every confidence); declaring only a
    shared error: its weight."""
    obs = SlotObservation(CORNERS, SlotKind.PERPENDICULAR, None, 0.0, 0.5, 0.30,
                          corner_sigma_own=(0.05,) * 4, corner_sigma_shared=(0.02,) * 4)
    weight = 0.30 / np.sqrt(0.5)
    np.testing.assert_allclose(own_sigma(SlotSightingFactor(0, 0, 0, obs, weight)), 0.05)
    shared_only = SlotObservation(CORNERS, SlotKind.PERPENDICULAR, None, 0.0, 0.5, 0.30,
                                  corner_sigma_shared=(0.02,) * 4)
    np.testing.assert_allclose(own_sigma(SlotSightingFactor(0, 0, 0, shared_only, weight)),
                               weight)
    assert has_shared_error(obs) and has_shared_error(shared_only)
    assert not has_shared_error(SlotObservation(CORNERS, SlotKind.PERPENDICULAR, None, 0.0,
                                                1.0, 0.3))


def test_the_jacobian_columns_are_gtsams():
    """The graph's sparse Jacobian: A^T A is the Hessian gtsam builds from the same graph."""
    graph, _ = _seen_from([0.1, 0.2], pose_sigma=0.05)
    A, columns = graph.jacobian()
    keys = sorted(columns)
    ordering = gtsam.Ordering()
    for key in keys:
        ordering.push_back(key)
    linear = graph.factors.linearize(graph.estimate)
    for key in keys:  # the vague priors jacobian() adds
        dim = 3 if gtsam.Symbol(key).chr() == ord("x") else 2
        linear.add(gtsam.JacobianFactor(key, np.eye(dim) / VAGUE_SIGMA, np.zeros(dim),
                                        gtsam.noiseModel.Unit.Create(dim)))
    hessian, _ = linear.hessian(ordering)
    np.testing.assert_allclose((A.T @ A).toarray(), hessian, rtol=1e-9, atol=1e-9)
    assert [columns[k] for k in keys] == sorted(columns.values())


def test_a_landmark_never_seen_has_no_error_of_its_own():
    """A slot whose sightings all went to the null hypothesis is still answered: its vague
    prior (VAGUE_SIGMA)."""
    graph, sightings = _seen_from([0.3] * 3, 0.02, 0.01, slots=2)
    kept = [s if s.landmark == 0 else SlotSightingFactor(s.index, s.keyframe, None,
                                                         s.observation, s.sigma)
            for s in sightings]
    cov = _sandwich(graph, kept, (0, 1))
    np.testing.assert_allclose(np.diag(cov[1]), 1.0 / VAGUE, rtol=1e-9)
    np.testing.assert_allclose(np.diag(cov[0]),
                               np.repeat(_weighted_mean_variance([0.3] * 3, 0.02, 0.01), 2),
                               rtol=1e-6)
