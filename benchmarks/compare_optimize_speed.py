"""`semslam optimize --robust maxmix` time of two versions of semslam on growing pose graphs.

    git worktree add /tmp/baseline REV
    PYTHONPATH=. python benchmarks/compare_optimize_speed.py --baseline /tmp/baseline \
        [--files ../shared/benchmarks/robust-backend/manhattan/outliers/*.g2o] \
        [--poses 875 1750 3500] [--work /tmp/semslam-optimize-speed]

Each file is cut to its first ``poses`` poses (ids below the count, which in the Manhattan
files is time order; every edge and mixture between them kept), so a graph grows as its
drive does. For each cut, `semslam optimize CUT -o OUT --robust maxmix` with the baseline's
source tree and then with this one; prints the wall time of each and whether the two wrote
the same graph, byte for byte.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

from _common import report, run_python_in

from semslam.io.g2o import PoseGraph2D, read_g2o, write_g2o

HERE = Path(__file__).resolve().parents[1]
OUTLIERS = HERE.parent / "shared" / "benchmarks" / "robust-backend" / "manhattan" / "outliers"


def first_poses(graph: PoseGraph2D, count: int) -> PoseGraph2D:
    """``graph`` cut to its poses of id below ``count`` and everything between them."""

    def kept(*ids: int) -> bool:
        return all(i < count for i in ids)

    return replace(
        graph,
        vertices={i: p for i, p in graph.vertices.items() if i < count},
        edges=[e for e in graph.edges if kept(e.a, e.b)],
        mixtures=[
            m for m in graph.mixtures
            if kept(m.a, m.b) and all(kept(c.edge.a, c.edge.b) for c in m.components)
        ],
        fixed=[i for i in graph.fixed if i < count],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="source tree to compare")
    parser.add_argument("--files", nargs="+", type=Path, default=sorted(OUTLIERS.glob("*.g2o")))
    parser.add_argument("--poses", nargs="+", type=int, default=[875, 1750, 3500])
    parser.add_argument("--work", type=Path, default=Path("/tmp/semslam-optimize-speed"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    rows = []
    for path in args.files:
        graph = read_g2o(path)
        for count in args.poses:
            cut = first_poses(graph, count)
            name = f"{path.stem[:22]}-{count}"
            source = args.work / f"{name}.g2o"
            write_g2o(source, cut)
            row = {"file": path.stem[:22], "poses": len(cut.vertices),
                   "mixtures": len(cut.mixtures)}
            written = {}
            for version, root in (("baseline", args.baseline.resolve()), ("this", HERE)):
                out = args.work / f"{name}-{version}.g2o"
                started = time.perf_counter()
                run_python_in(root, ["-m", "semslam", "optimize", str(source), "-o", str(out),
                                     "--robust", "maxmix"])
                row[f"{version}_s"] = round(time.perf_counter() - started, 2)
                written[version] = out.read_bytes()
            row["same_graph"] = written["baseline"] == written["this"]
            rows.append(row)
            print(row, file=sys.stderr, flush=True)
    lines = ["| file | poses | mixtures | baseline s | this s | same graph |", "|" + " --- |" * 6]
    lines += [f"| {r['file']} | {r['poses']} | {r['mixtures']} | {r['baseline_s']} | "
              f"{r['this_s']} | {r['same_graph']} |" for r in rows]
    report("\n".join(lines), {"rows": rows}, args.json)


if __name__ == "__main__":
    main()
