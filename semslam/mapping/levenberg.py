"""Levenberg-Marquardt over a gtsam factor graph, driven from Python.

gtsam's own ``LevenbergMarquardtOptimizer`` calls a Python ``CustomFactor`` with Values it
made itself, and pybind11 copies the whole Values for every such call, so a graph of N
variables and M Python factors costs O(N M) per linearisation (``BENCHMARKS.md``, "Why
`large` was quadratic"; the demo's 1,623-variable landmark graph: 28 s against 0.4 s in
g2o). Here the Values is always one of ours, passed by reference.

The loop: linearise, add damping ``lambda I`` as unit Jacobian factors on every variable,
solve (gtsam's elimination, COLAMD), retract; keep the step only if the nonlinear error
does not rise (so max-mixtures' switching is judged on the true error), then lambda / 10,
else lambda x 10 and solve again. A damped system that gtsam finds indeterminate (a tiny
lambda on an ill-conditioned graph: the odometry's information across the car reaches
1e9) is a failed step too, as in gtsam's own optimizer: lambda x 10. Stops after
``max_iterations``, when no lambda up to 1e10 lowers the error, or when a kept step lowers
it by at most ``relative_tolerance`` of it.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

INITIAL_LAMBDA = 1e-5
MAX_LAMBDA = 1e10


def tangent_dimensions(values: gtsam.Values) -> dict[int, int]:
    """Key -> tangent dimension of every variable in ``values``."""
    zero = values.zeroVectors()
    return {int(key): int(np.size(zero.at(key))) for key in values.keys()}  # noqa: SIM118 (not iterable)


def levenberg_marquardt(
    factors: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    max_iterations: int,
    relative_tolerance: float,
    dims: dict[int, int] | None = None,
    extra: Sequence = (),
) -> tuple[gtsam.Values, int]:
    """Minimise ``factors`` from ``values``; returns (solution, iterations).

    Args:
        factors: the nonlinear factor graph (native or Python factors).
        values: the start; not changed.
        max_iterations: linearisations at most.
        relative_tolerance: stop when a kept step lowers the error by at most this share.
        dims: tangent dimension per key (default: from ``values``).
        extra: more terms of the cost outside ``factors``, each with ``error(values)`` and
            ``linearize(values)`` (a list of gtsam linear factors), e.g.
            :class:`~semslam.mapping.g2o_factors.PointEdges`.

    Raises:
        RuntimeError: gtsam found the damped system indeterminate at every lambda up to
            :data:`MAX_LAMBDA` (its own exception).
    """
    dims = tangent_dimensions(values) if dims is None else dims
    unit = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}

    def cost(at: gtsam.Values) -> float:
        return factors.error(at) + sum(term.error(at) for term in extra)

    error = cost(values)
    lam, iterations = INITIAL_LAMBDA, 0
    while iterations < max_iterations:
        iterations += 1
        linear = factors.linearize(values)
        for term in extra:
            for factor in term.linearize(values):
                linear.push_back(factor)
        while lam <= MAX_LAMBDA:
            damped = gtsam.GaussianFactorGraph()
            damped.push_back(linear)
            for key, dim in dims.items():
                damped.add(
                    gtsam.JacobianFactor(key, np.eye(dim) * np.sqrt(lam), np.zeros(dim), unit[dim])
                )
            try:
                candidate = values.retract(damped.optimize())
            except RuntimeError:  # gtsam's indeterminate system: damp more
                if lam * 10.0 > MAX_LAMBDA:
                    raise
                lam *= 10.0
                continue
            new_error = cost(candidate)
            if new_error <= error:
                break
            lam *= 10.0
        else:
            break  # no damping gives a lower error: converged
        improvement = error - new_error
        values, error, lam = candidate, new_error, max(lam / 10.0, 1e-12)
        if improvement <= relative_tolerance * max(error, 1e-12):
            break
    return values, iterations
