"""Optimise a 2D g2o pose graph with max-mixture loop closures (GTSAM).

Three modes:

``robust="none"``
    Plain least squares: every mixture contributes its highest-weight
    component (the first of equals) as an ordinary Gaussian between factor;
    one Levenberg-Marquardt solve from the file's vertices.

``robust="maxmix"``
    Max-mixture (Olson & Agarwal 2012) with the components, weights and
    information matrices exactly as the file gives them; each component's
    constant ``-log w + 1/2 log det Sigma`` is counted once
    (:mod:`semslam.mapping.maxmix`). A two-component mixture whose second
    component is a null hypothesis on the same pose pair (same measurement,
    information scaled by ``s``) becomes a native ``BetweenFactorPose2`` with
    :func:`~semslam.mapping.maxmix.null_hypothesis_noise` (fast, exact);
    anything else (components on different pose pairs) becomes a
    :class:`~semslam.mapping.maxmix.MaxMixture` custom factor whose residuals
    are Pose2 between errors with analytic Jacobians.

    ``schedule="batch"`` is the textbook max-mixture: one LM solve of the
    whole graph from the file's initial guess, no front end. From an
    odometry-chained guess it falls into the local minima described in
    ``benchmarks/robust_backend.md``: closures are decided before the
    trajectory has converged, and a closure on the null (information scaled
    by 1e-11) exerts no pull, so an early wrong decision is never revised.

    ``schedule="incremental"`` runs the graph the way a SLAM system meets it
    while driving: poses in id order with iSAM2, each mixture added when the
    last of its poses exists. A front end gates each non-null component with
    the innovation test ``r' (Sigma_z + J Sigma_ab J')^-1 r <= chi2_3(p)``,
    where ``Sigma_ab`` is the current joint marginal of the two poses (drift
    before a loop closes widens the gate, a rigid, well-closed map narrows
    it). Components that pass enter the max-mixture together with the file's
    null, which still decides. After the pass, a batch re-check runs to a
    fixed point, with clusters of neighbouring closures (both ends at most
    ``cluster_gap`` poses apart) as the unit of decision, because a group of
    mutually consistent wrong closures props itself up when its members are
    tested one by one:

    1. each cluster of accepted closures is tested as a whole with the
       leave-cluster-out statistic ``r' (Sigma_z - H Sigma H')^-1 r`` against
       ``chi2_{3m}(p)``; a cluster that fails leaves the back end;
    2. each cluster of two or more closures that the gate admitted but the
       mixture holds on the null (decided before the map had converged with
       them: drift before a loop closes) is tested with its joint innovation
       against the map without it; a cluster that passes is solved once as
       plain measurements and handed back to the mixture, which then decides
       at a map that has converged with it (at most once per component). A
       lone closure is never forced (into a weakly constrained part of the
       map, such as a dead-end tail held only by odometry, any measurement
       looks consistent); closures the gate turned away or a cluster test
       removed stay out.

    The final solution is a max-mixture LM solve of everything admitted; the
    reported choice is the mixture's. ``schedule="auto"`` (default) is
    incremental when every mixture is a measurement and its null on one pose
    pair and the poses form an odometry chain in id order; otherwise batch
    (mixtures over several pose pairs cannot be played back in time order:
    the benchmark's multimodal hypotheses point at poses not yet driven).
    When iSAM2 finds the incremental pass indeterminate (round-off on a long,
    weakly constrained chain), auto falls back to batch.

``robust="dcs"``
    Dynamic covariance scaling (Agarwal et al. 2013, the closed form of switchable
    constraints; g2o's and gtsam's ``DCS`` kernel): each mixture's one measurement
    component, its null dropped, as a between factor whose information is scaled by
    ``s^2``, ``s = min(1, 2 phi / (phi + chi2))``; one Levenberg-Marquardt solve from the
    file's vertices. A loss, not a choice: a mixture with several measurement components
    (the multimodal files) is refused. A closure counts as accepted when its chi-square at
    the solution is within ``chi2_3(gate_probability)``. On the Manhattan outlier files it
    ends closer to the outlier-free solution than the max-mixture, ten to sixty times
    faster; but it needs a good initial guess and a ``phi`` that suits the graph (no one
    value solves both Manhattan and a graph with drift, ``benchmarks/robust_backend.md``).

Gauge: the poses named by FIX lines are held by a tight prior; without FIX,
the first pose (lowest id). Poses and points share the id space of the file.
Factors are built by :mod:`semslam.mapping.g2o_factors`; results are numpy.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from semslam.chi2 import chi2_quantile
from semslam.errors import MappingError
from semslam.geometry import FloatArray
from semslam.io.g2o import Edge2D, PointEdge2D, PoseGraph2D
from semslam.mapping.g2o_factors import (
    CompiledMixture,
    PointEdges,
    between_factor,
    between_residual,
    point_factor,
)
from semslam.mapping.levenberg import levenberg_marquardt

ROBUST_MODES = ("none", "maxmix", "dcs")

#: DCS's default kernel width ``phi`` (chi-square units): the value of Agarwal et al. and g2o.
DCS_PHI = 1.0
SCHEDULES = ("auto", "incremental", "batch")

#: Levenberg-Marquardt stops when a step lowers the error by at most this share of it.
LM_RELATIVE_TOLERANCE = 1e-7

#: Standard deviation of the prior that holds a fixed pose (metres, radians).
FIX_SIGMA = 1e-6


# --------------------------------------------------------------------------- result


@dataclass(frozen=True)
class PoseGraphResult:
    """An optimised pose graph.

    Attributes:
        ids: (N,) pose ids, ascending.
        poses: (N, 3) optimised ``(x, y, yaw)`` per id (metres, radians, yaw wrapped).
        point_ids: (P,) point-landmark ids, ascending.
        points: (P, 2) optimised points, metres.
        chosen: (M,) per mixture (file order), the index of the component in force at the
            solution (for a mixture the front end turned away: its null component).
        accepted: (M,) whether the chosen component is a real measurement, not a null.
        gated: (M,) whether the front end kept every non-null component out of the back end.
        iterations: Levenberg-Marquardt iterations of the batch solves.
        updates: iSAM2 updates of the incremental pass (0 for batch).
        error: the max-mixture cost of the whole graph as the file defines it (every
            mixture, admitted or not, at its best component) at the solution; for
            ``robust="none"`` the least-squares cost.
        seconds: wall time.
        robust: ``"none"``, ``"maxmix"`` or ``"dcs"``.
        schedule: ``"batch"`` or ``"incremental"``.
    """

    ids: np.ndarray
    poses: FloatArray
    point_ids: np.ndarray
    points: FloatArray
    chosen: np.ndarray
    accepted: np.ndarray
    gated: np.ndarray
    iterations: int
    updates: int
    error: float
    seconds: float
    robust: str
    schedule: str

    def pose_dict(self) -> dict[int, FloatArray]:
        """Pose id -> (3,) optimised pose."""
        return {int(i): p.copy() for i, p in zip(self.ids, self.poses, strict=True)}

    def point_dict(self) -> dict[int, FloatArray]:
        """Point id -> (2,) optimised point."""
        return {int(i): p.copy() for i, p in zip(self.point_ids, self.points, strict=True)}


# --------------------------------------------------------------------------- building


@dataclass
class _Problem:
    graph: PoseGraph2D
    mixtures: list[CompiledMixture]
    order: list[int]  # pose ids, ascending (time order)
    position: dict[int, int]
    fixed: list[int]
    point_key: dict[int, int] = field(default_factory=dict)  # point id -> gtsam key


def _problem(graph: PoseGraph2D) -> _Problem:
    order = sorted(graph.vertices)
    if not order:
        raise MappingError("the pose graph has no pose vertices")
    fixed = [v for v in graph.fixed if v in graph.vertices] or [order[0]]
    return _Problem(
        graph=graph,
        mixtures=[CompiledMixture(m) for m in graph.mixtures],
        order=order,
        position={v: i for i, v in enumerate(order)},
        fixed=list(dict.fromkeys(fixed)),
        point_key={p: p for p in graph.points},  # poses and points share the file's id space
    )


def _prior(vid: int, value: FloatArray) -> gtsam.PriorFactorPose2:
    return gtsam.PriorFactorPose2(
        vid, gtsam.Pose2(*value), gtsam.noiseModel.Isotropic.Sigma(3, FIX_SIGMA)
    )


def _base_factors(problem: _Problem, points: bool = True) -> gtsam.NonlinearFactorGraph:
    """Priors on the fixed poses, plain edges and (unless ``points`` is False: then they are
    :func:`_point_edges`) landmark edges."""
    g = problem.graph
    fg = gtsam.NonlinearFactorGraph()
    for vid in problem.fixed:
        fg.add(_prior(vid, g.vertices[vid]))
    for e in g.edges:
        fg.add(between_factor(e))
    if points:
        for pe in g.point_edges:
            fg.add(point_factor(pe, problem.point_key[pe.b]))
    return fg


def _point_edges(problem: _Problem) -> PointEdges:
    """The landmark edges evaluated together, for the Levenberg-Marquardt loop."""
    return PointEdges(problem.graph.point_edges, problem.point_key)


def _file_values(problem: _Problem) -> gtsam.Values:
    v = gtsam.Values()
    for vid, p in problem.graph.vertices.items():
        v.insert(vid, gtsam.Pose2(*p))
    for pid, p in problem.graph.points.items():
        v.insert(problem.point_key[pid], np.asarray(p, dtype=float))
    return v


def _lm(fg: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int,
        points: PointEdges | None = None):
    """Levenberg-Marquardt from Python (:mod:`semslam.mapping.levenberg`): the landmark and
    max-mixture factors are Python, which gtsam's own optimizer would call with copies of
    the whole Values. ``points``: landmark edges left out of ``fg``, evaluated together."""
    extra = () if points is None else (points,)
    return levenberg_marquardt(fg, values, max_iterations, LM_RELATIVE_TOLERANCE, extra=extra)


def _model_cost(problem: _Problem, values: gtsam.Values) -> float:
    """The file's max-mixture cost of the whole graph at ``values`` (every component of every
    mixture; constants relative to each mixture's best component)."""
    cost = _base_factors(problem).error(values)
    for mix in problem.mixtures:
        cost += min(mix.costs(values, range(len(mix.components)))) - float(mix.constants.min())
    return float(cost)


