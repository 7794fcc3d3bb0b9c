import math

import gtsam
import numpy as np
import pytest

from semslam.errors import MappingError
from semslam.geometry import between, compose
from semslam.io.g2o import (
    Edge2D,
    MixtureComponent,
    MixtureEdge2D,
    PointEdge2D,
    PoseGraph2D,
    parse_g2o,
    read_g2o,
    write_g2o,
)
from semslam.mapping.g2o_factors import (
    CompiledMixture,
    PointEdges,
    between_residual,
    null_components,
    point_factor,
    point_residual,
)
from semslam.mapping.levenberg import levenberg_marquardt
from semslam.mapping.pose_graph import (
    innovation_chi2,
    leave_out_chi2,
    optimize_pose_graph,
    plain_graph,
    single_measurements,
)
from semslam.pipeline.optimize import optimize_g2o_file

SIGMA_ODO = np.array([0.05, 0.05, 0.01])
SIGMA_LOOP = np.array([0.05, 0.05, 0.01])
NULL_WEIGHT, NULL_SCALE = 0.01, 1e-11  # as the benchmark files


def _information(sigma):
    return np.diag(1.0 / np.asarray(sigma) ** 2)


def _circle(n_lap=50, n=60, radius=8.0):
    """Poses on a circle, one lap = n_lap poses; poses n_lap.. revisit 0.."""
    step = 2 * math.pi / n_lap
    return np.array(
        [
            [radius * math.sin(i * step), radius * (1 - math.cos(i * step)), i * step]
            for i in range(n)
        ]
    )


def _mixture(a, b, z, weight_null=NULL_WEIGHT, scale=NULL_SCALE):
    info = _information(SIGMA_LOOP)
    return MixtureEdge2D(
        a,
        b,
        (
            MixtureComponent(1.0, Edge2D(a, b, z, info)),
            MixtureComponent(weight_null, Edge2D(a, b, z, info * scale)),
        ),
    )


def _world(seed=3):
    """Noisy odometry around ~1.2 laps, 10 true loop closures, 5 wrong ones (all mixtures)."""
    rng = np.random.default_rng(seed)
    truth = _circle()
    n = len(truth)
    g = PoseGraph2D()
    g.vertices[0] = truth[0].copy()
    for i in range(1, n):
        z = between(truth[i - 1], truth[i]) + rng.normal(0, SIGMA_ODO)
        g.edges.append(Edge2D(i - 1, i, z, _information(SIGMA_ODO)))
        g.vertices[i] = compose(g.vertices[i - 1], z)  # odometry-chained initial guess
    true_pairs = [(i, 50 + i) for i in range(10)]
    for a, b in true_pairs:
        g.mixtures.append(_mixture(a, b, between(truth[a], truth[b]) + rng.normal(0, SIGMA_LOOP)))
    wrong_pairs = [(3, 30), (12, 41), (20, 55), (8, 27), (33, 58)]
    for a, b in wrong_pairs:  # "this is where I was": relative pose ~ identity
        g.mixtures.append(_mixture(a, b, rng.normal(0, [0.3, 0.3, math.radians(10)])))
    return g, truth


def _reference(g):
    """Least squares with the true closures only."""
    clean = PoseGraph2D(
        vertices=dict(g.vertices),
        edges=list(g.edges) + [m.components[0].edge for m in g.mixtures[:10]],
    )
    return optimize_pose_graph(clean, "none").poses


def _rmse(a, b):
    return float(np.sqrt(np.mean(np.sum((a[:, :2] - b[:, :2]) ** 2, axis=1))))


# --------------------------------------------------------------------------- residuals


def _numerical(f, values, key, eps=1e-6):
    cols = []
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        plus, minus = gtsam.Values(values), gtsam.Values(values)
        plus.update(key, values.atPose2(key).retract(d))
        minus.update(key, values.atPose2(key).retract(-d))
        cols.append((f(plus) - f(minus)) / (2 * eps))
    return np.column_stack(cols)


