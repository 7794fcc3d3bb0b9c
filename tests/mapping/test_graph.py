"""The gtsam wrapper: iSAM2 fed with factors linearised in Python, relinearised here."""

import gtsam
import numpy as np
import pytest

from semslam.mapping.factors import custom_factor, slot_observation_residual
from semslam.mapping.graph import STEADY_VAGUE_SIGMA, VAGUE_SIGMA, Graph, TieredMarginals

X = gtsam.symbol_shorthand.X
P = gtsam.symbol_shorthand.P


def _circle(graph: Graph, steps: int = 24, radius: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """A loop of poses around four landmarks, added one pose per update; initial guesses
    by dead reckoning with a heading error of 0.03 rad per step (0.7 rad at the end).
    Exact measurements, so the optimum is the truth. Returns true poses and points."""
    angles = np.linspace(0.0, 2 * np.pi, steps, endpoint=False)
    truth = np.column_stack([radius * np.sin(angles), radius * (1 - np.cos(angles)), angles])
    points = np.array([[-1.0, radius - 1.0], [1.0, radius - 1.0], [1.0, radius + 1.0],
                       [-1.0, radius + 1.0]])
    guess = truth[0].copy()
    graph.add_pose(X(0), truth[0])
    graph.add_factor(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(*truth[0]),
                                            gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
    for j, p in enumerate(points):
        graph.add_point(P(j), p + 0.3)
    odometry_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.01]))
    seen_noise = gtsam.noiseModel.Isotropic.Sigma(8, 0.05)
    for k in range(steps):
        if k:
            step = gtsam.Pose2(*truth[k - 1]).between(gtsam.Pose2(*truth[k]))
            drifted = gtsam.Pose2(*guess).compose(
                gtsam.Pose2(step.x(), step.y(), step.theta() + 0.03))
            guess = np.array([drifted.x(), drifted.y(), drifted.theta()])
            graph.add_pose(X(k), guess)
            graph.add_factor(gtsam.BetweenFactorPose2(X(k - 1), X(k), step, odometry_noise))
        pose = gtsam.Pose2(*truth[k])
        seen = np.array([pose.transformTo(p) for p in points])
        graph.add_factor(custom_factor(
            [X(k), *[P(j) for j in range(4)]],
            slot_observation_residual(X(k), [P(j) for j in range(4)], seen), seen_noise))
        graph.update()
    for _ in range(12):  # updates without new factors: iSAM2 keeps relinearising
        graph.update()
    return truth, points


def _largest_error(graph: Graph, truth: np.ndarray, points: np.ndarray) -> float:
    errors = [np.abs(graph.pose(X(k))[:2] - truth[k, :2]).max() for k in range(len(truth))]
    errors += [np.abs(graph.point(P(j)) - p).max() for j, p in enumerate(points)]
    return float(max(errors))


def test_relinearised_isam2_reaches_the_optimum_that_batch_lm_finds():
    graph = Graph(relinearize_threshold=0.01, relinearize_skip=1)
    truth, points = _circle(graph)
    incremental = _largest_error(graph, truth, points)
    graph.optimize_batch()
    assert incremental < 1e-4
    assert _largest_error(graph, truth, points) < 1e-4


@pytest.mark.parametrize("skip", [1, 3])
def test_a_rebuild_at_the_estimate_after_the_loop_reaches_the_optimum(skip):
    """When a check would move more than ``rebuild_share`` of the variables (the loop
    closing on a 0.7 rad heading error), iSAM2 is rebuilt at its estimate; the incremental
    estimate still reaches the optimum, and the tree holds each factor once."""
    graph = Graph(relinearize_threshold=0.01, relinearize_skip=skip, rebuild_share=0.3)
    truth, points = _circle(graph)
    assert graph.rebuilds >= 1
    assert _largest_error(graph, truth, points) < 1e-4
    assert graph.isam.getFactorsUnsafe().nrFactors() == graph.factors.size()


def test_without_a_rebuild_share_isam2_is_never_rebuilt():
    graph = Graph(relinearize_threshold=0.01, relinearize_skip=1)
    _circle(graph)
    assert graph.rebuilds == 0


def test_reordering_the_whole_tree_as_it_fills_in_changes_the_order_not_the_estimate():
    """gtsam's adaptive reordering (``reorder_growth``) re-orders the tree more often than
    iSAM2's own rule; the estimate is the same to round-off and still the optimum."""
    estimates, reorders = [], []
    for growth in (0.0, 1.2):
        graph = Graph(relinearize_threshold=0.01, relinearize_skip=1, reorder_growth=growth)
        update, count = graph.update, []

        def counted(update=update, graph=graph, count=count):
            update()
            count.append(graph.last_result.getBatchReorderTriggered())

        graph.update = counted
        truth, points = _circle(graph, steps=60)
        assert _largest_error(graph, truth, points) < 1e-4
        estimates.append(np.array([graph.pose(X(k)) for k in range(60)]))
        reorders.append(sum(count))
    assert reorders[1] > reorders[0]
    np.testing.assert_allclose(estimates[1], estimates[0], atol=1e-9)


