"""Robust back-end benchmark on the Manhattan pose graphs (outlier and multimodal loop closures).

Runs every ``.g2o`` file under the benchmark root (default:
``../shared/benchmarks/robust-backend/manhattan`` relative to the repository root):

- the clean graph ``manhattanOlson3500.g2o``: least squares, the reference;
- each outlier file (``EDGE_SE2_MIXTURE`` with a measurement and a null): least squares,
  plain batch max-mixture and our max-mixture (incremental with the consistency front end);
  ATE, precision / recall of the accepted loop closures (the first ``n`` mixtures are the
  true closures, ``n`` = the loop closures of the clean graph; the rest are the wrong ones);
- each multimodal file (mixtures with several target poses): the same methods; the fraction
  of loop closures whose chosen component is the true one (the component whose pose pair is
  an edge of ``manhattanG2O3500_clean.g2o``) and ATE.

With ``--methods``, also the field's other robust back-ends on the outlier files: the library's
DCS (``dcs``, ``optimize_pose_graph(graph, "dcs")``) and, built here on gtsam, Huber, Cauchy,
Geman-McClure (``huber``, ``cauchy``, ``gm``) and graduated non-convexity with a truncated
quadratic (``gnc-tls``); a kernel "accepts" a closure whose chi-square at its solution is
within chi2_3(0.99).

ATE is the RMSE of the positions against ``manhattanOlson3500_nodes_groundTruth.dat`` with the
first pose fixed (pose 0 is the origin in the graphs and in the ground truth; no alignment:
the README's 1.18 m for the clean least-squares solution is this number). The table also gives
the RMSE after the best SE(2) alignment and the RMSE to the clean least-squares solution (0
means "as good as without outliers").

Usage::

    PYTHONPATH=. python tools/bench_robust_backend.py [--root DIR] [--methods ...] [--json OUT]
    PYTHONPATH=. python tools/bench_robust_backend.py \
        --methods none,maxmix-batch,maxmix,huber,cauchy,gm,dcs,gnc-tls  # about 35 minutes
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from semslam.chi2 import chi2_quantile  # noqa: E402
from semslam.io.g2o import PoseGraph2D, read_g2o  # noqa: E402
from semslam.mapping.g2o_factors import between_factor  # noqa: E402
from semslam.mapping.pose_graph import (  # noqa: E402
    optimize_pose_graph,
    plain_graph,
    single_measurements,
)

DEFAULT_ROOT = REPO.parent / "shared" / "benchmarks" / "robust-backend" / "manhattan"
CLEAN = "manhattanOlson3500.g2o"
MM_CLEAN = "manhattanG2O3500_clean.g2o"
GROUND_TRUTH = "manhattanOlson3500_nodes_groundTruth.dat"
METHODS = {
    "none": {"robust": "none"},
    "maxmix-batch": {"robust": "maxmix", "schedule": "batch", "gate_probability": None},
    "maxmix-inc-nogate": {"robust": "maxmix", "schedule": "incremental", "gate_probability": None},
    "maxmix-inc": {"robust": "maxmix", "schedule": "incremental"},
    "maxmix": {"robust": "maxmix"},  # the library's default: schedule "auto"
    "dcs": {"robust": "dcs"},  # the library's dynamic covariance scaling (outlier files only)
}
DEFAULT_METHODS = ("none", "maxmix-batch", "maxmix")
#: The field's other robust back-ends in gtsam, run on the outlier files only (each closure's
#: measurement component with a robust loss; the null component is dropped): M-estimators
#: on a batch LM from the file's initial guess, and graduated non-convexity with a
#: truncated quadratic (Yang et al. 2020), odometry and the prior known inliers.
BASELINES = {
    "huber": lambda: gtsam.noiseModel.mEstimator.Huber.Create(1.345),
    "cauchy": lambda: gtsam.noiseModel.mEstimator.Cauchy.Create(1.0),
    "gm": lambda: gtsam.noiseModel.mEstimator.GemanMcClure.Create(1.0),
    "gnc-tls": None,
}
#: A baseline "accepts" a closure whose chi-square at its solution is within this quantile
#: of chi2(3) (GNC: whose final weight is above one half).
BASELINE_ACCEPT_PROBABILITY = 0.99


# --------------------------------------------------------------------------- metrics


def ate_fixed(poses: np.ndarray, truth: np.ndarray) -> float:
    """Position RMSE without alignment (both start at the origin)."""
    d = poses[:, :2] - truth[:, :2]
    return float(math.sqrt(np.mean(np.sum(d * d, axis=1))))


def ate_aligned(poses: np.ndarray, truth: np.ndarray) -> float:
    """Position RMSE after the least-squares rigid SE(2) alignment of poses onto truth."""
    a, b = poses[:, :2], truth[:, :2]
    A, B = a - a.mean(0), b - b.mean(0)
    U, _, Vt = np.linalg.svd(A.T @ B)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, d]) @ U.T
    e = A @ R.T - B
    return float(math.sqrt(np.mean(np.sum(e * e, axis=1))))


def loop_closure_pairs(graph: PoseGraph2D) -> set[tuple[int, int]]:
    """Unordered pose pairs of the edges that are not odometry (ids not consecutive)."""
    return {tuple(sorted((e.a, e.b))) for e in graph.edges if abs(e.a - e.b) != 1}


def classify(graph: PoseGraph2D) -> str:
    if not graph.mixtures:
        return "clean"
    if all(len(m.components) == 2 for m in graph.mixtures):
        return "outliers"
    return "multimodal"


# --------------------------------------------------------------------------- baselines


class BaselineResult:
    """What :func:`solve_baseline` returns: the same fields the tool reads from
    :func:`optimize_pose_graph`'s result."""

    def __init__(self, poses: np.ndarray, accepted: np.ndarray, iterations: int) -> None:
        self.poses = poses
        self.accepted = accepted
        self.iterations = iterations
        self.updates = 0
        self.error = float("nan")
        self.gated = np.zeros(len(accepted), dtype=bool)