@pytest.mark.parametrize("seed", range(5))
def test_between_residual_jacobians_match_numerical_and_gtsam(seed):
    rng = np.random.default_rng(seed)
    xa = gtsam.Pose2(*rng.normal(0, [5, 5, 2]))
    xb = gtsam.Pose2(*rng.normal(0, [5, 5, 2]))
    z = gtsam.Pose2(*rng.normal(0, [5, 5, 2]))
    values = gtsam.Values()
    values.insert(1, xa)
    values.insert(2, xb)

    def residual(v):
        return between_residual(v.atPose2(1), v.atPose2(2), z, False)[0]

    r, Ja, Jb = between_residual(xa, xb, z)
    np.testing.assert_allclose(Ja, _numerical(residual, values, 1), atol=1e-6)
    np.testing.assert_allclose(Jb, _numerical(residual, values, 2), atol=1e-6)
    # the same error and Jacobians as gtsam's own between factor (unit noise)
    factor = gtsam.BetweenFactorPose2(1, 2, z, gtsam.noiseModel.Unit.Create(3))
    np.testing.assert_allclose(factor.unwhitenedError(values), r, atol=1e-12)
    lin = factor.linearize(values)
    np.testing.assert_allclose(lin.jacobian()[0], np.hstack([Ja, Jb]), atol=1e-9)


def test_point_residual_jacobians_match_numerical():
    rng = np.random.default_rng(1)
    pose = gtsam.Pose2(*rng.normal(0, [3, 3, 2]))
    point = rng.normal(0, 5, 2)
    z = rng.normal(0, 1, 2)
    values = gtsam.Values()
    values.insert(1, pose)
    _, Jp, Jl = point_residual(pose, point, z)
    num = _numerical(lambda v: point_residual(v.atPose2(1), point, z, False)[0], values, 1)
    np.testing.assert_allclose(Jp, num, atol=1e-6)
    eps = 1e-6
    num_l = np.column_stack(
        [
            (
                point_residual(pose, point + d, z, False)[0]
                - point_residual(pose, point - d, z, False)[0]
            )
            / (2 * eps)
            for d in np.eye(2) * eps
        ]
    )
    np.testing.assert_allclose(Jl, num_l, atol=1e-6)


def test_null_detection_and_native_path():
    mix = CompiledMixture(_mixture(0, 1, np.zeros(3)))
    assert null_components(mix.mixture) == [False, True]
    # weights 1 and 0.01 as written: the null's prior is 0.01 / 1.01, once
    assert mix.native_null.weight == pytest.approx(0.01 / 1.01)
    assert mix.native_null.information_scale == pytest.approx(NULL_SCALE)
    factor, used = mix.factor(mix.real)
    assert isinstance(factor, gtsam.BetweenFactorPose2) and used == [0, 1]
    # components on another pose pair: the custom max-mixture factor
    other = MixtureEdge2D(
        0,
        1,
        mix.mixture.components
        + (MixtureComponent(1.0, Edge2D(0, 2, np.zeros(3), _information(SIGMA_LOOP))),),
    )
    factor, used = CompiledMixture(other).factor([0, 2])
    assert isinstance(factor, gtsam.CustomFactor) and used == [0, 2, 1]


# --------------------------------------------------------------------------- optimisation


def test_least_squares_is_bent_and_maxmix_accepts_exactly_the_true_closures():
    g, truth = _world()
    ref = _reference(g)
    assert _rmse(ref, truth) < 0.5
    ls = optimize_pose_graph(g, "none")
    assert _rmse(ls.poses, truth) > 5.0  # visibly bent by the 5 wrong closures
    mm = optimize_pose_graph(g, "maxmix")
    assert mm.schedule == "incremental"
    assert mm.accepted.tolist() == [True] * 10 + [False] * 5
    assert mm.chosen.tolist() == [0] * 10 + [1] * 5
    assert _rmse(mm.poses, ref) < 1e-4
    assert mm.poses[0] == pytest.approx(g.vertices[0], abs=1e-5)  # first pose held
    assert mm.error > 0 and mm.seconds > 0 and mm.updates > 0


def test_plain_batch_maxmix_started_near_the_solution():
    g, _ = _world()
    ref = _reference(g)
    g.vertices = {i: ref[i] for i in range(len(ref))}  # start where the true closures agree
    mm = optimize_pose_graph(g, "maxmix", schedule="batch")
    assert mm.accepted.tolist() == [True] * 10 + [False] * 5
    assert not mm.gated.any() and mm.updates == 0
    assert _rmse(mm.poses, ref) < 1e-4