# --------------------------------------------------------------------------- gating


def _joint_covariance(marginals, keys: Sequence[int]) -> FloatArray:
    """Joint marginal covariance of distinct ``keys`` (3 x 3 blocks in the given order; gtsam's
    ``JointMarginal.fullMatrix`` orders the blocks as the keys are passed)."""
    return np.asarray(marginals.jointMarginalCovariance(list(keys)).fullMatrix(), dtype=float)


def _stack(values: gtsam.Values, edges: Sequence[Edge2D]):
    """Stacked residuals r (3m,), Jacobian H (3m, 3k) over the distinct poses ``keys`` (k) and
    block-diagonal measurement covariance (3m, 3m) of relative-pose edges."""
    keys = sorted({v for e in edges for v in (e.a, e.b)})
    col = {k: 3 * i for i, k in enumerate(keys)}
    m = len(edges)
    H = np.zeros((3 * m, 3 * len(keys)))
    r = np.zeros(3 * m)
    Sz = np.zeros((3 * m, 3 * m))
    for i, e in enumerate(edges):
        ri, Ja, Jb = between_residual(
            values.atPose2(e.a), values.atPose2(e.b), gtsam.Pose2(*e.measurement)
        )
        r[3 * i : 3 * i + 3] = ri
        H[3 * i : 3 * i + 3, col[e.a] : col[e.a] + 3] = Ja
        H[3 * i : 3 * i + 3, col[e.b] : col[e.b] + 3] = Jb
        Sz[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = np.linalg.inv(e.information)
    return r, H, Sz, keys


def innovation_chi2(
    values: gtsam.Values, marginals, edges: Sequence[Edge2D], gate: float | None = None
) -> float:
    """Joint innovation ``r' (Sigma_z + H Sigma H')^-1 r`` of relative-pose measurements that are
    not in the graph that ``marginals`` (gtsam ``Marginals`` or ``ISAM2``) describes;
    ``3 len(edges)`` degrees of freedom.

    With ``gate``, two bounds come first, and whichever settles the gate is returned instead
    of the statistic (the measurements pass or fail it either way), so that the marginals,
    expensive for poses far apart in the Bayes tree, are only formed when needed:

    - from above, free: ``Sigma_z + H Sigma H' >= Sigma_z``, so ``r' Sigma_z^-1 r`` is at
      least the statistic; when it is within ``gate`` no marginal is read at all (most true
      loop closures, once their loop has closed);
    - from below: the joint covariance of ``n`` poses is at most ``n`` times its block
      diagonal (Cauchy-Schwarz), so single-pose marginals bound the statistic from below;
      when that bound exceeds ``gate`` the joint marginal is never formed."""
    r, H, Sz, keys = _stack(values, edges)
    if gate is not None:
        free = float(r @ np.linalg.solve(Sz, r))
        if free <= gate:
            return free
        n = len(keys)
        upper = Sz.copy()
        for i, key in enumerate(keys):
            Hk = H[:, 3 * i : 3 * i + 3]
            upper += n * Hk @ np.asarray(marginals.marginalCovariance(key)) @ Hk.T
        bound = float(r @ np.linalg.solve(upper, r))
        if bound > gate:
            return bound
    S = Sz + H @ _joint_covariance(marginals, keys) @ H.T
    return float(r @ np.linalg.solve(S, r))


def leave_out_chi2(values: gtsam.Values, marginals, edges: Sequence[Edge2D]) -> float:
    """``r' (Sigma_z - H Sigma H')^-1 r`` for measurements that are in the graph: the chi-square
    of their disagreement with the rest of the graph (Baarda's test of a group, linearised).
    For a linear problem it equals :func:`innovation_chi2` of the same measurements against
    the graph without them; ``3 len(edges)`` degrees of freedom."""
    r, H, Sz, keys = _stack(values, edges)
    Q = Sz - H @ _joint_covariance(marginals, keys) @ H.T
    Q = 0.5 * (Q + Q.T)
    w, V = np.linalg.eigh(Q)
    floor = 1e-12 * float(np.max(np.diag(Sz)))
    w = np.maximum(w, floor)  # no redundancy in a direction: the residual there counts fully
    proj = V.T @ r
    return float(np.sum(proj * proj / w))


# --------------------------------------------------------------------------- main entry


def optimize_pose_graph(
    graph: PoseGraph2D,
    robust: str = "maxmix",
    *,
    schedule: str = "auto",
    gate_probability: float | None = 0.99,
    cluster_gap: int = 3,
    max_rounds: int = 6,
    max_iterations: int = 100,
    relinearize_threshold: float = 0.01,
    dcs_phi: float = DCS_PHI,
) -> PoseGraphResult:
    """Optimise ``graph``; see the module doc for the modes.

    Args:
        graph: the pose graph; its vertices are the initial guess.
        robust: ``"none"`` (least squares, highest-weight component of each mixture),
            ``"maxmix"`` or ``"dcs"`` (see the module doc).
        schedule: ``"incremental"``, ``"batch"`` or ``"auto"`` (incremental when every mixture
            joins one pose pair and every pose but the first has a plain edge to an earlier
            pose in id order, batch if iSAM2 finds that indeterminate; batch otherwise).
            Only used with ``robust="maxmix"``.
        gate_probability: confidence of the front end's chi-square gates (innovation test and
            cluster re-check); None turns the front end off (pure max-mixture, played back in
            time order). Used by the incremental schedule, and by ``"dcs"`` to call a closure
            accepted (None: 0.99 there). The default 0.99 is one global
            setting, chosen on the Manhattan benchmark (0.999 leaves more of the local-groups
            file's wrong closures in; see ``benchmarks/robust_backend.md``).
        cluster_gap: two accepted closures belong to one cluster when both of their ends are at
            most this many poses apart (in time order).
        max_rounds: re-check rounds at most.
        max_iterations: Levenberg-Marquardt iterations per batch solve.
        relinearize_threshold: iSAM2's relinearisation threshold.
        dcs_phi: DCS's kernel width (``robust="dcs"`` only). No one value suits every graph:
            on Manhattan 0.3-1 find the clean solution and 3 or more take wrong closures,
            while on a graph with drift 3 or more is needed (``benchmarks/robust_backend.md``).

    Returns:
        The optimised poses and points, the chosen component of every mixture and statistics.

    Raises:
        ValueError: an unknown mode or schedule.
        MappingError: a graph without poses, a mixture with several measurement components
            for ``"dcs"``, or gtsam found the system indeterminate (under-constrained or too
            poorly conditioned); one line naming the variable.
    """
    if robust not in ROBUST_MODES:
        raise ValueError(f"robust must be one of {ROBUST_MODES}, got {robust!r}")
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule must be one of {SCHEDULES}, got {schedule!r}")
    if not dcs_phi > 0.0:
        raise ValueError(f"dcs_phi must be positive, got {dcs_phi}")
    if gate_probability is not None and not 0.0 < gate_probability < 1.0:
        raise ValueError(f"gate_probability must be in (0, 1) or None, got {gate_probability}")
    start = time.perf_counter()
    problem = _problem(graph)
    if robust in ("none", "dcs"):
        try:
            if robust == "dcs":
                return _dcs(problem, dcs_phi, gate_probability or 0.99, max_iterations, start)
            return _least_squares(problem, max_iterations, start)
        except RuntimeError as exc:
            raise _indeterminate(exc) from None
    chosen = schedule
    if schedule == "auto":
        single_pair = all(m.single_pair for m in problem.mixtures)
        chosen = "incremental" if single_pair and _is_chain(problem) else "batch"
    if chosen == "incremental" and not _is_chain(problem):
        raise ValueError(
            "incremental schedule needs every pose but the first to have a plain edge to an "
            "earlier pose (in id order); use schedule='batch'"
        )

    def solve(which: str) -> PoseGraphResult:
        solver = _Solver(
            problem, gate_probability, cluster_gap, max_rounds, max_iterations,
            relinearize_threshold,
        )
        values = solver.batch() if which == "batch" else solver.incremental()
        return solver.result(values, which, start)

    try:
        return solve(chosen)
    except RuntimeError as exc:
        error = _indeterminate(exc)
        if schedule != "auto" or chosen == "batch" or not isinstance(error, MappingError):
            raise error from None
    # iSAM2's Cholesky on a long, weakly constrained chain can lose the gauge-free part
    # to round-off where batch LM's ordering does not (a 20,000-pose chain of unit
    # information fails near pose 600): the auto schedule falls back to batch.
    try:
        return solve("batch")
    except RuntimeError as exc:
        raise _indeterminate(exc) from None


def _indeterminate(exc: RuntimeError) -> MappingError | RuntimeError:
    """gtsam's (ten-line) IndeterminateSystemException as one line naming the variable;
    any other RuntimeError is returned unchanged (a bug, keeps its traceback)."""
    text = " ".join(str(exc).split())
    if "Indeterminate" not in text and "ndeterminant" not in text:
        return exc
    found = re.search(r"near variable (\S+)", text)
    variable = f"variable {found.group(1)}" if found else "an unknown variable"
    return MappingError(
        f"the pose graph could not be solved: the system is indeterminate near {variable} "
        "(under-constrained, or information matrices too poorly conditioned)"
    )


def _is_chain(problem: _Problem) -> bool:
    earlier: set[int] = set()
    for e in problem.graph.edges:
        later = max(e.a, e.b, key=problem.position.__getitem__)
        earlier.add(later)
    return all(v in earlier for v in problem.order[1:])


def _least_squares(problem: _Problem, max_iterations: int, start: float) -> PoseGraphResult:
    fg, points = _base_factors(problem, points=False), _point_edges(problem)
    chosen = []
    for mix in problem.mixtures:
        weights = [c.weight for c in mix.components]
        k = int(np.argmax(weights))
        chosen.append(k)
        fg.add(between_factor(mix.components[k].edge))
    values, iterations = _lm(fg, _file_values(problem), max_iterations, points)
    chosen_arr = np.array(chosen, dtype=int)
    accepted = np.array(
        [not mix.is_null[k] for mix, k in zip(problem.mixtures, chosen, strict=True)], dtype=bool
    )
    return _pack(
        problem,
        values,
        chosen_arr,
        accepted,
        np.zeros(len(chosen), bool),
        iterations,
        0,
        float(fg.error(values) + points.error(values)),
        start,
        "none",
        "batch",
    )


def single_measurements(graph: PoseGraph2D) -> list[Edge2D]:
    """Each mixture's one measurement component (its nulls dropped), in file order: what a
    robust kernel (``robust="dcs"``, the baselines of ``tools/bench_robust_backend.py``)
    takes in place of the mixture.

    Raises:
        MappingError: a mixture with no or several measurement components.
    """
    return _single_measurements([CompiledMixture(m) for m in graph.mixtures])


def _single_measurements(mixtures: Sequence[CompiledMixture]) -> list[Edge2D]:
    edges = []
    for index, mix in enumerate(mixtures):
        if len(mix.real) != 1:
            raise MappingError(
                f"a robust kernel takes one measurement per mixture (and its null); mixture "
                f"{index} ({mix.mixture.a} -> {mix.mixture.b}) has {len(mix.real)}: use 'maxmix'"
            )
        edges.append(mix.components[mix.real[0]].edge)
    return edges


def plain_graph(graph: PoseGraph2D) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The part of every mode that is not a mixture: the priors on the fixed poses, the plain
    and landmark edges; and the file's vertices and points as values."""
    problem = _problem(replace(graph, mixtures=[]))
    return _base_factors(problem), _file_values(problem)


def _dcs(problem: _Problem, phi: float, probability: float, max_iterations: int, start: float):
    """Dynamic covariance scaling on each mixture's one measurement component."""
    fg = _base_factors(problem, points=False)
    edges = _single_measurements(problem.mixtures)
    for edge in edges:
        gaussian = gtsam.noiseModel.Gaussian.Information(edge.information)
        kernel = gtsam.noiseModel.mEstimator.DCS.Create(phi)
        fg.add(between_factor(edge, gtsam.noiseModel.Robust.Create(kernel, gaussian)))
    values, iterations = _lm(fg, _file_values(problem), max_iterations, _point_edges(problem))
    gate = chi2_quantile(probability, 3)
    accepted = np.array([2.0 * between_factor(e).error(values) <= gate for e in edges], bool)
    chosen = np.array(
        [
            mix.real[0] if ok or not mix.nulls else mix.nulls[0]
            for mix, ok in zip(problem.mixtures, accepted, strict=True)
        ],
        dtype=int,
    )
    return _pack(
        problem,
        values,
        chosen,
        accepted,
        np.zeros(len(chosen), bool),
        iterations,
        0,
        _model_cost(problem, values),
        start,
        "dcs",
        "batch",
    )


def _pack(
    problem, values, chosen, accepted, gated, iterations, updates, error, start, robust, schedule
) -> PoseGraphResult:
    ids = np.array(problem.order, dtype=int)
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (values.atPose2(int(i)) for i in ids)])
    pids = np.array(sorted(problem.graph.points), dtype=int)
    pts = np.array([values.atPoint2(problem.point_key[int(i)]) for i in pids]).reshape(-1, 2)
    return PoseGraphResult(
        ids=ids,
        poses=poses,
        point_ids=pids,
        points=pts,
        chosen=np.asarray(chosen, dtype=int),
        accepted=np.asarray(accepted, dtype=bool),
        gated=np.asarray(gated, dtype=bool),
        iterations=int(iterations),
        updates=int(updates),
        error=float(error),
        seconds=time.perf_counter() - start,
        robust=robust,
        schedule=schedule,
    )


