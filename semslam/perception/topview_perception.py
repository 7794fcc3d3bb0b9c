"""Everything semslam reads from one top view: marking points, slots, slot IDs, lines.

:class:`TopviewPerception` runs the marking-point CNN and slot inference
(:mod:`semslam.perception.slots`), reads each slot's painted ID with the ID CNN
(:mod:`semslam.perception.slot_ids`) and finds painted lines with Houben's detector
(:mod:`semslam.perception.markings`), and turns the result into vehicle-frame
observations for the mapper and the localizer. Library only: no file I/O.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from semslam.errors import PerceptionError
from semslam.perception.markings import MarkingDetector
from semslam.perception.slot_ids import SlotIdReader, SlotIdReading, crop_id_patch
from semslam.perception.slots import DetectedSlot, SlotDetector, slot_observation
from semslam.rig import TopviewSpec
from semslam.types import MarkingObservation, SlotObservation

DEFAULT_CORNER_SIGMA = 0.30
"""m: 1-sigma declared for a detected slot corner, for a map or a filter that treats the
frames as independent. One frame's corners are better than this (0.027 m RMS per axis at
the entrance, 0.054 m at the rear), but part of the error is the same in every frame that
sees a slot (0.016 / 0.033 m RMS per slot), so averaging ~50 frames does not shrink it as
independent noise would: 0.033 m x sqrt(50) is about 0.25 m. Chosen with the painted lines'
sigma on two worlds (`bench_image_map_sources.py --grid`, the demo's mapping drives of
garage seeds 1 and 2): map corner RMSE with lines at 0.15 m, corners at 0.10 / 0.15 / 0.20 /
0.30 / 0.45 m: 0.083 / 0.068 / 0.061 / 0.055 / 0.054 m (seed 1) and 0.109 / 0.083 / 0.065 /
0.048 / 0.043 m (seed 2). The demo end to end, 0.15 -> 0.30 m: map 0.068 -> 0.055 m and
0.083 -> 0.048 m, localizer ATE 0.073 -> 0.058 m and 0.090 -> 0.059 m, its NEES 2.2 -> 1.3
and 5.4 -> 1.9 (conservative now). BENCHMARKS.md, `bench_slot_corner_errors.py`."""

CORNER_SIGMA_OWN = (0.017, 0.017, 0.033, 0.033)
"""m per axis, per corner (entrance-left, entrance-right, rear-right, rear-left): the part of
a detected corner's error that is each frame's own. With :data:`CORNER_SIGMA_SHARED`, the
error model the mapper exports its corner covariances from (``SlotObservation``); the
weight stays :data:`DEFAULT_CORNER_SIGMA`. Measured by ``bench_slot_corner_errors.py`` on
the demo's mapping drive (garage seed 1, drive 0; 8,723 detections of 184 slots): entrance
0.0167, rear 0.0327 m. The rear is placed from the entrance by the slot's depth, so it is
off by more."""

CORNER_SIGMA_SHARED = (0.008, 0.008, 0.019, 0.019)
"""m per axis, per corner: the part of a detected corner's error that every frame seeing
the slot shares (the same measurement: entrance 0.0078, rear 0.0186 m)."""

DEFAULT_LINE_SIGMA = 0.15
"""m: 1-sigma declared for a detected painted line's end points across the line. The same
reason as the corners: a line is detected a little off in the same way in every frame that
sees it, and the simulator's independent 0.05 m (``mapping.marking_sigma``) let the image
lines pull the map off on seed 1 (corners at 0.30 m; lines at 0.05 / 0.10 / 0.15 / 0.20 m:
0.089 / 0.059 / 0.055 / 0.056 m; seed 2: 0.080 / 0.046 / 0.048 / 0.052 m). The real garage
masks use 0.15 m for the same reason (`pipeline/import_bev.py`)."""


@dataclass(frozen=True, eq=False)
class TopviewDetections:
    """What one top view shows.

    Attributes:
        points: marking points (pixels, image directions) from the CNN.
        slots: slots assembled from them (pixel corners).
        ids: the painted ID read next to each slot (same order as ``slots``).
        markings: painted lines in the vehicle frame (empty when lines are off).
        timings_ms: per stage: ``slots`` (marking points + slots), ``ids``, ``markings``.
    """

    points: tuple
    slots: tuple[DetectedSlot, ...]
    ids: tuple[SlotIdReading, ...]
    markings: tuple[MarkingObservation, ...] = ()
    timings_ms: dict[str, float] = field(default_factory=dict)


def into_slot_direction(slot: DetectedSlot) -> np.ndarray:
    """Unit vector (pixels) from the slot's entrance into the slot."""
    c = np.asarray(slot.uv_corners, float)
    d = (c[3] + c[2]) / 2.0 - (c[0] + c[1]) / 2.0
    n = float(np.hypot(*d))
    if n < 1e-9:
        raise PerceptionError("slot with zero depth: cannot orient its ID patch")
    return d / n


