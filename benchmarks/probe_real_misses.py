"""Where each labelled marking point of a real set is lost, stage by stage (issue 5).

For every label of a folder of top views with DMPR-PS labels (default the real ps2.0
samples; L directions turned to the separator, as semslam reports them), what each stage of
the shipped detector made of it:

- ``grid``: the highest confidence of the mean grid (the pair as shipped) in the 3 x 3
  cells around the label;
- ``candidate``: whether the grid offers a candidate (>= ``CANDIDATE_THRESHOLD``) within
  10 px, and how far its direction is turned from the label's (deg);
- ``verifier``: the verifier pair's probability at that candidate with its own direction,
  and at the label's own position and direction (what it would say, shown the right way);
- ``hit``: whether the shipped output (verifier, entrance check, the rows' next junctions)
  has a point within 10 px and 30 deg of it (the ps2.0 metric).

Each missed label is put down to the first stage that loses it: ``no grid response``
(grid < 0.3), ``no candidate`` (the grid's cell is there but its candidate lies farther than
10 px), ``verifier, placement`` (the verifier turns the candidate down, but shown the
label's own position and direction it would keep it: the geometric mean with the
candidate's grid confidence reaches ``DEFAULT_THRESHOLD``), ``verifier`` (it would not),
and ``after the verifier`` (kept by the verifier, lost to the checks or the metric's
30 deg). A probe of the shipped detector; nothing here is tuned on these labels.

    PYTHONPATH=. python benchmarks/probe_real_misses.py [--images DIR --labels DIR] [--json OUT]
        [--points-model A.onnx B.onnx]
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from pathlib import Path

import numpy as np
from _common import report

from semslam.evaluation.detection_metrics import PS20_DISTANCE_PX, match_points
from semslam.io.dmpr_labels import read_dmpr_labels
from semslam.io.images import read_image
from semslam.perception.marking_points import (
    CANDIDATE_THRESHOLD,
    DEFAULT_THRESHOLD,
    decode_grid,
    verified_confidence,
)
from semslam.perception.slots import SlotDetector

PS20 = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "ps2.0-samples"


def _turn_deg(a: float, b: float) -> float:
    return abs(math.degrees(math.remainder(a - b, math.tau)))


def probe_view(detector: SlotDetector, image: np.ndarray, points: np.ndarray,
               directions: np.ndarray) -> list[dict]:
    """One row per labelled point (``points`` (N, 2) px, ``directions`` (N,) rad) of a
    600 x 600 top view: the stages above."""
    marking = detector.points
    grid, side, _ = marking.grid(image)
    cells = grid.shape[1]
    candidates = decode_grid(grid, side, CANDIDATE_THRESHOLD)
    final, _ = detector.detect(image)
    # which labels the shipped output hits, as bench_perception.py scores them (one-to-one)
    match = match_points(np.array([p.uv for p in final]).reshape(-1, 2),
                         np.array([p.direction for p in final]),
                         np.array([p.confidence for p in final]), points, directions)
    hit = set(match[match >= 0].tolist())
    at_label = marking.verifier.verify(image, points, directions)[0] if len(points) else []
    rows = []
    for k, ((u, v), d) in enumerate(zip(points, directions, strict=True)):
        cu, cv = int(u * cells / side), int(v * cells / side)
        window = grid[0, max(cv - 1, 0): cv + 2, max(cu - 1, 0): cu + 2]
        near = [c for c in candidates
                if math.hypot(c.uv[0] - u, c.uv[1] - v) <= PS20_DISTANCE_PX]
        best = max(near, key=lambda c: c.confidence) if near else None
        row = {
            "label": [round(float(u)), round(float(v))],
            "direction_deg": round(math.degrees(d)),
            "grid": round(float(window.max()), 2) if window.size else 0.0,
            "candidate_turn_deg": None if best is None else round(_turn_deg(best.direction, d)),
            "verifier_at_candidate": None,
            "verifier_at_label": round(float(at_label[k]), 2),
            "hit": k in hit,
        }
        if best is not None:
            prob = marking.verifier.verify(image, best.uv[None], np.array([best.direction]))[0]
            row["verifier_at_candidate"] = round(float(prob[0]), 2)
            row["verified_confidence"] = round(
                float(verified_confidence(best.confidence, prob[0])), 2)
        row["lost_at"] = _lost_at(row, best)
        rows.append(row)
    return rows


def _lost_at(row: dict, best) -> str | None:
    """The first stage that loses a missed label (see the module); None for a hit."""
    if row["hit"]:
        return None
    if row["grid"] < CANDIDATE_THRESHOLD:
        return "no grid response"
    if best is None:
        return "no candidate"
    if row["verified_confidence"] < DEFAULT_THRESHOLD:
        shown_right = float(verified_confidence(best.confidence, row["verifier_at_label"]))
        return "verifier, placement" if shown_right >= DEFAULT_THRESHOLD else "verifier"
    return "after the verifier"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=Path, default=PS20 / "images",
                        help="600 x 600 top views (*.jpg), as ps2.0's")
    parser.add_argument("--labels", type=Path, default=PS20 / "labels")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--points-model", type=Path, nargs="+", default=None,
                        help="grid ONNX files to probe instead of the shipped pair")
    args = parser.parse_args()
    detector = SlotDetector(args.points_model)
    views = {}
    for label_path in sorted(args.labels.glob("*.json")):
        image_path = args.images / f"{label_path.stem}.jpg"
        if not image_path.is_file():
            continue
        labels = read_dmpr_labels(label_path).with_separator_directions()
        views[label_path.stem] = probe_view(detector, read_image(image_path),
                                            np.asarray(labels.points, float).reshape(-1, 2),
                                            np.asarray(labels.directions, float).reshape(-1))
    rows = [(name, r) for name, view in views.items() for r in view]
    lost = Counter(r["lost_at"] for _, r in rows if r["lost_at"])
    md = [f"{sum(r['hit'] for _, r in rows)} of {len(rows)} labels hit in {len(views)} views.",
          "", "| stage that loses it | labels |", "| --- | --- |",
          *(f"| {stage} | {n} |" for stage, n in lost.most_common()), "",
          "| view | label (px) | dir (deg) | grid | candidate turned (deg) | verifier at "
          "candidate | verifier at label | lost at |", "| --- " * 8 + "|"]
    md += [f"| {name} | {tuple(r['label'])} | {r['direction_deg']} | {r['grid']:.2f} | "
           f"{'-' if r['candidate_turn_deg'] is None else r['candidate_turn_deg']} | "
           f"{'-' if r['verifier_at_candidate'] is None else r['verifier_at_candidate']} | "
           f"{r['verifier_at_label']:.2f} | {r['lost_at']} |"
           for name, r in rows if r["lost_at"]]
    report("\n".join(md), {"views": views, "lost_at": dict(lost)}, args.json)


if __name__ == "__main__":
    main()
