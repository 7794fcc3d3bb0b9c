"""`semslam detect` and `semslam evaluate detections`: the top-view detectors on image files.

``detect_files`` runs :class:`~semslam.perception.topview_perception.TopviewPerception` on
each top view and returns the JSON document the command prints::

    {"images": [{"image": PATH, "width": W, "height": H, "points": [...], "slots": [...],
                 "markings": [...], "timings_ms": {...}}]}

An image of any size is read as a top view whose longer side spans ps2.0's 10 m, or at the
ground resolution given (``px_per_m``), and brought into the detectors' frame for them
(:mod:`semslam.perception.view_frame`); every pixel in the result is the image's own.

Per marking point: ``u``, ``v`` (px, OpenCV pixel centres), ``direction_deg`` (image
coordinates, atan2(dv, du), along the separator into the slot), ``shape`` (T or L),
``confidence``, ``from_row`` (true: placed from its row's neighbours where no junction is
seen, :mod:`semslam.perception.row_completion`). Per slot: ``points`` (0-based indices
of its entrance points), ``corners_px`` and ``corners_vehicle`` (m; entrance-left,
entrance-right, rear-right, rear-left), ``kind``, ``angle_deg``, ``confidence``,
``label``, ``label_confidence``.
Per painted line: end points ``a``, ``b`` in the vehicle frame (m), ``confidence``.
Optionally an overlay picture per image (``<stem>.png`` in the overlay folder).

``evaluate_detection_folder`` scores the detectors on a folder of top views against
labels in the DMPR-PS form (``labels/<stem>.json``) with the ps2.0 metric.
"""

from __future__ import annotations

import math
import os
import statistics
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from semslam.errors import FormatError, PerceptionError, SemslamError
from semslam.evaluation.detection_metrics import DetectionCounts, score_image
from semslam.io.atomic import atomic_write_bytes
from semslam.io.images import IMAGE_SUFFIXES, image_files, read_image
from semslam.perception.topview_perception import TopviewDetections, TopviewPerception
from semslam.perception.view_frame import ViewFrame, into_detector_frame, view_frame


def _r(values: Any, digits: int = 3) -> Any:
    return np.round(np.asarray(values, dtype=float), digits).tolist()


def _identity(shape: tuple[int, ...]) -> ViewFrame:
    return ViewFrame((int(shape[0]), int(shape[1])), (1.0, 1.0), (0, 0))


def within_image(det: TopviewDetections, frame: ViewFrame) -> TopviewDetections:
    """``det`` (detectors' frame) without the marking points that lie in the padding around
    the image, and without the slots they make (the others' point indices renumbered)."""
    height, width = frame.image_shape
    uv = frame.to_image(np.array([p.uv for p in det.points], float))
    keep = (uv[:, 0] >= -0.5) & (uv[:, 0] <= width - 0.5) & (uv[:, 1] >= -0.5) \
        & (uv[:, 1] <= height - 0.5)
    if keep.all():
        return det
    index = {int(old): new for new, old in enumerate(np.flatnonzero(keep))}
    pairs = [(replace(s, i=index[s.i], j=index[s.j]), r)
             for s, r in zip(det.slots, det.ids, strict=True) if s.i in index and s.j in index]
    return replace(det, points=tuple(p for p, k in zip(det.points, keep, strict=True) if k),
                   slots=tuple(s for s, _ in pairs), ids=tuple(r for _, r in pairs))


def detections_json(
    perception: TopviewPerception, det: TopviewDetections, frame: ViewFrame | None = None
) -> dict[str, Any]:
    """Points, slots with IDs and lines of one image, JSON-ready; ``det`` in the detectors'
    frame, pixels reported in the image's (``frame``; None: the same)."""
    observations = perception.slot_observations(det)
    frame = frame or _identity((perception.spec.size_px,) * 2)
    uv = frame.to_image(np.array([p.uv for p in det.points], float))
    return {
        "points": [
            {
                "u": round(float(u), 2),
                "v": round(float(v), 2),
                "direction_deg": round(math.degrees(frame.direction_to_image(p.direction)), 2),
                "shape": str(p.shape),
                "confidence": round(float(p.confidence), 4),
                "from_row": bool(p.from_row),
            }
            for p, (u, v) in zip(det.points, uv, strict=True)
        ],
        "slots": [
            {
                "points": [int(s.i), int(s.j)],
                "corners_px": _r(frame.to_image(s.uv_corners), 2),
                "corners_vehicle": _r(o.vCorners, 4),
                "kind": str(s.kind),
                "angle_deg": round(float(s.angle_deg), 2),
                "confidence": round(float(s.confidence), 4),
                "label": r.label,
                "label_confidence": round(float(r.confidence), 4),
            }
            for s, r, o in zip(det.slots, det.ids, observations, strict=True)
        ],
        "markings": [
            {"a": _r(m.vA, 4), "b": _r(m.vB, 4), "confidence": round(float(m.confidence), 4)}
            for m in det.markings
        ],
        "timings_ms": {k: round(v, 3) for k, v in det.timings_ms.items()},
    }