class _IsamEstimate:
    """The parts of ``gtsam.Values`` the incremental pass reads, served pose by pose by iSAM2."""

    def __init__(self, isam: gtsam.ISAM2) -> None:
        self.isam = isam

    def exists(self, key: int) -> bool:
        return bool(self.isam.valueExists(key))

    def atPose2(self, key: int) -> gtsam.Pose2:
        return self.isam.calculateEstimatePose2(key)


class _Solver:
    """The max-mixture solve: state shared by the incremental pass and the re-check."""

    def __init__(
        self,
        problem,
        gate_probability,
        cluster_gap,
        max_rounds,
        max_iterations,
        relinearize_threshold,
    ) -> None:
        self.p = problem
        self.gate_probability = gate_probability
        self.cluster_gap = cluster_gap
        self.max_rounds = max_rounds
        self.max_iterations = max_iterations
        self.relinearize_threshold = relinearize_threshold
        # per mixture: the real components the front end lets in (all of them without gate)
        self.allowed: list[list[int]] = [list(m.real) for m in problem.mixtures]
        self.iterations = 0
        self.updates = 0
        self._forced: set[tuple[int, int]] = set()  # components the re-check has forced once
        self._gates: dict[int, float] = {}

    # ------------------------------------------------------------------ gates

    def _gate(self, dof: int) -> float:
        """The chi-square gate for ``dof`` degrees of freedom (infinite without front end)."""
        if self.gate_probability is None:
            return math.inf
        if dof not in self._gates:
            self._gates[dof] = chi2_quantile(self.gate_probability, dof)
        return self._gates[dof]

    def _admit(self, mix: CompiledMixture, values, marginals) -> dict[int, float]:
        """The real components of ``mix`` that pass the innovation gate, with their innovation
        chi-square (a mixture without a null keeps every component: it must choose)."""
        if not mix.nulls:
            return {k: 0.0 for k in mix.real}
        gate = self._gate(3)
        chi = {
            k: innovation_chi2(values, marginals, [mix.components[k].edge], gate) for k in mix.real
        }
        return {k: c for k, c in chi.items() if c <= gate}

    # ------------------------------------------------------------------ graphs

    def _graph(
        self, forced: dict[int, int] | None = None
    ) -> tuple[gtsam.NonlinearFactorGraph, list[list[int] | None]]:
        """Base factors and a factor per admitted mixture; ``forced`` mixtures (index ->
        component) enter as that component's plain Gaussian factor instead."""
        fg = _base_factors(self.p)
        used: list[list[int] | None] = []
        for i, (mix, allowed) in enumerate(zip(self.p.mixtures, self.allowed, strict=True)):
            if not allowed:
                used.append(None)
                continue
            if forced and i in forced:
                fg.add(between_factor(mix.components[forced[i]].edge))
                used.append([forced[i]])
                continue
            factor, u = mix.factor(allowed)
            fg.add(factor)
            used.append(u)
        return fg, used

    def _solve(self, values: gtsam.Values, forced: dict[int, int] | None = None):
        """LM on the admitted graph; with ``forced`` first on the graph where those mixtures
        are their chosen measurement (so the map converges with them before they decide)."""
        if forced:
            fg, _ = self._graph(forced)
            values, it = _lm(fg, values, self.max_iterations)
            self.iterations += it
        fg, used = self._graph()
        values, it = _lm(fg, values, self.max_iterations)
        self.iterations += it
        return fg, used, values

    # ------------------------------------------------------------------ schedules

    def batch(self) -> gtsam.Values:
        values = _file_values(self.p)
        _, _, values = self._solve(values)
        return values

    def incremental(self) -> gtsam.Values:
        p = self.p
        g = p.graph
        if self.gate_probability is not None:
            self.allowed = [[] for _ in p.mixtures]
        edges_at: dict[int, list[Edge2D]] = {}
        for e in g.edges:
            edges_at.setdefault(max(p.position[e.a], p.position[e.b]), []).append(e)
        points_at: dict[int, list[PointEdge2D]] = {}
        for pe in g.point_edges:
            points_at.setdefault(p.position[pe.a], []).append(pe)
        mix_at: dict[int, list[int]] = {}
        for i, mix in enumerate(p.mixtures):
            mix_at.setdefault(mix.arrival(p.position), []).append(i)

        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = 1
        isam = gtsam.ISAM2(params)
        first = p.order[0]
        estimate = _IsamEstimate(isam)  # per-pose reads: the whole estimate costs O(N) each time
        seen_points: set[int] = set()
        for t, vid in enumerate(p.order):
            fg = gtsam.NonlinearFactorGraph()
            new = gtsam.Values()
            if t == 0:
                fg.add(_prior(first, g.vertices[first]))
                new.insert(first, gtsam.Pose2(*g.vertices[first]))
            else:
                new.insert(vid, self._initial(vid, edges_at[t], estimate))
            for e in edges_at.get(t, []):
                fg.add(between_factor(e))
            for pe in points_at.get(t, []):
                key = p.point_key[pe.b]
                if pe.b not in seen_points:
                    seen_points.add(pe.b)
                    pose = new.atPose2(vid) if new.exists(vid) else estimate.atPose2(vid)
                    new.insert(key, np.asarray(pose.transformFrom(pe.measurement), dtype=float))
                fg.add(point_factor(pe, key))
            isam.update(fg, new)
            self.updates += 1
            if t not in mix_at:
                continue
            fg = gtsam.NonlinearFactorGraph()
            for i in mix_at[t]:
                mix = p.mixtures[i]
                if self.gate_probability is not None:
                    self.allowed[i] = sorted(self._admit(mix, estimate, isam))
                if self.allowed[i]:
                    fg.add(mix.factor(self.allowed[i])[0])
            if fg.size():
                isam.update(fg, gtsam.Values())
                isam.update()
                self.updates += 2
        values = self._regauge(isam.calculateEstimate())
        return self._recheck(values)

    def _initial(self, vid: int, edges: list[Edge2D], estimate: gtsam.Values) -> gtsam.Pose2:
        for e in edges:
            z = gtsam.Pose2(*e.measurement)
            if e.b == vid and estimate.exists(e.a):
                return estimate.atPose2(e.a).compose(z)
            if e.a == vid and estimate.exists(e.b):
                return estimate.atPose2(e.b).compose(z.inverse())
        raise AssertionError("chain check passed but no edge initialises the pose")

    def _regauge(self, estimate: gtsam.Values) -> gtsam.Values:
        """Move the incremental estimate rigidly so the first fixed pose sits where the file
        holds it (the incremental pass anchors the first pose)."""
        anchor = self.p.fixed[0]
        T = gtsam.Pose2(*self.p.graph.vertices[anchor]).compose(estimate.atPose2(anchor).inverse())
        out = gtsam.Values()
        for vid in self.p.order:
            out.insert(vid, T.compose(estimate.atPose2(vid)))
        for pid, key in self.p.point_key.items():
            if estimate.exists(key):
                out.insert(key, np.asarray(T.transformFrom(estimate.atPoint2(key)), dtype=float))
            else:  # a point no edge observes stays where the file holds it, as in batch
                out.insert(key, np.asarray(self.p.graph.points[pid], dtype=float))
        return out

    # ------------------------------------------------------------------ re-check

    def _recheck(self, values: gtsam.Values) -> gtsam.Values:
        """Batch re-check to a fixed point; neighbouring closures are one hypothesis."""
        fg, used, values = self._solve(values)
        if self.gate_probability is None:
            return values
        seen = {self._state()}
        for _ in range(self.max_rounds):
            changed = False
            # 1. clusters of accepted closures, each tested as a whole against the rest
            marginals = gtsam.Marginals(fg, values)
            accepted = []
            for i, (mix, u) in enumerate(zip(self.p.mixtures, used, strict=True)):
                if u is not None and mix.nulls:
                    k = mix.chosen(values, u)
                    if not mix.is_null[k]:
                        accepted.append((i, k))
            for cluster in self._clusters(accepted):
                edges = [self.p.mixtures[i].components[k].edge for i, k in cluster]
                if leave_out_chi2(values, marginals, edges) > self._gate(3 * len(edges)):
                    for i, k in cluster:
                        self.allowed[i].remove(k)
                    changed = True
            if changed:
                fg, used, values = self._solve(values)
                marginals = gtsam.Marginals(fg, values)
            # 2. closures the front end admitted but the mixture holds on the null (decided at a
            # map that had not converged with them: drift before a loop closes), in clusters,
            # tested with their joint innovation against the map without them; a cluster that
            # passes is solved once as plain measurements and handed back to the mixture, which
            # then decides at a map that has converged with it (at most once per component).
            # Only clusters of at least two closures (a revisit confirmed by neighbouring
            # closures that agree, as a temporal-consistency check): a lone closure into a
            # weakly constrained part of the map (a dead-end tail held only by odometry) looks
            # consistent whatever it says, and forcing it swings that part to match. Closures
            # the gate turned away or a cluster test removed stay out for the same reason.
            out = []
            for i, (mix, u) in enumerate(zip(self.p.mixtures, used, strict=True)):
                if u is None or not mix.nulls or not mix.is_null[mix.chosen(values, u)]:
                    continue
                out += [(i, k) for k in self.allowed[i] if (i, k) not in self._forced]
            admitted: dict[int, int] = {}
            for cluster in self._clusters(out):
                if len(cluster) < 2:
                    continue  # a revisit is confirmed by neighbouring closures that agree
                edges = [self.p.mixtures[i].components[k].edge for i, k in cluster]
                gate = self._gate(3 * len(edges))
                if innovation_chi2(values, marginals, edges, gate) <= gate:
                    for i, k in cluster:
                        self.allowed[i] = sorted(set(self.allowed[i]) | {k})
                        admitted[i] = k
                        self._forced.add((i, k))
            if admitted:
                fg, used, values = self._solve(values, forced=admitted)
            state = self._state()
            if not (changed or admitted) or (state in seen and not admitted):
                break
            seen.add(state)
        return values

    def _state(self) -> tuple[tuple[int, ...], ...]:
        return tuple(tuple(a) for a in self.allowed)

    def _clusters(self, members: list[tuple[int, int]]) -> list[list[tuple[int, int]]]:
        """(mixture, component) pairs grouped into clusters: two closures are neighbours when
        both of their ends are at most ``cluster_gap`` poses apart (in time order)."""
        ends = []
        for i, k in members:
            e = self.p.mixtures[i].components[k].edge
            ends.append(sorted((self.p.position[e.a], self.p.position[e.b])))
        parent = list(range(len(members)))

        def find(x: int) -> int:
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        gap = self.cluster_gap
        by_early = sorted(range(len(members)), key=lambda n: ends[n][0])
        for idx, n in enumerate(by_early):
            a, b = ends[n]
            for m in by_early[idx + 1 :]:
                if ends[m][0] - a > gap:
                    break
                if abs(ends[m][1] - b) <= gap:
                    parent[find(m)] = find(n)
        groups: dict[int, list[tuple[int, int]]] = {}
        for n, member in enumerate(members):
            groups.setdefault(find(n), []).append(member)
        return list(groups.values())

    # ------------------------------------------------------------------ result

    def result(self, values: gtsam.Values, schedule: str, start: float) -> PoseGraphResult:
        _, used = self._graph()
        chosen, accepted, gated = [], [], []
        for mix, u in zip(self.p.mixtures, used, strict=True):
            if u is None:
                k = mix.nulls[0] if mix.nulls else mix.real[0]
                gated.append(True)
            else:
                k = mix.chosen(values, u)
                gated.append(False)
            chosen.append(k)
            accepted.append(not mix.is_null[k])
        return _pack(
            self.p,
            values,
            chosen,
            accepted,
            gated,
            self.iterations,
            self.updates,
            _model_cost(self.p, values),
            start,
            "maxmix",
            schedule,
        )
