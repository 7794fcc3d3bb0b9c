"""Why iSAM2 must not call Python factors itself (BENCHMARKS.md, mapper scaling).

Adds 100 Python CustomFactors to an iSAM2 that already holds N variables, two ways:
gtsam's own iSAM2 calling the Python factors (pybind11 copies iSAM2's whole Values
for each call), and semslam's Graph (factors linearised in Python, given to iSAM2 as
native LinearContainerFactors). Prints milliseconds per 100 factors, median of 5.

    PYTHONPATH=. python benchmarks/bench_isam2_python_factors.py
"""

from __future__ import annotations

import statistics
import time

import gtsam
import numpy as np

from semslam.mapping.graph import Graph


def _error(this: gtsam.CustomFactor, values: gtsam.Values, H):
    p = values.atPoint2(this.keys()[0])
    if H is not None:
        H[0] = np.eye(2)
    return p


def _custom(key: int) -> gtsam.CustomFactor:
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [key], _error)


def _prior(key: int) -> gtsam.NonlinearFactor:
    return gtsam.PriorFactorPoint2(key, np.zeros(2), gtsam.noiseModel.Unit.Create(2))


def gtsam_isam2_ms(n: int) -> float:
    isam = gtsam.ISAM2()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for key in range(n):
        values.insert(key, np.array([1.0, 2.0]))
        graph.add(_prior(key))
    isam.update(graph, values)
    graph = gtsam.NonlinearFactorGraph()
    for key in range(100):
        graph.add(_custom(key))
    started = time.perf_counter()
    isam.update(graph, gtsam.Values())
    return (time.perf_counter() - started) * 1e3


def semslam_graph_ms(n: int) -> float:
    graph = Graph()
    for key in range(n):
        graph.add_point(key, np.array([1.0, 2.0]))
        graph.add_factor(_prior(key))
    graph.update()
    for key in range(100):
        graph.add_factor(_custom(key))
    started = time.perf_counter()
    graph.update()
    return (time.perf_counter() - started) * 1e3


def main() -> None:
    print("| variables in iSAM2 | gtsam iSAM2 calling Python, ms | semslam Graph, ms |")
    print("|---|---|---|")
    for n in (100, 2_000, 10_000, 30_000):
        own = statistics.median(gtsam_isam2_ms(n) for _ in range(5))
        ours = statistics.median(semslam_graph_ms(n) for _ in range(5))
        print(f"| {n:,} | {own:.1f} | {ours:.1f} |")


if __name__ == "__main__":
    main()
