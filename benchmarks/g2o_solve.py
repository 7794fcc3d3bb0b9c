"""g2o's Levenberg-Marquardt on a 2D graph given as JSON: the child process of
``compare_with_g2o.py``. Needs only numpy and g2o-python (see that script's doc).

Usage::

    python benchmarks/g2o_solve.py JOB.json OUT.json
"""

from __future__ import annotations

import json
import sys
import time

import g2o
import numpy as np


def main(job_path: str, out_path: str) -> int:
    with open(job_path) as f:
        job = json.load(f)
    # timed from the graph description in memory to the solution, as semslam's side is
    # (optimize_pose_graph builds its gtsam graph, solves and reads the estimate back)
    start = time.perf_counter()
    optimizer = g2o.SparseOptimizer()
    solver = g2o.BlockSolverX(g2o.LinearSolverEigenX())
    optimizer.set_algorithm(g2o.OptimizationAlgorithmLevenberg(solver))
    fixed = set(job["fixed"])
    for key, (x, y, yaw) in job["vertices"].items():
        v = g2o.VertexSE2()
        v.set_id(int(key))
        v.set_estimate(g2o.SE2(x, y, yaw))
        v.set_fixed(int(key) in fixed)
        optimizer.add_vertex(v)
    for key, p in job["points"].items():
        v = g2o.VertexPointXY()
        v.set_id(int(key))
        v.set_estimate(np.array(p))
        optimizer.add_vertex(v)

    def add(edge: dict, kind, measurement, kernel=None) -> None:
        e = kind()
        e.set_vertex(0, optimizer.vertex(edge["a"]))
        e.set_vertex(1, optimizer.vertex(edge["b"]))
        e.set_measurement(measurement)
        e.set_information(np.array(edge["information"]))
        if kernel is not None:
            e.set_robust_kernel(kernel)
        optimizer.add_edge(e)

    for edge in job["edges"]:
        add(edge, g2o.EdgeSE2, g2o.SE2(*edge["measurement"]))
    for edge in job["point_edges"]:
        add(edge, g2o.EdgeSE2PointXY, np.array(edge["measurement"]))
    for edge in job["robust_edges"]:
        kernel = g2o.RobustKernelDCS()
        kernel.set_delta(job["dcs_phi"])
        add(edge, g2o.EdgeSE2, g2o.SE2(*edge["measurement"]), kernel)
    optimizer.initialize_optimization()
    optimizer.optimize(job["iterations"])
    vertices = {}
    for key in job["vertices"]:
        est = optimizer.vertex(int(key)).estimate()
        t = est.translation()
        vertices[key] = [float(t[0]), float(t[1]), float(est.rotation().angle())]
    points = {key: list(map(float, optimizer.vertex(int(key)).estimate())) for key in job["points"]}
    seconds = time.perf_counter() - start
    with open(out_path, "w") as f:
        json.dump({"vertices": vertices, "points": points, "seconds": seconds}, f)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(*sys.argv[1:3]))