def solve_baseline(graph: PoseGraph2D, method: str) -> BaselineResult:
    """One of :data:`BASELINES` on a graph whose mixtures are (measurement, null) pairs."""
    fg, values = plain_graph(graph)
    known_inliers = list(range(fg.size()))
    closures = single_measurements(graph)
    kernel = BASELINES[method]
    for e in closures:
        gaussian = gtsam.noiseModel.Gaussian.Information(e.information)
        noise = gaussian if kernel is None else gtsam.noiseModel.Robust.Create(kernel(), gaussian)
        fg.add(between_factor(e, noise))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(200)
    if kernel is None:
        params = gtsam.GncLMParams(lm)
        params.setLossType(gtsam.GncLossType.TLS)
        params.setKnownInliers(known_inliers)
        gnc = gtsam.GncLMOptimizer(fg, values, params)
        gnc.setInlierCostThresholdsAtProbability(BASELINE_ACCEPT_PROBABILITY)
        result = gnc.optimize()
        accepted = np.asarray(gnc.getWeights())[len(known_inliers) :] > 0.5
        iterations = -1
    else:
        optimizer = gtsam.LevenbergMarquardtOptimizer(fg, values, lm)
        result = optimizer.optimize()
        iterations = optimizer.iterations()
        gate = chi2_quantile(BASELINE_ACCEPT_PROBABILITY, 3)
        accepted = np.array([2.0 * between_factor(e).error(result) <= gate for e in closures])
    poses = np.array(
        [[p.x(), p.y(), p.theta()] for p in (result.atPose2(v) for v in sorted(graph.vertices))]
    )
    return BaselineResult(poses, accepted, iterations)


# --------------------------------------------------------------------------- runs


def run_file(
    path: Path,
    method: str,
    truth: np.ndarray,
    reference: np.ndarray | None,
    n_true: int,
    true_pairs: set[tuple[int, int]] | None,
) -> dict:
    graph = read_g2o(path)
    kind = classify(graph)
    t0 = time.perf_counter()
    if method in BASELINES:
        result = solve_baseline(graph, method)
    else:
        result = optimize_pose_graph(graph, **METHODS[method])
    seconds = time.perf_counter() - t0
    row: dict = {
        "file": path.name,
        "kind": kind,
        "method": method,
        "ate_fixed_m": ate_fixed(result.poses, truth),
        "ate_aligned_m": ate_aligned(result.poses, truth),
        "rmse_to_clean_ls_m": (
            ate_fixed(result.poses, reference) if reference is not None else None
        ),
        "seconds": seconds,
        "iterations": result.iterations,
        "isam2_updates": result.updates,
        "model_cost": result.error,
        "mixtures": len(graph.mixtures),
        "gated": int(result.gated.sum()),
    }
    if kind == "outliers":
        truth_mask = np.arange(len(graph.mixtures)) < n_true
        acc = result.accepted
        tp = int(np.sum(acc & truth_mask))
        fp = int(np.sum(acc & ~truth_mask))
        fn = int(np.sum(~acc & truth_mask))
        row.update(
            tp=tp,
            fp=fp,
            fn=fn,
            tn=int(np.sum(~acc & ~truth_mask)),
            precision=tp / (tp + fp) if tp + fp else 1.0,
            recall=tp / (tp + fn) if tp + fn else 1.0,
        )
    elif kind == "multimodal" and true_pairs is not None:
        right = wrong = null = 0
        for mix, k in zip(graph.mixtures, result.chosen, strict=True):
            e = mix.components[k].edge
            pair = tuple(sorted((e.a, e.b)))
            if result.robust == "maxmix" and _is_null(mix, k):
                null += 1
            elif pair in true_pairs:
                right += 1
            else:
                wrong += 1
        row.update(right=right, wrong=wrong, null=null, right_fraction=right / len(graph.mixtures))
    return row