def test_dcs_down_weights_the_wrong_closures_and_refuses_several_hypotheses():
    g, truth = _world()
    ref = _reference(g)
    # from the odometry-chained guess (0.6 m of drift per lap here) every closure starts far
    # out on the kernel's tail and DCS stops in a local minimum; the max-mixture's
    # incremental schedule does not (the test above)
    assert _rmse(optimize_pose_graph(g, "dcs").poses, ref) > 0.3
    # a wider kernel finds it here (and takes wrong closures on Manhattan)
    assert _rmse(optimize_pose_graph(g, "dcs", dcs_phi=10.0).poses, ref) < 1e-3
    g.vertices = {i: ref[i] + (0.05 if i else 0.0) for i in range(len(ref))}
    dcs = optimize_pose_graph(g, "dcs")
    assert (dcs.robust, dcs.schedule, dcs.updates) == ("dcs", "batch", 0)
    assert not dcs.accepted[10:].any() and dcs.chosen[10:].tolist() == [1] * 5
    assert dcs.accepted[:10].sum() >= 5 and (dcs.chosen[:10] == 0).sum() >= 5
    # true closures with chi2 > phi lose weight too (s = 2 phi / (phi + chi2)): near the
    # clean solution, not on it, and some of them fail the chi2 test there
    assert 1e-3 < _rmse(dcs.poses, ref) < 0.05
    assert _rmse(optimize_pose_graph(g, "none").poses, ref) > 5.0
    assert single_measurements(g) == [m.components[0].edge for m in g.mixtures]
    fg, values = plain_graph(g)  # the prior on pose 0 and the odometry, no closure
    assert (fg.size(), values.size()) == (1 + len(g.edges), len(g.vertices))
    g.mixtures, _ = _multimodal(g)
    with pytest.raises(MappingError, match=r"mixture 0 \(.*\) has 2: use 'maxmix'"):
        optimize_pose_graph(g, "dcs")
    with pytest.raises(MappingError, match="use 'maxmix'"):
        single_measurements(g)


def _multimodal(g):
    """Each true closure offered with 1 or 2 other target poses (same measurement) + a null
    on a wrong pair, as in the benchmark's multimodal files."""
    rng = np.random.default_rng(7)
    info = _information(SIGMA_LOOP)
    mixtures = []
    for i, m in enumerate(g.mixtures[:10]):
        z = m.components[0].edge.measurement
        a, b = m.a, m.b
        wrong = (a, b - 25 - i % 3)
        comps = [
            MixtureComponent(1.0, Edge2D(*wrong, z, info)),
            MixtureComponent(1.0, Edge2D(a, b, z, info)),
            MixtureComponent(1e-7, Edge2D(*wrong, z, info * 1e-7)),
        ]
        if i % 2:
            comps.insert(1, MixtureComponent(1.0, Edge2D(a, int(rng.integers(20, 40)), z, info)))
        mixtures.append(MixtureEdge2D(*wrong, tuple(comps)))
    right = [2 if i % 2 else 1 for i in range(10)]
    return mixtures, right


def test_multimodal_components_on_different_pose_pairs_choose_the_right_one():
    g, truth = _world()
    ref = _reference(g)
    g.mixtures, right = _multimodal(g)
    mm = optimize_pose_graph(g, "maxmix", schedule="incremental")
    assert mm.chosen.tolist() == right
    assert mm.accepted.all()
    assert _rmse(mm.poses, ref) < 1e-4
    # the custom max-mixture factor in a plain batch solve, started near the solution
    g.vertices = {i: ref[i] + (0.05 if i else 0.0) for i in range(len(ref))}
    mm = optimize_pose_graph(g, "maxmix")
    assert mm.schedule == "batch"  # "auto" with hypotheses on several pose pairs
    assert mm.chosen.tolist() == right
    assert _rmse(mm.poses, ref) < 1e-4
    # least squares takes the first of the equally weighted components: the wrong pair
    assert optimize_pose_graph(g, "none").chosen.tolist() == [0] * 10


def test_fix_lines_and_landmarks():
    g, truth = _world()
    g.mixtures = g.mixtures[:10]
    g.fixed = [10]
    rng = np.random.default_rng(2)
    landmark = np.array([3.0, 4.0])
    g.points[1000] = landmark + 0.5
    for i in (2, 5, 52):
        local = (landmark - truth[i, :2]) @ np.array(
            [
                [math.cos(truth[i, 2]), -math.sin(truth[i, 2])],
                [math.sin(truth[i, 2]), math.cos(truth[i, 2])],
            ]
        )
        g.point_edges.append(PointEdge2D(i, 1000, local + rng.normal(0, 0.01, 2), np.eye(2) * 1e4))
    for schedule in ("incremental", "batch"):
        res = optimize_pose_graph(g, "maxmix", schedule=schedule)
        assert res.accepted.all(), schedule
        assert res.pose_dict()[10] == pytest.approx(g.vertices[10], abs=1e-5)
        assert res.point_ids.tolist() == [1000]
        # the map is defined up to the gauge: compare the landmark seen from pose 2
        seen = res.points[0] - res.poses[2, :2]
        true = landmark - truth[2, :2]
        assert np.linalg.norm(seen) == pytest.approx(np.linalg.norm(true), abs=0.1)


