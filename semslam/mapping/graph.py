"""A small wrapper over GTSAM: variables, factors, iSAM2 updates, batch LM, marginals.

Everything outside ``semslam.mapping`` speaks numpy poses ``(x, y, yaw)`` and
points ``(x, y)``; this wrapper is where they become gtsam values. Reading one
variable asks iSAM2 for that variable only, so the work per keyframe does not
grow with the size of the map.

Why iSAM2 holds linearised factors. The mapper's factors are Python
``CustomFactor`` s. When gtsam calls one with a ``Values`` that has no Python
object (iSAM2's own linearisation point, or LM's), pybind11 copies the whole
``Values`` for the call: linearising one factor then costs time in proportion to
the size of the map, and an incremental run grows quadratically (3.2 km
`large` drive: 999 s of iSAM2, almost all of it in that copy; BENCHMARKS.md).
So iSAM2 never sees a Python factor: each is linearised here at iSAM2's own
linearisation point (``_theta``, a copy owned by Python, which pybind11 passes
by reference) and handed over as a ``LinearContainerFactor`` (native C++).
iSAM2 relinearises by its own rule (``relinearize_threshold``, every
``relinearize_skip`` updates); this wrapper predicts which variables that rule
moves (their step since the linearisation point), moves ``_theta`` the same way
and swaps in every factor on them, linearised again at the new point, in the
same update, so the max-mixtures choose their component again as before and
the container factors never need their first-order shift. The wrapper says when iSAM2
checks (``force_relinearize`` every ``relinearize_skip`` updates; iSAM2's own count is never
reached), so the cadence survives a rebuild.

Why a rebuild after a long loop. iSAM2 relinearises only the variables whose step passed the
threshold; after a long loop that is thousands of poses of a chain whose odometry is nearly
rigid across the car, beside neighbours left where they were. The new linearisation point is
then as far from consistent as the old one (on `large` its error stays 1e8-1e9 where the
estimate's is 1e4-1e5), so the next check's step swings back, and every swing re-eliminates
most of the tree. When more than ``rebuild_share`` of the variables would move, a fresh iSAM2
gets every factor linearised at the whole estimate instead: one Gauss-Newton step from a
consistent point, and a fresh ordering (BENCHMARKS.md).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

import gtsam
import numpy as np
import scipy.sparse as sp

from semslam.errors import MappingError
from semslam.geometry import FloatArray
from semslam.mapping.levenberg import levenberg_marquardt

# Sigma of the vague prior every variable gets in the linearised graph of marginals()
# (m for positions and line offsets, rad for angles, units of the calibration). Vague for
# the whole map too: a turn of the map about its anchor by delta moves each of N variables
# by its distance r from the anchor, and their priors hold that turn with the information
# sum(r^2) / sigma^2. At 10 m, `large`'s 20,000 variables 100-250 m out held the map's heading
# to about 0.1 deg, tighter than the graph itself: its maps were twice as far off as their
# covariances said (BENCHMARKS.md). At 10 km that information is a millionth of it.
VAGUE_SIGMA = 1e4
# The second tier of marginals(): for a key whose clique the first refuses (an almost
# undetermined landmark beside well-determined ones; `large` world 3: 616 slots), priors of
# 10 m, which hold the map's heading somewhat, rather than no covariance from the graph.
STEADY_VAGUE_SIGMA = 10.0


class Graph:
    """All factors ever added (for the final batch solve) plus an incremental iSAM2."""

    def __init__(
        self,
        relinearize_threshold: float = 0.05,
        relinearize_skip: int = 5,
        reorder_growth: float = 0.0,
        rebuild_share: float = 0.0,
    ) -> None:
        """``reorder_growth`` > 1: iSAM2 re-eliminates the whole tree with a fresh ordering
        when its fill-in (nonzeros) has grown to that many times the fill-in after the last
        full ordering (gtsam's adaptive reordering); 0: only when an update touches most
        variables (iSAM2's own rule). The incremental ordering otherwise keeps the fill-in of
        long loops: on `large` cliques of 126-298 variables where a fresh one has 13-26.
        ``rebuild_share`` in (0, 1]: a check that would relinearise more than that share of
        the variables rebuilds iSAM2 at its whole estimate instead; 0: never."""
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize_threshold)
        params.relinearizeSkip = 2**31 - 1  # never by iSAM2's own count: see update()
        params.enablePartialRelinearizationCheck = False  # the full check is the one predicted
        # QR: Cholesky fails on the ill-conditioned steps that null-hypothesis losses give
        params.setFactorization("QR")
        if reorder_growth > 0:
            params.enableAdaptiveReorder = True
            params.adaptiveReorderThreshold = reorder_growth
        self._params = params
        self.isam = gtsam.ISAM2(params)
        self.factors = gtsam.NonlinearFactorGraph()
        self._batch: gtsam.Values | None = None  # set by optimize_batch
        self._keys: set[int] = set()
        self._dims: dict[int, int] = {}  # tangent dimension of every variable
        self._unit = {d: gtsam.noiseModel.Unit.Create(d) for d in (1, 2, 3)}
        self._new_values = gtsam.Values()
        self._theta = gtsam.Values()  # linearisation point of every variable in iSAM2
        self._in_isam = 0  # factors [0, _in_isam) are in iSAM2
        self._slot: list[int] = []  # iSAM2 factor index of each factor
        self._factors_of: dict[int, list[int]] = defaultdict(list)
        self._threshold = relinearize_threshold
        self._skip = relinearize_skip
        self._updates = 0
        self._rebuild_share = rebuild_share
        self.rebuilds = 0  # iSAM2 rebuilt at its estimate (after long loops)
        self.last_result: gtsam.ISAM2Result | None = None  # of the last iSAM2 update

    # -- building
    def _insert(self, key: int, value, dim: int) -> None:
        self._new_values.insert(key, value)
        self._keys.add(key)
        self._dims[key] = dim
        self._batch = None

    def add_pose(self, key: int, pose: FloatArray) -> None:
        self._insert(key, gtsam.Pose2(*map(float, pose)), 3)

    def add_point(self, key: int, point: FloatArray) -> None:
        self._insert(key, np.asarray(point, dtype=float), 2)

    def add_vector(self, key: int, vector: FloatArray) -> None:
        vector = np.asarray(vector, dtype=float)
        self._insert(key, vector, len(vector))

    def add_factor(self, factor: gtsam.NonlinearFactor) -> int:
        """Add a factor; its index in :attr:`factors`."""
        index = self.factors.size()
        self.factors.add(factor)
        for key in factor.keys():  # noqa: SIM118 (a gtsam factor, not a dict)
            self._factors_of[key].append(index)
        self._batch = None
        return index

    def has(self, key: int) -> bool:
        return key in self._keys

    # -- solving
    def update(self) -> None:
        """One iSAM2 step with everything added since the last one."""
        self._updates += 1
        check = self._updates % self._skip == 0
        if check and self._rebuild_due():
            self._rebuild_at_estimate()
            check = False  # the estimate is the linearisation point now
        moved = self._relinearized_by_isam2() if check else []
        again = sorted({i for key in moved for i in self._factors_of[key] if i < self._in_isam})
        new = list(range(self._in_isam, self.factors.size()))
        self._theta.insert(self._new_values)
        linear = gtsam.NonlinearFactorGraph()
        with _one_line_errors():
            for i in again + new:
                linear.add(self._linearized(i))
            params = gtsam.ISAM2UpdateParams()
            params.removeFactorIndices = [self._slot[i] for i in again]
            params.force_relinearize = check
            result = self.isam.update(linear, self._new_values, params)
        self.last_result = result
        slots = list(result.getNewFactorsIndices())
        for i, slot in zip(again, slots[: len(again)], strict=True):
            self._slot[i] = slot
        self._slot.extend(slots[len(again):])
        self._in_isam = self.factors.size()
        self._new_values = gtsam.Values()

    def _linearized(self, index: int) -> gtsam.LinearContainerFactor:
        """Factor ``index`` linearised at ``_theta``, as a native factor for iSAM2."""
        linear = self.factors.at(index).linearize(self._theta)
        return gtsam.LinearContainerFactor(linear, self._theta)

    def _largest_steps(self) -> tuple[list[int], FloatArray]:
        """Every variable in iSAM2 and the largest component of its step since its
        linearisation point."""
        keys = sorted(self._theta.keys())
        step = np.abs(self.isam.getDelta().vector(keys))
        starts = np.cumsum([0] + [self._dims[key] for key in keys[:-1]])
        return keys, np.maximum.reduceat(step, starts)

    def _rebuild_due(self) -> bool:
        if self._rebuild_share <= 0 or self._theta.size() == 0:
            return False
        keys, largest = self._largest_steps()
        return np.count_nonzero(largest >= self._threshold) > self._rebuild_share * len(keys)

    def _rebuild_at_estimate(self) -> None:
        """A fresh iSAM2 holding every factor linearised at the old one's whole estimate.
        Kept only if it eliminates: else the old iSAM2 goes on as it was."""
        theta, isam = self._theta, self.isam
        with _one_line_errors():
            self._theta = self.isam.calculateEstimate()
        linear = gtsam.NonlinearFactorGraph()
        for i in range(self._in_isam):
            linear.add(self._linearized(i))
        self.isam = gtsam.ISAM2(self._params)
        try:
            result = self.isam.update(linear, self._theta, gtsam.ISAM2UpdateParams())
        except RuntimeError:  # an indeterminate system: keep the old tree
            self._theta, self.isam = theta, isam
            return
        self._slot[: self._in_isam] = list(result.getNewFactorsIndices())
        self.rebuilds += 1

    def _relinearized_by_isam2(self) -> list[int]:
        """The variables iSAM2 will relinearise in this update, by its own rule (largest
        component of the step since the linearisation point at least the threshold); moves
        ``_theta`` to where iSAM2 will move its own point: ``theta + delta``."""
        if self._theta.size() == 0:
            return []
        keys, largest = self._largest_steps()
        delta = self.isam.getDelta()
        moved = [keys[n] for n in np.flatnonzero(largest >= self._threshold)]
        if moved:
            steps = gtsam.VectorValues()
            for key in moved:
                steps.insert(key, delta.at(key))
            self._theta = self._theta.retract(steps)
        return moved

    @property
    def estimate(self) -> gtsam.Values:
        """All variables: the batch solution if one is current, else iSAM2's."""
        if self._batch is not None:
            return self._batch
        if self._in_isam < self.factors.size() or self._new_values.size():
            self.update()
        with _one_line_errors():
            return self.isam.calculateEstimate()

    def optimize_batch(self, max_iterations: int = 20, relative_tolerance: float = 1e-5) -> int:
        """Levenberg-Marquardt over all factors from iSAM2's estimate; returns iterations.

        :func:`~semslam.mapping.levenberg.levenberg_marquardt`, not
        gtsam.LevenbergMarquardtOptimizer: that optimizer calls the Python factors with its
        own Values, which pybind11 copies for every call (see the module docstring): ~15x
        longer per iteration on `garage` (5 s against 0.5 s).
        """
        with _one_line_errors():
            values, iterations = levenberg_marquardt(
                self.factors, self.estimate, max_iterations, relative_tolerance, self._dims
            )
        self._batch = values
        return iterations

    # -- reading one variable
    def _pending(self, key: int) -> bool:
        return self._new_values.exists(key)

    def pose(self, key: int) -> FloatArray:
        if self._batch is not None:
            p = self._batch.atPose2(key)
        elif self._pending(key):
            p = self._new_values.atPose2(key)
        else:
            with _one_line_errors():
                p = self.isam.calculateEstimatePose2(key)
        return np.array([p.x(), p.y(), p.theta()])

    def point(self, key: int) -> FloatArray:
        if self._batch is not None:
            return np.asarray(self._batch.atPoint2(key), dtype=float)
        if self._pending(key):
            return np.asarray(self._new_values.atPoint2(key), dtype=float)
        with _one_line_errors():
            return np.asarray(self.isam.calculateEstimatePoint2(key), dtype=float)

    def vector(self, key: int) -> FloatArray:
        if self._batch is not None:
            return np.asarray(self._batch.atVector(key), dtype=float)
        if self._pending(key):
            return np.asarray(self._new_values.atVector(key), dtype=float)
        with _one_line_errors():
            return np.asarray(self.isam.calculateEstimateVector(key), dtype=float)

    def marginals(self) -> TieredMarginals | None:
        """Marginal covariances at the current estimate: an object with
        ``marginalCovariance(key)`` and ``jointMarginalCovariance(keys).fullMatrix()``, or
        None if even QR finds the system singular.

        gtsam's Marginals eliminate by Cholesky, which refuses a nearly indeterminate
        system (on `large`, a slot corner whose observations all sat on the null
        hypothesis). Every variable therefore gets a vague prior (sigma
        :data:`VAGUE_SIGMA`, 10 km or rad) in the linearised graph: it leaves a determined
        variable's covariance, and the map's turn about its anchor, as the graph has them,
        and gives an undetermined one a large, honest covariance. A graph
        Cholesky still refuses as a whole (`large` world 3: odometry information up to 1e9
        beside those priors) is eliminated by QR instead, into a Bayes tree that answers
        the same two questions (1 s for world 3's 35,000 unknowns). A key whose clique is
        refused there is asked again of the same system with priors of
        :data:`STEADY_VAGUE_SIGMA` (built only then)."""
        tiered = TieredMarginals(self._marginals_with)
        return tiered if tiered.answers() else None

    def _marginals_with(self, vague_sigma: float):
        linear = self._linearized_with_vague_priors(self.factors, vague_sigma)
        try:
            return gtsam.Marginals(linear, self.estimate)
        except RuntimeError:
            pass
        try:
            colamd = gtsam.Ordering.OrderingType.COLAMD
            return linear.eliminateMultifrontal(colamd, gtsam.EliminateQR)
        except RuntimeError:
            return None

    def _linearized_with_vague_priors(
        self, factors: gtsam.NonlinearFactorGraph, vague_sigma: float = VAGUE_SIGMA
    ):
        linear = factors.linearize(self.estimate)
        for key, dim in self._dims.items():
            vague = np.eye(dim) / vague_sigma
            linear.add(gtsam.JacobianFactor(key, vague, np.zeros(dim), self._unit[dim]))
        return linear

    def jacobian(self, without: Iterable[int] = ()) -> tuple[sp.csr_matrix, dict[int, int]]:
        """The whitened Jacobian (rows x unknowns) of every factor but those of index
        ``without`` at the current estimate, with the vague priors of :meth:`marginals`; and
        the first column of each variable (gtsam's order: ascending keys)."""
        left_out = set(without)
        factors = gtsam.NonlinearFactorGraph()
        for i in range(self.factors.size()):
            if i not in left_out:
                factors.add(self.factors.at(i))
        triplets = self._linearized_with_vague_priors(factors).sparseJacobian_()
        columns, n = {}, 0
        for key in sorted(self._dims):
            columns[key] = n
            n += self._dims[key]
        rows, cols, vals = triplets[0].astype(int) - 1, triplets[1].astype(int) - 1, triplets[2]
        inside = cols < n  # column n holds the right-hand side
        A = sp.csr_matrix((vals[inside], (rows[inside], cols[inside])),
                          shape=(int(rows.max()) + 1, n))
        return A, columns


class TieredMarginals:
    """Marginals of the linearised graph with priors of :data:`VAGUE_SIGMA`; a question
    that system refuses (RuntimeError) goes to the same graph with priors of
    :data:`STEADY_VAGUE_SIGMA`, solved on first need. ``solve(sigma)``: gtsam's Marginals or
    a QR Bayes tree of the graph with priors of that sigma, or None."""

    def __init__(self, solve) -> None:
        self._solve = solve
        self._tiers: dict[float, object] = {VAGUE_SIGMA: solve(VAGUE_SIGMA)}

    def _tier(self, sigma: float):
        if sigma not in self._tiers:
            self._tiers[sigma] = self._solve(sigma)
        return self._tiers[sigma]

    def answers(self) -> bool:
        """Whether any tier could be built."""
        return self._tier(VAGUE_SIGMA) is not None or self._tier(STEADY_VAGUE_SIGMA) is not None

    def _ask(self, method: str, arg):
        error = RuntimeError("no tier of the marginals could be built")
        for sigma in (VAGUE_SIGMA, STEADY_VAGUE_SIGMA):
            tier = self._tier(sigma)
            if tier is None:
                continue
            try:
                return getattr(tier, method)(arg)
            except RuntimeError as e:
                error = e
        raise error

    def marginalCovariance(self, key: int):  # noqa: N802 (gtsam's name)
        return self._ask("marginalCovariance", key)

    def jointMarginalCovariance(self, keys):  # noqa: N802
        return self._ask("jointMarginalCovariance", keys)


@contextmanager
def _one_line_errors() -> Iterator[None]:
    """gtsam's RuntimeError (an indeterminate system, ten lines) as a one-line MappingError.
    iSAM2 may raise it in an update or, solving lazily, when an estimate is read."""
    try:
        yield
    except RuntimeError as e:
        raise MappingError(f"the factor graph could not be solved: {_first_line(e)}") from None


def _first_line(error: Exception) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return " ".join(lines[:2]) if lines else type(error).__name__