def _is_null(mix, k: int) -> bool:
    from semslam.mapping.g2o_factors import null_components

    return null_components(mix)[k]


def clean_reference(root: Path) -> np.ndarray | None:
    path = root / CLEAN
    if not path.exists():
        return None
    return optimize_pose_graph(read_g2o(path), "none").poses


# --------------------------------------------------------------------------- report


def _fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def table(rows: list[dict]) -> str:
    head = (
        "| file | method | ATE fixed [m] | ATE aligned [m] | to clean LS [m] | TP | FP | "
        "precision | recall | right comp. | gated | s |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        right = (
            f"{100 * r['right_fraction']:.2f} % ({r['wrong']} wrong, {r['null']} null)"
            if "right_fraction" in r
            else "-"
        )
        lines.append(
            f"| {r['file']} | {r['method']} | {_fmt(r['ate_fixed_m'], '.3f')} | "
            f"{_fmt(r['ate_aligned_m'], '.3f')} | {_fmt(r['rmse_to_clean_ls_m'], '.3f')} | "
            f"{r.get('tp', '-')} | {r.get('fp', '-')} | "
            f"{_fmt(r.get('precision'), '.4f')} | {_fmt(r.get('recall'), '.4f')} | {right} | "
            f"{r['gated']} | {r['seconds']:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--root",
        type=Path,
        default=DEFAULT_ROOT,
        help="folder searched recursively for .g2o files (default: %(default)s)",
    )
    parser.add_argument(
        "--methods",
        default=",".join(DEFAULT_METHODS),
        help=f"comma-separated, from {', '.join([*METHODS, *BASELINES])} "
        "(default: %(default)s; the baselines run on the outlier files only)",
    )
    parser.add_argument("--only", default="", help="run only files whose name contains this text")
    parser.add_argument(
        "--gate",
        type=float,
        default=None,
        help="gate probability of the maxmix front end (default: the library's)",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = parser.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    if args.gate is not None:
        METHODS["maxmix"] = {**METHODS["maxmix"], "gate_probability": args.gate}
    unknown = [m for m in methods if m not in METHODS and m not in BASELINES]
    if unknown:
        parser.error(f"unknown method(s) {unknown}; choose from {[*METHODS, *BASELINES]}")
    root = args.root.resolve()
    files = sorted(p for p in root.rglob("*.g2o") if args.only in p.name)
    gt_path = root / GROUND_TRUTH
    if not files or not gt_path.exists():
        parser.error(f"{root}: no .g2o files or no {GROUND_TRUTH}")
    truth = np.loadtxt(gt_path)
    clean = read_g2o(root / CLEAN) if (root / CLEAN).exists() else None
    # the outlier files list the clean graph's loop closures first, in its order
    n_true = sum(abs(e.a - e.b) != 1 for e in clean.edges) if clean is not None else 0
    if clean is not None:
        closures = [(e.a, e.b) for e in clean.edges if abs(e.a - e.b) != 1]
        for path in files:
            g = read_g2o(path)
            if classify(g) == "outliers" and [(m.a, m.b) for m in g.mixtures[:n_true]] != closures:
                parser.error(
                    f"{path.name}: the first {n_true} mixtures are not the clean graph's "
                    "loop closures in order; cannot score accept / reject decisions"
                )
    mm_clean_path = next(root.rglob(MM_CLEAN), None)
    true_pairs = loop_closure_pairs(read_g2o(mm_clean_path)) if mm_clean_path else None
    reference = clean_reference(root)

    rows = []
    for path in files:
        kind = classify(read_g2o(path))
        todo = ["none"] if kind == "clean" else methods
        if kind != "outliers":
            todo = [m for m in todo if m not in BASELINES and m != "dcs"]
        if kind == "multimodal" and "maxmix" in todo:
            # "auto" runs these as plain batch max-mixture: the same run as maxmix-batch
            todo = [m for m in todo if m != "maxmix-batch"]
        for method in todo:
            row = run_file(path, method, truth, reference, n_true, true_pairs)
            rows.append(row)
            print(
                f"{path.name[:60]:60s} {method:18s} ATE {row['ate_fixed_m']:.3f} m "
                f"(aligned {row['ate_aligned_m']:.3f}) "
                + (f"TP {row['tp']} FP {row['fp']} " if "tp" in row else "")
                + (f"right {100 * row['right_fraction']:.2f} % " if "right_fraction" in row else "")
                + f"{row['seconds']:.1f} s",
                file=sys.stderr,
                flush=True,
            )
    print(table(rows))
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
