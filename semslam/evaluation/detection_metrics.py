"""The ps2.0 marking-point and slot metric (DMPR-PS), on pixel coordinates.

A detected marking point is a hit when it lies within ``distance_px`` (10 px of a 600 px
top view) of a labelled point and its direction is within ``angle_deg`` (30 deg) of that
point's; each labelled point is matched at most once, detections taken in order of
confidence. A detected slot is a hit when both of its entrance points hit the two
entrance points of one labelled slot (in either order: the pair names the slot, the
directions its side), again one to one. Precision and recall are pooled over images.
Pure numpy: the pipeline reads the files and runs the detectors.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from semslam.geometry import FloatArray

PS20_DISTANCE_PX = 10.0
PS20_ANGLE_DEG = 30.0


@dataclass
class DetectionCounts:
    """Pooled counts of the ps2.0 metric; add them over images with ``+=``."""

    point_true_positives: int = 0
    point_detections: int = 0
    point_labels: int = 0
    shape_correct: int = 0
    slot_true_positives: int = 0
    slot_detections: int = 0
    slot_labels: int = 0
    images: int = 0

    def __iadd__(self, other: DetectionCounts) -> DetectionCounts:
        for key, value in asdict(other).items():
            setattr(self, key, getattr(self, key) + value)
        return self

    def summary(self) -> dict[str, float | int]:
        """Precision and recall (1.0 when there is nothing to find or nothing found),
        shape accuracy over matched points, and the counts."""

        def ratio(a: int, b: int) -> float:
            return a / b if b else 1.0

        return {
            "point_precision": ratio(self.point_true_positives, self.point_detections),
            "point_recall": ratio(self.point_true_positives, self.point_labels),
            "slot_precision": ratio(self.slot_true_positives, self.slot_detections),
            "slot_recall": ratio(self.slot_true_positives, self.slot_labels),
            "shape_accuracy": ratio(self.shape_correct, self.point_true_positives),
            **asdict(self),
        }


def _angle_diff(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.abs((a - b + np.pi) % (2 * np.pi) - np.pi)


def match_points(
    detected: FloatArray,
    detected_directions: FloatArray,
    confidences: FloatArray,
    labelled: FloatArray,
    labelled_directions: FloatArray,
    distance_px: float = PS20_DISTANCE_PX,
    angle_deg: float = PS20_ANGLE_DEG,
) -> np.ndarray:
    """For each detected point (N, 2) the index of the labelled point (M, 2) it hits, or
    -1: greedy one-to-one in order of decreasing confidence, nearest eligible label first.
    Directions in radians (image coordinates)."""
    detected = np.asarray(detected, float).reshape(-1, 2)
    labelled = np.asarray(labelled, float).reshape(-1, 2)
    match = np.full(len(detected), -1, int)
    if not len(detected) or not len(labelled):
        return match
    d = np.linalg.norm(detected[:, None, :] - labelled[None, :, :], axis=2)
    da = _angle_diff(
        np.asarray(detected_directions, float)[:, None],
        np.asarray(labelled_directions, float)[None],
    )
    eligible = (d <= distance_px) & (da <= np.radians(angle_deg))
    taken = np.zeros(len(labelled), bool)
    for i in np.argsort(-np.asarray(confidences, float), kind="stable"):
        candidates = np.nonzero(eligible[i] & ~taken)[0]
        if len(candidates):
            j = candidates[np.argmin(d[i, candidates])]
            match[i] = j
            taken[j] = True
    return match


def score_image(
    detected_points: FloatArray,
    detected_directions: FloatArray,
    detected_shapes: np.ndarray,
    confidences: FloatArray,
    detected_slots: np.ndarray,
    labelled_points: FloatArray,
    labelled_directions: FloatArray,
    labelled_shapes: np.ndarray,
    labelled_slots: np.ndarray,
    distance_px: float = PS20_DISTANCE_PX,
    angle_deg: float = PS20_ANGLE_DEG,
) -> DetectionCounts:
    """The ps2.0 counts of one image.

    Args:
        detected_points, labelled_points: (N, 2) / (M, 2) pixels.
        detected_directions, labelled_directions: radians, image coordinates.
        detected_shapes, labelled_shapes: 0 = T, 1 = L.
        confidences: (N,) detection confidences (the matching order).
        detected_slots, labelled_slots: (K, >=2) rows whose first two entries are the
            0-based (detected) / 1-based (labelled, DMPR-PS form) indices of the
            entrance points.
    """
    match = match_points(
        detected_points,
        detected_directions,
        confidences,
        labelled_points,
        labelled_directions,
        distance_px,
        angle_deg,
    )
    hit = match >= 0
    shapes_ok = (
        np.asarray(detected_shapes, int)[hit] == np.asarray(labelled_shapes, int)[match[hit]]
    )
    # slots: a detected slot hits when its entrance points matched a labelled slot's pair
    truth = {
        frozenset((int(i) - 1, int(j) - 1))
        for i, j in np.asarray(labelled_slots, int).reshape(-1, 4)[:, :2]
    }
    remaining = set(truth)
    slot_hits = 0
    rows = np.asarray(detected_slots, int)
    rows = rows.reshape(-1, rows.shape[-1]) if rows.size else np.zeros((0, 2), int)
    for row in rows:
        i, j = int(row[0]), int(row[1])
        pair = frozenset((int(match[i]), int(match[j])))
        if match[i] >= 0 and match[j] >= 0 and pair in remaining:
            remaining.discard(pair)
            slot_hits += 1
    return DetectionCounts(
        point_true_positives=int(hit.sum()),
        point_detections=len(match),
        point_labels=len(np.asarray(labelled_points).reshape(-1, 2)),
        shape_correct=int(shapes_ok.sum()),
        slot_true_positives=slot_hits,
        slot_detections=len(rows),
        slot_labels=len(truth),
        images=1,
    )


__all__ = [
    "PS20_ANGLE_DEG",
    "PS20_DISTANCE_PX",
    "DetectionCounts",
    "match_points",
    "score_image",
]
