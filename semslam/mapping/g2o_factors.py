"""gtsam factors for the edges of a g2o pose graph: the Pose2 between error and a point
seen from a pose with analytic Jacobians, and a mixture edge compiled into a native
factor (a measurement and its null as a robust loss) or a
:class:`~semslam.mapping.maxmix.MaxMixture` custom factor. Used by
:mod:`semslam.mapping.pose_graph`; poses are gtsam ``Pose2`` (metres, radians), the
Jacobians are with respect to gtsam's retraction ``x * Exp(d)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np

from semslam.geometry import FloatArray
from semslam.io.g2o import Edge2D, MixtureEdge2D, PointEdge2D
from semslam.mapping.maxmix import (
    Component,
    MaxMixture,
    NullHypothesis,
    null_hypothesis_noise,
)

#: A component whose information is at most this fraction of another component's
#: (largest eigenvalue against smallest) is a null hypothesis ("it is an outlier").
NULL_INFORMATION_RATIO = 1e-4


# --------------------------------------------------------------------------- residuals


def between_residual(
    xa: gtsam.Pose2, xb: gtsam.Pose2, measured: gtsam.Pose2, want_jacobians: bool = True
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """The Pose2 between error ``Log(measured^-1 * xa^-1 * xb)`` and its Jacobians.

    This is the error of gtsam's ``BetweenFactorPose2`` (local coordinates at
    ``measured``). The Jacobians are with respect to gtsam's retraction
    ``x * Exp(d)``: ``Jb = Jr^-1(r)`` and ``Ja = -Jr^-1(r) Ad(h^-1)`` with
    ``h = xa^-1 xb``.

    Returns:
        ``(r (3,), Ja (3, 3), Jb (3, 3))``; the Jacobians are None unless wanted.
    """
    h = xa.between(xb)
    e = measured.between(h)
    r = np.asarray(gtsam.Pose2.Logmap(e), dtype=float)
    if not want_jacobians:
        return r, None, None
    Jb = np.asarray(gtsam.Pose2.LogmapDerivative(e), dtype=float)
    Ja = -Jb @ np.asarray(h.inverse().AdjointMap(), dtype=float)
    return r, Ja, Jb


def point_residual(
    pose: gtsam.Pose2, point: FloatArray, measured: FloatArray, want_jacobians: bool = True
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """``R(yaw)^T (point - t) - measured`` (a point seen from a pose) and its Jacobians
    with respect to the pose (retraction ``x * Exp(d)``) and the point."""
    c, s = math.cos(pose.theta()), math.sin(pose.theta())
    Rt = np.array([[c, s], [-s, c]])
    local = Rt @ (np.asarray(point, dtype=float) - np.array([pose.x(), pose.y()]))
    r = local - measured
    if not want_jacobians:
        return r, None, None
    Jp = np.array([[-1.0, 0.0, local[1]], [0.0, -1.0, -local[0]]])
    return r, Jp, Rt


def _between_residual_function(edge: Edge2D):
    measured = gtsam.Pose2(*edge.measurement)
    a, b = edge.a, edge.b

    def residual(values: gtsam.Values, want: bool):
        r, Ja, Jb = between_residual(values.atPose2(a), values.atPose2(b), measured, want)
        return r, ({a: Ja, b: Jb} if want else None)

    return residual


def point_factor(edge: PointEdge2D, point_key: int) -> gtsam.CustomFactor:
    measured = np.asarray(edge.measurement, dtype=float)
    a = edge.a

    def error_function(this: gtsam.CustomFactor, values: gtsam.Values, H) -> FloatArray:
        r, Jp, Jl = point_residual(
            values.atPose2(a), values.atPoint2(point_key), measured, H is not None
        )
        if H is not None:
            H[0] = Jp
            H[1] = Jl
        return r

    noise = gtsam.noiseModel.Gaussian.Information(edge.information)
    return gtsam.CustomFactor(noise, [a, point_key], error_function)


class PointEdges:
    """Many pose-to-point edges (``EDGE_SE2_XY``) evaluated and linearised together in numpy:
    the residual, Jacobians and whitening of :func:`point_factor`, without a Python callback
    per edge (which was most of a landmark graph's least-squares solve). For the
    Levenberg-Marquardt loop of :mod:`semslam.mapping.levenberg` (``extra``)."""

    def __init__(self, edges: Sequence[PointEdge2D], point_key: dict[int, int]) -> None:
        self._keys = [(e.a, point_key[e.b]) for e in edges]
        self._poses = sorted({a for a, _ in self._keys})
        self._points = sorted({b for _, b in self._keys})
        row_of_pose = {k: i for i, k in enumerate(self._poses)}
        row_of_point = {k: i for i, k in enumerate(self._points)}
        self._pose_row = np.array([row_of_pose[a] for a, _ in self._keys], dtype=np.intp)
        self._point_row = np.array([row_of_point[b] for _, b in self._keys], dtype=np.intp)
        self._measured = np.array([e.measurement for e in edges], dtype=float).reshape(-1, 2)
        self._sqrt_information = np.array(
            [_sqrt_information(np.asarray(e.information, dtype=float)) for e in edges]
        ).reshape(-1, 2, 2)
        self._unit = gtsam.noiseModel.Unit.Create(2)

    def _whitened(self, values: gtsam.Values, jacobians: bool):
        """Whitened residuals (M, 2) and, if asked, the whitened Jacobians with respect to
        the pose (M, 2, 3) and the point (M, 2, 2)."""
        poses = np.array(
            [[p.x(), p.y(), p.theta()] for p in map(values.atPose2, self._poses)]
        ).reshape(-1, 3)
        points = np.array([values.atPoint2(k) for k in self._points]).reshape(-1, 2)
        pose, d = poses[self._pose_row], points[self._point_row] - poses[self._pose_row, :2]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
        R = self._sqrt_information
        whitened = np.einsum("mij,mj->mi", R, local - self._measured)
        if not jacobians:
            return whitened, None, None
        Jp = np.zeros((len(local), 2, 3))
        Jp[:, 0, 0] = Jp[:, 1, 1] = -1.0
        Jp[:, 0, 2], Jp[:, 1, 2] = local[:, 1], -local[:, 0]
        Jl = np.stack([np.column_stack([c, s]), np.column_stack([-s, c])], axis=1)
        return whitened, R @ Jp, R @ Jl

    def error(self, values: gtsam.Values) -> float:
        """``1/2 sum |R r|^2`` over the edges (gtsam's factor error)."""
        if not self._keys:
            return 0.0
        whitened, _, _ = self._whitened(values, False)
        return 0.5 * float(np.sum(whitened * whitened))

    def linearize(self, values: gtsam.Values) -> list[gtsam.JacobianFactor]:
        """One whitened Jacobian factor per edge, as gtsam linearises :func:`point_factor`."""
        if not self._keys:
            return []
        whitened, Ap, Al = self._whitened(values, True)
        return [
            gtsam.JacobianFactor(a, Ap[m], b, Al[m], -whitened[m], self._unit)
            for m, (a, b) in enumerate(self._keys)
        ]


def _sqrt_information(information: FloatArray) -> FloatArray:
    """Upper-triangular R with ``R' R = information``."""
    return np.linalg.cholesky(information).T


def between_factor(edge: Edge2D, noise=None) -> gtsam.BetweenFactorPose2:
    if noise is None:
        noise = gtsam.noiseModel.Gaussian.Information(edge.information)
    return gtsam.BetweenFactorPose2(edge.a, edge.b, gtsam.Pose2(*edge.measurement), noise)


# --------------------------------------------------------------------------- mixtures


def null_components(mixture: MixtureEdge2D) -> list[bool]:
    """Which components of a mixture are null hypotheses: information at most
    :data:`NULL_INFORMATION_RATIO` of another component's (largest eigenvalue of the
    candidate against the smallest of the other)."""
    largest = [float(np.linalg.eigvalsh(c.edge.information)[-1]) for c in mixture.components]
    smallest = [float(np.linalg.eigvalsh(c.edge.information)[0]) for c in mixture.components]
    strongest = max(smallest)
    return [lam <= NULL_INFORMATION_RATIO * strongest for lam in largest]


class CompiledMixture:
    """One mixture edge compiled for gtsam; ``allowed`` are the non-null components the
    front end lets into the back end (the nulls always take part)."""

    def __init__(self, mixture: MixtureEdge2D) -> None:
        self.mixture = mixture
        self.components = list(mixture.components)
        self.is_null = null_components(mixture)
        self.real = [k for k, n in enumerate(self.is_null) if not n]
        self.nulls = [k for k, n in enumerate(self.is_null) if n]
        self.native_null = self._native_null()
        #: ``-log w_k + 1/2 log det Sigma_k`` per component, as the file gives them
        self.constants = np.array(
            [
                -math.log(c.weight) - 0.5 * np.linalg.slogdet(c.edge.information)[1]
                for c in self.components
            ]
        )
        pairs = {(c.edge.a, c.edge.b) for c in self.components}
        #: every component joins the same two poses (a measurement or its null)
        self.single_pair = len(pairs) == 1

    def _native_null(self) -> NullHypothesis | None:
        """The null as a robust loss when the mixture is {measurement, scaled copy}."""
        if len(self.components) != 2 or len(self.real) != 1:
            return None
        meas = self.components[self.real[0]]
        null = self.components[self.nulls[0]]
        if (meas.edge.a, meas.edge.b) != (null.edge.a, null.edge.b) or not np.array_equal(
            meas.edge.measurement, null.edge.measurement
        ):
            return None
        scale = float(np.trace(null.edge.information) / np.trace(meas.edge.information))
        if not np.allclose(
            null.edge.information, scale * meas.edge.information, rtol=1e-6, atol=0.0
        ):
            return None
        return NullHypothesis(null.weight / (meas.weight + null.weight), scale)

    def arrival(self, position: dict[int, int]) -> int:
        """Position (in time order) of the last pose any component needs."""
        return max(position[v] for c in self.components for v in (c.edge.a, c.edge.b))

    def factor(self, allowed: Sequence[int]):
        """The gtsam factor of the allowed real components and every null."""
        allowed = sorted(allowed)
        if not self.nulls:  # no null hypothesis: a plain measurement or a choice among real ones
            if len(allowed) == 1:
                return between_factor(self.components[allowed[0]].edge), allowed
        elif self.native_null is not None and allowed == self.real:
            edge = self.components[self.real[0]].edge
            noise = null_hypothesis_noise(np.linalg.inv(edge.information), self.native_null)
            return between_factor(edge, noise), allowed + self.nulls
        used = allowed + self.nulls
        comps = [
            Component(
                _between_residual_function(self.components[k].edge),
                _sqrt_information(self.components[k].edge.information),
                self.components[k].weight,
            )
            for k in used
        ]
        # The factor's keys are the poses of its real components. A null component on another
        # pose pair is evaluated exactly (the residual reads its poses from the values), but its
        # Jacobian blocks on poses no real component uses are left out: they are scaled by the
        # square root of the null's information scale (3e-4 for 1e-7) and would only add
        # fill-in, linking each closure to a far pose in every elimination.
        keys = sorted(
            {v for k in allowed for v in (self.components[k].edge.a, self.components[k].edge.b)}
        )
        mix = MaxMixture(keys, [3] * len(keys), comps)
        return mix.factor(), used

    def costs(self, values: gtsam.Values, used: Sequence[int]) -> list[float]:
        """``1/2 chi2_k + c_k`` for the components ``used`` (constants over ``used``)."""
        chi = []
        for k in used:
            edge = self.components[k].edge
            r, _, _ = between_residual(
                values.atPose2(edge.a),
                values.atPose2(edge.b),
                gtsam.Pose2(*edge.measurement),
                False,
            )
            chi.append(float(r @ edge.information @ r))
        return list(0.5 * np.array(chi) + self.constants[list(used)])

    def chosen(self, values: gtsam.Values, used: Sequence[int]) -> int:
        costs = self.costs(values, used)
        return int(used[int(np.argmin(costs))])


__all__ = [
    "NULL_INFORMATION_RATIO",
    "CompiledMixture",
    "between_factor",
    "between_residual",
    "null_components",
    "point_factor",
    "point_residual",
]