class TopviewPerception:
    """The top-view detectors, loaded once.

    Args:
        spec: the top-view grid (ps2.0 by default).
        slot_detector, id_reader, marking_detector: injected detectors (default: the
            shipped models and the tuned line detector); ``lines=False`` skips lines.
        corner_sigma: 1-sigma of each reported slot corner, metres: the weight a map or
            filter that takes frames as independent gives it.
        corner_error: per corner, the sigmas (m) of each frame's own error and of the error
            every frame of a slot shares (``SlotObservation.corner_sigma_own`` /
            ``_shared``); None: not declared.
        line_sigma: 1-sigma of each reported line end point across the line, metres.
    """

    def __init__(
        self,
        spec: TopviewSpec | None = None,
        slot_detector: SlotDetector | None = None,
        id_reader: SlotIdReader | None = None,
        marking_detector: MarkingDetector | None = None,
        lines: bool = True,
        corner_sigma: float = DEFAULT_CORNER_SIGMA,
        line_sigma: float = DEFAULT_LINE_SIGMA,
        corner_error: tuple[tuple, tuple] | None = (CORNER_SIGMA_OWN, CORNER_SIGMA_SHARED),
    ) -> None:
        self.spec = spec or TopviewSpec()
        self.slot_detector = slot_detector or SlotDetector(spec=self.spec)
        self.id_reader = id_reader or SlotIdReader()
        self.marking_detector = (marking_detector or MarkingDetector()) if lines else None
        self.corner_sigma = corner_sigma
        self.corner_error = corner_error
        self.line_sigma = line_sigma

    def detect(self, topview: np.ndarray) -> TopviewDetections:
        """Marking points, slots with their IDs, and lines of one BGR uint8 top view."""
        t0 = time.perf_counter()
        points, slots = self.slot_detector.detect(topview)
        t1 = time.perf_counter()
        ids: tuple[SlotIdReading, ...] = ()
        if slots:
            grey = cv2.cvtColor(topview, cv2.COLOR_BGR2GRAY)  # once, not per slot
            patches = [
                crop_id_patch(grey, s.uv_corners[:2], into_slot_direction(s),
                              topview_m_per_px=self.spec.metres_per_px)
                for s in slots
            ]
            ids = tuple(self.id_reader.read_patches(patches))
        t2 = time.perf_counter()
        markings: tuple[MarkingObservation, ...] = ()
        if self.marking_detector is not None:
            markings = tuple(
                dataclasses.replace(m, sigma=self.line_sigma)
                for m in self.marking_detector.detect(topview, self.spec)
            )
        t3 = time.perf_counter()
        timings = {
            "slots": (t1 - t0) * 1e3,
            "ids": (t2 - t1) * 1e3,
            "markings": (t3 - t2) * 1e3,
        }
        return TopviewDetections(tuple(points), tuple(slots), ids, markings, timings)

    def slot_observations(self, detections: TopviewDetections) -> tuple[SlotObservation, ...]:
        """The detected slots as vehicle-frame observations with their read IDs."""
        own, shared = self.corner_error or (None, None)
        return tuple(
            slot_observation(
                slot,
                self.spec,
                reading.label,
                reading.confidence,
                self.corner_sigma,
                own,
                shared,
            )
            for slot, reading in zip(detections.slots, detections.ids, strict=True)
        )


__all__ = [
    "CORNER_SIGMA_OWN",
    "CORNER_SIGMA_SHARED",
    "DEFAULT_CORNER_SIGMA",
    "DEFAULT_LINE_SIGMA",
    "TopviewDetections",
    "TopviewPerception",
    "into_slot_direction",
]