def _landmark_graph(seed: int = 5) -> PoseGraph2D:
    """A chain of 40 poses seeing 25 points, each with its own anisotropic information."""
    rng = np.random.default_rng(seed)
    g = PoseGraph2D()
    truth = np.column_stack([np.arange(40) * 0.8, np.sin(np.arange(40) * 0.2), np.zeros(40)])
    truth[:, 2] = np.arctan2(np.gradient(truth[:, 1]), 0.8)
    points = rng.uniform([-2, -6], [34, 6], (25, 2))
    for i, p in enumerate(truth):
        g.vertices[i] = p + (rng.normal(0, [0.3, 0.3, 0.05]) if i else 0)
        if i:
            z = between(truth[i - 1], p) + rng.normal(0, SIGMA_ODO)
            g.edges.append(Edge2D(i - 1, i, z, np.diag(1 / SIGMA_ODO**2)))
    for j, q in enumerate(points):
        g.points[100 + j] = q + rng.normal(0, 0.5, 2)
        for i in np.flatnonzero(np.hypot(*(truth[:, :2] - q).T) < 8):
            c, s_ = math.cos(truth[i, 2]), math.sin(truth[i, 2])
            local = np.array([[c, s_], [-s_, c]]) @ (q - truth[i, :2])
            a = rng.normal(size=(2, 2))
            info = a @ a.T + np.eye(2) * 50
            g.point_edges.append(PointEdge2D(int(i), 100 + j, local + rng.normal(0, 0.05, 2), info))
    return g


def test_landmark_edges_evaluated_together_are_gtsams_point_factors():
    """PointEdges (numpy, one pass over every edge) gives the error and the linear factors
    that gtsam gives for each point_factor, at a point that is not the optimum."""
    g = _landmark_graph()
    _, values = plain_graph(g)
    key = {p: p for p in g.points}
    together = PointEdges(g.point_edges, key)
    one_by_one = gtsam.NonlinearFactorGraph()
    for pe in g.point_edges:
        one_by_one.add(point_factor(pe, pe.b))
    assert together.error(values) == pytest.approx(one_by_one.error(values), rel=1e-12)
    mine = together.linearize(values)
    theirs = one_by_one.linearize(values)
    assert len(mine) == theirs.size() == len(g.point_edges) > 100
    for k, factor in enumerate(mine):
        A, b = factor.jacobian()
        A_ref, b_ref = theirs.at(k).jacobian()
        np.testing.assert_allclose(A, A_ref, atol=1e-9)
        np.testing.assert_allclose(b, b_ref, atol=1e-9)
    assert PointEdges([], key).error(values) == 0.0 and PointEdges([], key).linearize(values) == []


def test_least_squares_with_landmarks_is_the_solve_with_gtsams_point_factors():
    g = _landmark_graph()
    fast = optimize_pose_graph(g, "none")
    factors, values = plain_graph(g)
    solved, _ = levenberg_marquardt(factors, values, 100, 1e-7)
    np.testing.assert_allclose(fast.poses[:, :2], [solved.atPose2(i).translation()
                                                   for i in fast.ids], atol=1e-6)
    np.testing.assert_allclose(fast.points, [solved.atPoint2(p) for p in fast.point_ids],
                               atol=1e-6)  # the two stop within the tolerance, not on one bit
    assert fast.error == pytest.approx(factors.error(solved), rel=1e-6)
    dcs = optimize_pose_graph(g, "dcs")  # no mixture: the same least squares
    np.testing.assert_allclose(dcs.points, fast.points, atol=1e-9)