def draw_overlay(
    image: np.ndarray, perception: TopviewPerception, det: TopviewDetections,
    frame: ViewFrame | None = None,
) -> np.ndarray:
    """The image with lines (blue), slots (green, with their IDs) and marking points
    (red T, orange L, with direction; magenta where placed from its row, not seen) drawn
    on it; ``det`` in the detectors' frame, placed on the image by ``frame`` (None: the
    image is in that frame)."""
    out = image.copy()
    spec = perception.spec
    frame = frame or _identity(image.shape)
    for m in det.markings:
        a, b = frame.to_image(spec.vehicle_to_pixel(np.array([m.vA, m.vB])))
        cv2.line(
            out,
            tuple(int(round(x)) for x in a),
            tuple(int(round(x)) for x in b),
            (255, 128, 0),
            2,
            cv2.LINE_AA,
        )
    for s, r in zip(det.slots, det.ids, strict=True):
        corners = frame.to_image(s.uv_corners)
        poly = np.round(corners).astype(np.int32)
        cv2.polylines(out, [poly], True, (0, 220, 0), 2, cv2.LINE_AA)
        if r.label:
            centre = corners.mean(axis=0)
            text = f"{r.label} {r.confidence:.2f}"
            org = (int(centre[0]) - 30, int(centre[1]))
            cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 0), 1, cv2.LINE_AA)
    for p in det.points:
        u, v = frame.to_image(p.uv)[0]
        direction = float(frame.direction_to_image(p.direction))
        colour = (0, 0, 255) if str(p.shape) == "T" else (0, 140, 255)
        if p.from_row:
            colour = (255, 0, 255)
        tip = (
            int(round(u + 25 * math.cos(direction))),
            int(round(v + 25 * math.sin(direction))),
        )
        cv2.circle(out, (int(round(u)), int(round(v))), 5, colour, 2, cv2.LINE_AA)
        cv2.line(out, (int(round(u)), int(round(v))), tip, colour, 2, cv2.LINE_AA)
    return out


