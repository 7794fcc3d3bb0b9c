"""`semslam optimize`: optimise a 2D g2o pose graph and write the result.

Reads the graph, runs :func:`semslam.mapping.pose_graph.optimize_pose_graph`, and writes a
g2o file with the same edges, mixtures and FIX lines whose vertices are the optimised
poses and points (atomically: a failed run leaves no partial file).
"""

from __future__ import annotations

import os
from dataclasses import replace

from semslam.io._text import path_text
from semslam.io.g2o import read_g2o, write_g2o
from semslam.mapping.pose_graph import optimize_pose_graph


def optimize_g2o_file(
    in_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    robust: str = "maxmix",
    **options,
) -> dict:
    """Optimise the g2o graph at ``in_path`` and write it to ``out_path``.

    Args:
        in_path: the input graph (its vertices are the initial guess).
        out_path: the output graph; its folder is created if missing.
        robust: ``"none"``, ``"maxmix"`` or ``"dcs"``.
        **options: passed to :func:`~semslam.mapping.pose_graph.optimize_pose_graph`
            (``schedule``, ``gate_probability``...).

    Returns:
        A JSON-ready summary: paths, counts of vertices / edges / mixtures / points,
        ``robust`` and ``schedule``, ``accepted`` / ``rejected`` / ``gated`` mixture counts,
        ``chosen`` (per mixture, in file order, the index of the component in force),
        ``iterations``, ``isam2_updates``, ``error`` (the max-mixture cost of the result) and
        ``seconds`` (optimisation wall time).

    Raises:
        FormatError: the input is not a readable g2o graph, or the output cannot be written
            as one.
        ValueError: an unknown ``robust`` mode or option value.
        OSError: the output cannot be written (the target is unchanged).
    """
    graph = read_g2o(in_path)
    result = optimize_pose_graph(graph, robust, **options)
    optimized = replace(graph, vertices=result.pose_dict(), points=result.point_dict())
    # keep the file's vertex order
    optimized.vertices = {vid: optimized.vertices[vid] for vid in graph.vertices}
    optimized.points = {pid: optimized.points[pid] for pid in graph.points}
    write_g2o(out_path, optimized)
    n_mix = len(graph.mixtures)
    accepted = int(result.accepted.sum())
    return {
        "input": path_text(in_path),
        "output": path_text(out_path),
        "robust": result.robust,
        "schedule": result.schedule,
        "poses": len(graph.vertices),
        "points": len(graph.points),
        "edges": len(graph.edges),
        "point_edges": len(graph.point_edges),
        "mixtures": n_mix,
        "accepted": accepted,
        "rejected": n_mix - accepted,
        "gated": int(result.gated.sum()),
        "chosen": [int(k) for k in result.chosen],
        "iterations": result.iterations,
        "isam2_updates": result.updates,
        "error": result.error,
        "seconds": result.seconds,
    }