def test_without_relinearisation_the_first_linearisation_point_shows():
    graph = Graph(relinearize_threshold=1e9, relinearize_skip=1)
    truth, points = _circle(graph)
    assert _largest_error(graph, truth, points) > 0.05


@pytest.mark.parametrize("skip", [1, 3])
def test_a_factor_is_swapped_not_duplicated_when_relinearised(skip):
    graph = Graph(relinearize_threshold=0.01, relinearize_skip=skip)
    _circle(graph)
    assert graph.isam.getFactorsUnsafe().nrFactors() == graph.factors.size()


def test_the_last_isam2_result_is_kept_for_profiling():
    graph = Graph()
    assert graph.last_result is None
    graph.add_pose(X(0), np.zeros(3))
    graph.add_factor(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
    graph.add_pose(X(1), np.array([1.0, 0.0, 0.0]))
    graph.add_factor(gtsam.BetweenFactorPose2(X(0), X(1), gtsam.Pose2(1.0, 0.0, 0.0),
                                              gtsam.noiseModel.Unit.Create(3)))
    graph.update()
    assert graph.last_result.getVariablesReeliminated() == 2
    graph.update()  # nothing new: nothing re-eliminated
    assert graph.last_result.getVariablesReeliminated() == 0


def test_a_graph_cholesky_refuses_gets_the_same_marginals_from_qr(monkeypatch):
    """When gtsam's Marginals (Cholesky) refuse the graph, QR elimination answers the same
    covariances (`large` world 3's map was exported with none)."""
    graph = Graph()
    _circle(graph, steps=12)
    graph.optimize_batch()
    cholesky = graph.marginals()
    assert isinstance(cholesky._tier(VAGUE_SIGMA), gtsam.Marginals)

    def refuse(*args):
        raise RuntimeError("Indeterminate linear system detected")

    monkeypatch.setattr(gtsam, "Marginals", refuse)
    qr = graph.marginals()
    assert qr is not None
    for key in (X(0), X(6), P(2)):
        np.testing.assert_allclose(qr.marginalCovariance(key), cholesky.marginalCovariance(key),
                                   rtol=1e-8, atol=1e-14)
    keys = [P(j) for j in range(4)]
    np.testing.assert_allclose(qr.jointMarginalCovariance(keys).fullMatrix(),
                               cholesky.jointMarginalCovariance(keys).fullMatrix(),
                               rtol=1e-8, atol=1e-14)


def test_the_vague_priors_of_the_marginals_leave_a_long_map_s_heading_to_the_graph():
    """A 1 km straight drive, odometry only: the last pose's heading variance is the sum of
    the steps' (the anchor holds the first). Priors of 10 m on every pose held the heading
    of the whole line about its anchor ~100x tighter than that (a turn by delta moves a
    pose r from the anchor by r * delta; 1,000 priors summed). On `large` the maps were too
    sure of their heading so."""
    graph = Graph()
    steps, step, yaw_sigma = 1000, 1.0, 1e-3
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, yaw_sigma]))
    graph.add_pose(X(0), np.zeros(3))
    graph.add_factor(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(
        3, 1e-6)))
    for k in range(1, steps + 1):
        graph.add_pose(X(k), np.array([k * step, 0.0, 0.0]))
        graph.add_factor(gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(step, 0.0, 0.0),
                                                  noise))
    graph.update()
    heading_variance = graph.marginals().marginalCovariance(X(steps))[2, 2]
    assert heading_variance == pytest.approx(steps * yaw_sigma**2, rel=1e-3)


def test_a_key_the_vague_tier_refuses_is_answered_by_the_steady_one():
    """A clique refused with the 10 km priors (an almost undetermined landmark beside
    well-determined ones) is asked again of the graph with 10 m priors, built once, only
    when needed; a key every tier refuses raises."""
    built = []

    class Tier:
        def __init__(self, sigma):
            self.sigma = sigma
            built.append(sigma)

        def marginalCovariance(self, key):  # noqa: N802
            if self.sigma == VAGUE_SIGMA and key == 1 or key == 2:
                raise RuntimeError("Indeterminate linear system detected")
            return np.eye(2) * self.sigma

    tiers = TieredMarginals(Tier)
    assert built == [VAGUE_SIGMA]
    np.testing.assert_array_equal(tiers.marginalCovariance(0), np.eye(2) * VAGUE_SIGMA)
    assert built == [VAGUE_SIGMA]
    np.testing.assert_array_equal(tiers.marginalCovariance(1), np.eye(2) * STEADY_VAGUE_SIGMA)
    tiers.marginalCovariance(1)
    assert built == [VAGUE_SIGMA, STEADY_VAGUE_SIGMA]
    with pytest.raises(RuntimeError):
        tiers.marginalCovariance(2)