def test_a_point_no_edge_observes_stays_where_the_file_holds_it():
    g = parse_g2o("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_XY 5 2 1\n"
                  "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    for schedule in ("incremental", "batch"):
        res = optimize_pose_graph(g, "maxmix", schedule=schedule)
        assert res.points.tolist() == [[2.0, 1.0]], schedule


def test_auto_falls_back_to_batch_where_isam2_loses_a_long_weak_chain():
    """A 700-pose chain of unit information: iSAM2's Cholesky finds the incremental pass
    indeterminate (round-off, near pose 586); batch LM solves it, and auto uses batch."""
    n = 700
    g = parse_g2o(
        "".join(f"VERTEX_SE2 {i} {i} 0 0\n" for i in range(n))
        + "".join(f"EDGE_SE2 {i} {i + 1} 1 0 0 1 0 0 1 0 1\n" for i in range(n - 1))
    )
    with pytest.raises(MappingError, match="indeterminate near variable"):
        optimize_pose_graph(g, "maxmix", schedule="incremental")
    res = optimize_pose_graph(g, "maxmix")
    assert res.schedule == "batch"
    np.testing.assert_allclose(res.poses[:, 0], np.arange(n), atol=1e-6)
    np.testing.assert_allclose(res.poses[:, 1:], 0.0, atol=1e-6)


def test_bad_arguments():
    g, _ = _world()
    with pytest.raises(ValueError, match="robust"):
        optimize_pose_graph(g, "huber")
    with pytest.raises(ValueError, match="schedule"):
        optimize_pose_graph(g, schedule="later")
    with pytest.raises(ValueError, match="dcs_phi"):
        optimize_pose_graph(g, "dcs", dcs_phi=0.0)
    with pytest.raises(ValueError, match="gate_probability"):
        optimize_pose_graph(g, gate_probability=1.5)
    broken = PoseGraph2D(vertices={0: np.zeros(3), 1: np.zeros(3)})  # no edges: no chain
    with pytest.raises(ValueError, match="incremental"):
        optimize_pose_graph(broken, schedule="incremental")


def test_optimize_g2o_file_writes_the_same_edges(tmp_path):
    g, _ = _world()
    src, dst = tmp_path / "in.g2o", tmp_path / "out" / "opt.g2o"
    write_g2o(src, g)
    summary = optimize_g2o_file(src, dst, "maxmix")
    out = read_g2o(dst)
    assert out.edges == g.edges and out.mixtures == g.mixtures and out.fixed == g.fixed
    assert list(out.vertices) == list(g.vertices)
    assert summary["accepted"] == 10 and summary["mixtures"] == 15
    assert summary["chosen"] == [0] * 10 + [1] * 5
    ref = _reference(g)
    assert _rmse(np.array([out.vertices[i] for i in sorted(out.vertices)]), ref) < 1e-3


def test_leave_out_statistic_equals_innovation_against_the_graph_without_them():
    g, _ = _world()
    closures = [m.components[0].edge for m in g.mixtures[:10]]
    test = closures[3:6]
    rest = PoseGraph2D(vertices=dict(g.vertices), edges=list(g.edges) + closures[:3] + closures[6:])
    full = PoseGraph2D(vertices=dict(g.vertices), edges=list(g.edges) + closures)
    res_rest = optimize_pose_graph(rest, "none")
    res_full = optimize_pose_graph(full, "none")

    def solved(result, graph):
        values = gtsam.Values()
        for i, p in result.pose_dict().items():
            values.insert(i, gtsam.Pose2(*p))
        fg = gtsam.NonlinearFactorGraph()
        fg.add(
            gtsam.PriorFactorPose2(
                0, gtsam.Pose2(*graph.vertices[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
            )
        )
        for e in graph.edges:
            fg.add(
                gtsam.BetweenFactorPose2(
                    e.a,
                    e.b,
                    gtsam.Pose2(*e.measurement),
                    gtsam.noiseModel.Gaussian.Information(e.information),
                )
            )
        return values, gtsam.Marginals(fg, values)

    v_rest, m_rest = solved(res_rest, rest)
    v_full, m_full = solved(res_full, full)
    innovation = innovation_chi2(v_rest, m_rest, test)
    assert leave_out_chi2(v_full, m_full, test) == pytest.approx(innovation, rel=0.02)
    assert 0.5 < innovation < 40  # 9 degrees of freedom, true measurements
    # the cheap bound never exceeds the statistic; with a tiny gate it is what comes back
    bound = innovation_chi2(v_rest, m_rest, test, gate=1e-9)
    assert 0 < bound <= innovation + 1e-9
    # with a gate the measurement alone passes, its own chi-square comes back, a bound from
    # above, and no marginal is read
    upper = innovation_chi2(v_rest, None, test, gate=1e9)
    assert upper >= innovation - 1e-9
    own = 0.0
    for e in test:
        z = gtsam.Pose2(*e.measurement)
        r = between_residual(v_rest.atPose2(e.a), v_rest.atPose2(e.b), z)[0]
        own += float(r @ e.information @ r)
    assert upper == pytest.approx(own)
    wrong = [Edge2D(3, 30, np.zeros(3), closures[0].information)]
    assert innovation_chi2(v_full, m_full, wrong, gate=16.0) > 1e3
