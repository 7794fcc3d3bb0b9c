"""semslam's pose-graph solutions against g2o's own optimizer, on the same g2o files.

g2o (Kümmerle et al. 2011, ``pip install g2o-python``) is the reference its file format
comes from. This script reads a graph with semslam's reader, builds the same graph with
g2o's own types (``VertexSE2``, ``VertexPointXY``, ``EdgeSE2``, ``EdgeSE2PointXY``: the
file's ``VERTEX_SE2``, ``VERTEX_XY``, ``EDGE_SE2``, ``EDGE_SE2_XY``), solves it with g2o's
Levenberg-Marquardt, and compares the solution with semslam's:

- graphs without mixtures: ``optimize_pose_graph(graph, "none")`` against plain g2o;
- graphs whose mixtures are a measurement and its null (the outlier files): also
  ``optimize_pose_graph(graph, "dcs")`` against each measurement under g2o's
  ``RobustKernelDCS`` with the same width.

It prints, per solver, the chi-square of the plain (un-kernelled) graph at its solution,
the wall time, and the RMSE between the two solutions' positions (poses and points).
g2o runs in a child process (``benchmarks/g2o_solve.py``, which needs only numpy and g2o):
g2o-python 0.0.12, the newest on PyPI, crashes on numpy 2 arrays, so it lives in its own
environment with numpy 1.26. Its ``SparseOptimizer.load`` registers no types
(RainerKuemmerle/g2o#793), so the graph is built through the API rather than loaded.

Usage::

    python -m venv /tmp/g2o && /tmp/g2o/bin/pip install "numpy<2" g2o-python==0.0.12
    PYTHONPATH=. python benchmarks/compare_with_g2o.py GRAPH.g2o [GRAPH.g2o ...]
        --g2o-python /tmp/g2o/bin/python [--iterations 100] [--json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gtsam
import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from semslam.errors import MappingError  # noqa: E402
from semslam.io.g2o import PoseGraph2D, read_g2o  # noqa: E402
from semslam.mapping.g2o_factors import between_factor  # noqa: E402
from semslam.mapping.pose_graph import (  # noqa: E402
    DCS_PHI,
    optimize_pose_graph,
    plain_graph,
    single_measurements,
)

G2O_SOLVER = Path(__file__).with_name("g2o_solve.py")


def closure_edges(graph: PoseGraph2D) -> list | None:
    """Each mixture's one measurement component, or None when a mixture has several."""
    try:
        return single_measurements(graph)
    except MappingError:
        return None


def solve_with_g2o(graph: PoseGraph2D, robust: str, iterations: int, python: str):
    """g2o's LM on ``graph``, in a child process run by ``python`` (an interpreter with
    g2o-python; see the module doc): with ``robust="dcs"`` each mixture's measurement goes in
    under ``RobustKernelDCS``. Returns ({pose id: (x, y, yaw)}, {point id: (x, y)}, seconds)."""
    job = {
        "iterations": iterations,
        "fixed": sorted(set(graph.fixed) or {min(graph.vertices)}),
        "vertices": {str(k): list(map(float, v)) for k, v in graph.vertices.items()},
        "points": {str(k): list(map(float, v)) for k, v in graph.points.items()},
        "edges": [_edge_json(e) for e in graph.edges],
        "point_edges": [_edge_json(e) for e in graph.point_edges],
        "robust_edges": [_edge_json(e) for e in closure_edges(graph)] if robust == "dcs" else [],
        "dcs_phi": DCS_PHI,
    }
    with tempfile.TemporaryDirectory() as tmp:
        job_path, out_path = Path(tmp) / "job.json", Path(tmp) / "out.json"
        job_path.write_text(json.dumps(job))
        subprocess.run([python, str(G2O_SOLVER), str(job_path), str(out_path)], check=True, cwd=tmp)
        out = json.loads(out_path.read_text())
    poses = {int(k): np.array(v) for k, v in out["vertices"].items()}
    points = {int(k): np.array(v) for k, v in out["points"].items()}
    return poses, points, out["seconds"]


def _edge_json(edge) -> dict:
    return {
        "a": int(edge.a),
        "b": int(edge.b),
        "measurement": list(map(float, edge.measurement)),
        "information": np.asarray(edge.information, dtype=float).tolist(),
    }


def plain_chi2(graph: PoseGraph2D, poses: dict, points: dict, closures) -> float:
    """Chi-square of the plain graph (semslam's factors for the prior, odometry, landmark
    edges and, if given, the closures without any kernel) at a solution; the same for both
    solvers."""
    fg, _ = plain_graph(graph)
    for edge in closures or []:
        fg.add(between_factor(edge))
    solution = gtsam.Values()
    for vid, (x, y, yaw) in poses.items():
        solution.insert(int(vid), gtsam.Pose2(float(x), float(y), float(yaw)))
    for pid, point in points.items():
        solution.insert(int(pid), np.asarray(point, dtype=float))
    return 2.0 * fg.error(solution)


def rmse_between(a: dict, b: dict) -> float:
    keys = sorted(a)
    if not keys:
        return 0.0
    d = np.array([np.asarray(a[k])[:2] - np.asarray(b[k])[:2] for k in keys])
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def compare(path: Path, iterations: int, python: str) -> list[dict]:
    graph = read_g2o(path)
    closures = closure_edges(graph)
    modes = []
    if not graph.mixtures:
        modes.append("none")
    if graph.mixtures and closures is not None:
        modes.append("dcs")
    rows = []
    for mode in modes:
        t0 = time.perf_counter()
        ours = optimize_pose_graph(graph, mode, max_iterations=iterations)
        ours_s = time.perf_counter() - t0
        our_poses, our_points = ours.pose_dict(), ours.point_dict()
        g2o_poses, g2o_points, g2o_s = solve_with_g2o(graph, mode, iterations, python)
        rows.append(
            {
                "file": path.name,
                "mode": mode,
                "poses": len(graph.vertices),
                "points": len(graph.points),
                "semslam_chi2": plain_chi2(graph, our_poses, our_points, closures),
                "g2o_chi2": plain_chi2(graph, g2o_poses, g2o_points, closures),
                "semslam_s": ours_s,
                "g2o_s": g2o_s,
                "pose_rmse_between_m": rmse_between(our_poses, g2o_poses),
                "point_rmse_between_m": rmse_between(our_points, g2o_points),
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("graphs", type=Path, nargs="+", help="g2o files")
    parser.add_argument("--iterations", type=int, default=100, help="LM iterations at most")
    parser.add_argument(
        "--g2o-python",
        default=sys.executable,
        help="the Python that has g2o-python (default: this one)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON only")
    args = parser.parse_args(argv)
    rows = [row for path in args.graphs for row in compare(path, args.iterations, args.g2o_python)]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(
        "| file | mode | poses / points | plain chi2, semslam / g2o | s, semslam / g2o "
        "| RMSE between the solutions, poses / points m |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(
            f"| {r['file']} | {r['mode']} | {r['poses']} / {r['points']} | "
            f"{r['semslam_chi2']:.2f} / {r['g2o_chi2']:.2f} | "
            f"{r['semslam_s']:.1f} / {r['g2o_s']:.1f} | "
            f"{r['pose_rmse_between_m']:.2e} / {r['point_rmse_between_m']:.2e} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
