"""Are the slot-ID reader's confidences honest on a whole drive? Reliability of its readings.

Runs the top-view perception on every ``--step``-th frame of a simulated drive with images,
matches each detected slot to the exact observation of the same slot in that frame (mean
corner distance < 1 m) and scores every decoded label against the true one, binned by
confidence. Two confidences side by side: the reader's (the label's CTC probability) and
the product of the emitted characters' probabilities that it replaced.

    PYTHONPATH=. python benchmarks/bench_slot_id_readings.py DRIVE_WITH_IMAGES [--step 3]
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
from _common import true_slot

from semslam.io import Drive
from semslam.io.images import read_image
from semslam.perception.slot_ids import SlotIdReader
from semslam.perception.topview_perception import TopviewPerception

BINS = (0.0, 0.3, 0.5, 0.7, 0.9, 0.97, 1.0001)


def readings(drive: Drive, step: int) -> list[tuple[str, str, float, float]]:
    """(true label, read label, label probability, characters' product) per decoded label."""
    perception = TopviewPerception(
        spec=drive.rig.topview, id_reader=SlotIdReader(min_confidence=0.0), lines=False
    )
    frames, exact = drive.frames(), drive.observations("exact")
    out = []
    for i in range(0, len(frames.t), step):
        found = perception.detect(read_image(drive.image_path("topview", i)))
        for slot, reading in zip(perception.slot_observations(found), found.ids, strict=True):
            if reading.label is None:
                continue
            truth = true_slot(slot, exact[i].slots)
            if truth is not None and truth.label:
                product = math.prod(reading.char_confidences)
                out.append((truth.label, reading.label, reading.confidence, product))
    return out


def reliability(right: np.ndarray, confidence: np.ndarray) -> dict:
    table = []
    for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
        sel = (confidence >= lo) & (confidence < hi)
        table.append({
            "bin": f"[{lo:.2f}, {min(hi, 1.0):.2f})",
            "n": int(sel.sum()),
            "mean_confidence": round(float(confidence[sel].mean()), 3) if sel.any() else None,
            "right": round(float(right[sel].mean()), 3) if sel.any() else None,
        })
    confident = confidence >= 0.9
    return {
        "readings_ge_0.9": int(confident.sum()),
        "right_ge_0.9": round(float(right[confident].mean()), 4) if confident.any() else None,
        "bins": table,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive")
    parser.add_argument("--step", type=int, default=3, help="every n-th frame")
    args = parser.parse_args()
    rows = readings(Drive.open(args.drive), max(1, args.step))
    right = np.array([t == r for t, r, _, _ in rows])
    out = {
        "drive": args.drive,
        "labels_decoded": len(rows),
        "right": round(float(right.mean()), 4) if rows else None,
        "label_probability": reliability(right, np.array([r[2] for r in rows])),
        "characters_product": reliability(right, np.array([r[3] for r in rows])),
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