def _encode_png(path: Path, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - OpenCV cannot fail on a BGR uint8 array
        raise FormatError(f"{path}: could not encode the overlay")
    return buf.tobytes()


def _refuse_overlays_among_images(
    images: Sequence[str | os.PathLike[str]], overlay_dir: str | os.PathLike[str]
) -> None:
    """Raise FormatError if the overlay folder holds one of the images: an overlay would
    replace an input picture, or be read as one the next time the folder is given."""
    folder = Path(overlay_dir)
    if not folder.is_dir():
        return
    for path in images:
        if os.path.samefile(Path(path).parent, folder):
            raise FormatError(f"{overlay_dir}: the overlay folder holds the input image "
                              f"{path}; give --overlay another folder")


def detect_files(
    images: Sequence[str | os.PathLike[str]],
    overlay_dir: str | os.PathLike[str] | None = None,
    lines: bool = True,
    perception: TopviewPerception | None = None,
    px_per_m: float | None = None,
) -> dict[str, Any]:
    """Run the top-view detectors on every image (a folder: its image files, by name); the
    JSON-ready result (module doc). ``px_per_m``: the images' ground resolution (None: each
    one's longer side spans the detectors' 10 m).

    Raises:
        FormatError: an image is missing or unreadable, a folder holds no image, two
            images would write the same overlay (the same file name in two folders), or the
            overlay folder holds an input image.
        PerceptionError: a model is missing or broken, an image has the wrong type, or it
            covers more ground than the detectors' view.
    """
    images = [file for given in images for file in image_files(given)]
    if overlay_dir is not None:
        _refuse_overlays_among_images(images, overlay_dir)
        stems: dict[str, str] = {}
        for path in images:
            first = stems.setdefault(Path(path).stem, os.fspath(path))
            if first != os.fspath(path):
                raise FormatError(f"{path}: its overlay would replace that of {first} "
                                  f"({Path(path).stem}.png); give each image its own name")
    perception = perception or TopviewPerception(lines=lines)
    out = []
    overlays = []  # written only once every image is read and detected: a bad one writes none
    for path in images:
        image = read_image(path)
        try:
            frame = view_frame(image.shape, px_per_m, perception.spec)
            det = perception.detect(into_detector_frame(image, frame, perception.spec))
            det = within_image(det, frame)
        except SemslamError as e:  # name the image: the detectors do not know it
            message = str(e)
            raise PerceptionError(
                message if message.startswith(os.fspath(path)) else f"{path}: {message}"
            ) from None
        out.append(
            {
                "image": os.fspath(path),
                "width": int(image.shape[1]),
                "height": int(image.shape[0]),
                **detections_json(perception, det, frame),
            }
        )
        if overlay_dir is not None:
            target = Path(overlay_dir) / f"{Path(path).stem}.png"
            picture = draw_overlay(image, perception, det, frame)
            overlays.append((target, _encode_png(target, picture)))
    for target, data in overlays:
        atomic_write_bytes(target, data)
    return {"images": out}


def evaluate_detection_folder(
    images_dir: str | os.PathLike[str],
    labels_dir: str | os.PathLike[str],
    perception: TopviewPerception | None = None,
    progress: Callable[[int, int], None] | None = None,
    separator_convention: bool = True,
    px_per_m: float | None = None,
) -> dict[str, Any]:
    """Score the detectors on every image of ``images_dir`` that has a label file
    ``labels_dir/<stem>.json`` (DMPR-PS form) with the ps2.0 metric, in the detectors' frame
    (10 px there are ps2.0's 10 px: 1/6 m), whatever the images' size (``px_per_m`` as in
    :func:`detect_files`).

    With ``separator_convention`` the labels' L junctions that ps2.0 directs along the
    entrance are directed along their separator first, as semslam reports every point
    (:meth:`~semslam.io.dmpr_labels.TopviewLabels.with_separator_directions`); without
    it, the directions are scored as the files give them.

    Returns:
        ``point_precision``, ``point_recall``, ``slot_precision``, ``slot_recall``,
        ``shape_accuracy``, the pooled counts (``images`` among them), the median
        milliseconds per stage, the images without labels, ``labels_redirected``
        (labelled points whose direction the convention changed), ``per_image``: each
        image's labels, hits and false detections, points and slots (which views fail), and
        ``images_with_point_errors``: how many of them miss a point or find a false one.

    Raises:
        FormatError: a folder is missing, holds no labelled image, or a file is broken.
    """
    from semslam.io.dmpr_labels import read_dmpr_labels

    images_dir, labels_dir = Path(images_dir), Path(labels_dir)
    for folder in (images_dir, labels_dir):
        if not folder.is_dir():
            raise FormatError(f"{folder}: no such folder")
    images = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    labelled = [p for p in images if (labels_dir / f"{p.stem}.json").is_file()]
    if not labelled:
        raise FormatError(f"{images_dir}: no image with a label file in {labels_dir}")
    perception = perception or TopviewPerception(lines=False)
    total = DetectionCounts()
    per_image: list[dict[str, Any]] = []
    timings: dict[str, list[float]] = {}
    redirected = 0
    for k, path in enumerate(labelled):
        raw = read_dmpr_labels(labels_dir / f"{path.stem}.json")
        labels = raw.with_separator_directions() if separator_convention else raw
        redirected += int(np.count_nonzero(labels.directions != raw.directions))
        image = read_image(path)
        try:
            frame = view_frame(image.shape, px_per_m, perception.spec)
        except SemslamError as e:
            raise PerceptionError(f"{path}: {e}") from None
        det = within_image(perception.detect(into_detector_frame(image, frame, perception.spec)),
                           frame)
        points = np.array([p.uv for p in det.points], float).reshape(-1, 2)
        counts = score_image(
            points,
            np.array([p.direction for p in det.points], float),
            np.array([0 if str(p.shape) == "T" else 1 for p in det.points], int),
            np.array([p.confidence for p in det.points], float),
            np.array([[s.i, s.j] for s in det.slots], int).reshape(-1, 2),
            frame.to_detector(labels.points),
            frame.direction_to_detector(labels.directions),
            labels.shapes,
            labels.slots,
        )
        total += counts
        per_image.append({
            "image": path.name,
            "point_labels": counts.point_labels,
            "point_hits": counts.point_true_positives,
            "false_points": counts.point_detections - counts.point_true_positives,
            "slot_labels": counts.slot_labels,
            "slot_hits": counts.slot_true_positives,
            "false_slots": counts.slot_detections - counts.slot_true_positives,
        })
        for stage, ms in det.timings_ms.items():
            timings.setdefault(stage, []).append(ms)
        if progress is not None:
            progress(k + 1, len(labelled))
    return {
        "images_dir": os.fspath(images_dir),
        "labels_dir": os.fspath(labels_dir),
        **total.summary(),
        "median_ms": {k: round(statistics.median(v), 3) for k, v in timings.items()},
        "unlabelled_images": len(images) - len(labelled),
        "labels_redirected": redirected,
        "images_with_point_errors": sum(
            e["point_hits"] < e["point_labels"] or e["false_points"] > 0 for e in per_image
        ),
        "per_image": per_image,
    }


__all__ = [
    "detect_files",
    "detections_json",
    "draw_overlay",
    "evaluate_detection_folder",
    "within_image",
]
