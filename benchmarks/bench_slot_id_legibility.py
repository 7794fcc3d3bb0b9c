"""How legible are the "readable" slot IDs? The ID reader against a reading by eye.

The slot-ID test set (``tools/train_slot_ids.py``, test worlds 0-99) calls an ID readable
when its text box is inside the top view and uncovered; blur and the stitched fisheye's
radial smear are not considered. A seeded sample of 160 of those crops was read by eye,
blind to the truth and to the reader, into ``benchmarks/annotations/slot_id_legibility.csv``
(empty reading: could not read it). This script regenerates the crops (cached), checks that
each annotated crop is the same one (world, render seed, slot), and scores the reader
against the eye: how often each is right, and the reader's accuracy on the IDs the eye
read right (the "readable" a person means). A second table splits both by how sharp the
simulated camera is where the ID is painted: camera samples across the text's height
(``meta`` column 6 of the crops).

    PYTHONPATH=. python benchmarks/bench_slot_id_legibility.py [--json out.json]
    PYTHONPATH=. python benchmarks/bench_slot_id_legibility.py --montage DIR  # pictures to annotate
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import cv2
import numpy as np
from _common import report

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from train_slot_ids import READABLE, generate  # noqa: E402

from semslam.perception.slot_ids import SlotIdReader  # noqa: E402

ANNOTATIONS = Path(__file__).resolve().parent / "annotations" / "slot_id_legibility.csv"
SAMPLE_SEED, SAMPLE_SIZE, PER_PICTURE = 2026, 160, 40


def sample_indices(status: np.ndarray) -> np.ndarray:
    """The annotated sample: ``SAMPLE_SIZE`` readable crops drawn with ``SAMPLE_SEED``."""
    readable = np.nonzero(status == READABLE)[0]
    return np.random.default_rng(SAMPLE_SEED).choice(readable, SAMPLE_SIZE, replace=False)


def write_montages(data: dict, out: Path) -> None:
    """The sample as numbered 2x enlarged crops, 40 per picture, no labels."""
    out.mkdir(parents=True, exist_ok=True)
    idx = sample_indices(data["status"])
    for m in range(0, len(idx), PER_PICTURE):
        tiles = []
        for rank in range(m, min(m + PER_PICTURE, len(idx))):
            p = data["patches"][idx[rank]].reshape(data["patches"].shape[-2:]).astype(np.uint8)
            p = cv2.cvtColor(cv2.resize(p, (2 * p.shape[1], 2 * p.shape[0]),
                                        interpolation=cv2.INTER_CUBIC), cv2.COLOR_GRAY2BGR)
            cv2.putText(p, str(rank), (3, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 255, 255), 1)
            tiles.append(p)
        while len(tiles) % 5:
            tiles.append(np.zeros_like(tiles[0]))
        rows = [np.hstack(tiles[k:k + 5]) for k in range(0, len(tiles), 5)]
        cv2.imwrite(str(out / f"legibility_{m // PER_PICTURE}.png"), np.vstack(rows))


def read_annotations(data: dict) -> list[tuple[int, str | None]]:
    """(crop index, reading or None) per annotated crop, checked against the crops."""
    idx = sample_indices(data["status"])
    lines = [ln for ln in ANNOTATIONS.read_text().splitlines() if not ln.startswith("#")]
    out = []
    for row in csv.DictReader(lines):
        rank, crop = int(row["rank"]), int(row["crop"])
        meta = data["meta"][crop]
        same = (idx[rank] == crop and int(meta[0]) == int(row["world_seed"])
                and int(meta[1]) == int(row["render_seed"]) and int(meta[2]) == int(row["slot_id"]))
        if not same:
            raise SystemExit(f"{ANNOTATIONS}: rank {rank}: crop {crop} is not the crop the test "
                             "set now has there (the renderer or the sampling changed)")
        out.append((crop, row["reading"] or None))
    return out


def score(data: dict, annotations: list[tuple[int, str | None]], model: Path | None) -> dict:
    crops = [c for c, _ in annotations]
    truth = data["labels"][crops]
    eye = np.array([r for _, r in annotations], dtype=object)
    reads = SlotIdReader(model, min_confidence=0.0).read_patches(list(data["patches"][crops]))
    label = np.array([r.label for r in reads], dtype=object)
    conf = np.array([r.confidence for r in reads])
    eye_right = eye == truth
    eye_tried = np.array([e is not None for e in eye])
    reader_right = label == truth

    def share(mask: np.ndarray, within: np.ndarray | None = None) -> dict:
        w = np.ones(len(mask), bool) if within is None else within
        return {"right": int((mask & w).sum()), "of": int(w.sum()),
                "share": round(float((mask & w).sum() / max(1, w.sum())), 3)}

    return {
        "crops": len(crops),
        "eye_right": share(eye_right),
        "eye_right_when_it_read": share(eye_right, eye_tried),
        "reader_right": share(reader_right),
        "reader_right_on_ids_the_eye_read_right": share(reader_right, eye_right),
        "reader_right_on_ids_the_eye_could_not_read": share(reader_right, ~eye_tried),
        "reader_confidence_ge_0.9": share(reader_right, conf >= 0.9),
        "reader_given_ge_0.9_on_ids_the_eye_read_right": share(conf >= 0.9, eye_right),
        "reader_misses_on_ids_the_eye_read_right": [
            {"truth": str(t), "reader": lab, "confidence": round(float(c), 2)}
            for t, lab, c, e, r in zip(truth, label, conf, eye_right, reader_right, strict=True)
            if e and not r],
    }


SAMPLE_BINS = (0.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 15.0, np.inf)


def by_resolution(data: dict, annotations: list[tuple[int, str | None]],
                  model: Path | None) -> list[dict]:
    """The eye (on its sample) and the reader (on every readable test crop) by how many
    camera samples span the text's height where it is painted (the simulator's fisheye
    resolution there: ``TopviewRenderer.source_spacing_m``), one row per bin."""
    samples = data["meta"][:, 6]
    readable = np.nonzero(data["status"] == READABLE)[0]
    reads = SlotIdReader(model, min_confidence=0.0).read_patches(list(data["patches"][readable]))
    reader_right = np.array([r.label for r in reads], dtype=object) == data["labels"][readable]
    crops = np.array([c for c, _ in annotations])
    eye_right = np.array([r for _, r in annotations], dtype=object) == data["labels"][crops]
    rows = []
    for lo, hi in zip(SAMPLE_BINS[:-1], SAMPLE_BINS[1:], strict=True):
        e = (samples[crops] >= lo) & (samples[crops] < hi)
        r = (samples[readable] >= lo) & (samples[readable] < hi)
        rows.append({"samples": [lo, hi if np.isfinite(hi) else None],
                     "eye": [int(eye_right[e].sum()), int(e.sum())],
                     "reader": [int(reader_right[r].sum()), int(r.sum())]})
    return rows


def markdown_by_resolution(rows: list[dict]) -> str:
    out = ["| camera samples across the text height | the eye: right / of | the reader: "
           "right / of | share |", "| --- | --- | --- | --- |"]
    for row in rows:
        lo, hi = row["samples"]
        (er, en), (rr, rn) = row["eye"], row["reader"]
        span = f"{lo:g}-{hi:g}" if hi is not None else f">= {lo:g}"
        out.append(f"| {span} | {er} / {en} | {rr} / {rn} | {rr / max(rn, 1):.3f} |")
    return "\n".join(out)


def markdown(s: dict) -> str:
    rows = [("the eye, all readable crops", s["eye_right"]),
            ("the eye, crops it read", s["eye_right_when_it_read"]),
            ("the reader, all readable crops (top label)", s["reader_right"]),
            ("the reader, IDs the eye read right", s["reader_right_on_ids_the_eye_read_right"]),
            ("the reader, IDs the eye could not read",
             s["reader_right_on_ids_the_eye_could_not_read"]),
            ("the reader, labels it gave confidence >= 0.9", s["reader_confidence_ge_0.9"])]
    out = ["| who, on which crops | right | of | share |", "| --- | --- | --- | --- |"]
    out += [f"| {name} | {v['right']} | {v['of']} | {v['share']:.3f} |" for name, v in rows]
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=Path("/tmp/slot_ids_cache"))
    parser.add_argument("--model", type=Path, default=None, help="ONNX reader (default: shipped)")
    parser.add_argument("--montage", type=Path, default=None,
                        help="write the sample's pictures for annotating into this folder and stop")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    data = generate("test", args.cache)
    if args.montage is not None:
        write_montages(data, args.montage)
        return
    annotations = read_annotations(data)
    result = score(data, annotations, args.model)
    result["by_resolution"] = by_resolution(data, annotations, args.model)
    report(markdown(result) + "\n\n" + markdown_by_resolution(result["by_resolution"]),
           result, args.json)


if __name__ == "__main__":
    main()
