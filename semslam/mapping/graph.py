"""A small wrapper over GTSAM: variables, factors, iSAM2 updates, batch LM, marginals.

Everything outside ``semslam.mapping`` speaks numpy poses ``(x, y, yaw)`` and
points ``(x, y)``; this wrapper is where they become gtsam values.
"""

from __future__ import annotations

import gtsam
import numpy as np

from semslam.geometry import FloatArray


class Graph:
    """All factors ever added (for the final batch solve) plus an incremental iSAM2."""

    def __init__(self, relinearize_threshold: float = 0.05, relinearize_skip: int = 5) -> None:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize_threshold)
        params.relinearizeSkip = relinearize_skip
        params.setFactorization(
            "QR"
        )  # Cholesky fails on the ill-conditioned steps null losses give
        self.isam = gtsam.ISAM2(params)
        self.factors = gtsam.NonlinearFactorGraph()
        self.estimate = gtsam.Values()
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()

    # -- building
    def add_pose(self, key: int, pose: FloatArray) -> None:
        value = gtsam.Pose2(*map(float, pose))
        self._new_values.insert(key, value)
        self.estimate.insert(key, value)

    def add_point(self, key: int, point: FloatArray) -> None:
        value = np.asarray(point, dtype=float)
        self._new_values.insert(key, value)
        self.estimate.insert(key, value)

    def add_vector(self, key: int, vector: FloatArray) -> None:
        value = np.asarray(vector, dtype=float)
        self._new_values.insert(key, value)
        self.estimate.insert(key, value)

    def add_factor(self, factor: gtsam.NonlinearFactor) -> None:
        self._new_factors.add(factor)
        self.factors.add(factor)

    def has(self, key: int) -> bool:
        return self.estimate.exists(key)

    # -- solving
    def update(self) -> None:
        """One iSAM2 step with everything added since the last one."""
        self.isam.update(self._new_factors, self._new_values)
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self.estimate = self.isam.calculateEstimate()

    def optimize_batch(self, max_iterations: int = 100) -> int:
        """Levenberg-Marquardt over all factors from the current estimate; returns iterations."""
        if self._new_factors.size() or self._new_values.size():
            self.update()
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        params.setRelativeErrorTol(1e-7)
        optimizer = gtsam.LevenbergMarquardtOptimizer(self.factors, self.estimate, params)
        self.estimate = optimizer.optimize()
        return int(optimizer.iterations())

    def error(self) -> float:
        return float(self.factors.error(self.estimate))

    # -- reading
    def pose(self, key: int) -> FloatArray:
        p = self.estimate.atPose2(key)
        return np.array([p.x(), p.y(), p.theta()])

    def point(self, key: int) -> FloatArray:
        return np.asarray(self.estimate.atPoint2(key), dtype=float)

    def vector(self, key: int) -> FloatArray:
        return np.asarray(self.estimate.atVector(key), dtype=float)

    def marginals(self) -> gtsam.Marginals | None:
        """Marginal covariances at the current estimate (None if the system is singular)."""
        try:
            return gtsam.Marginals(self.factors, self.estimate)
        except RuntimeError:
            return None
