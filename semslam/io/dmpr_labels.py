"""Top-view labels in the DMPR-PS form of the ps2.0 data set.

One JSON file per 600 x 600 top-view image::

    {"marks": [[x, y, x2, y2, shape], ...], "slots": [[i, j, type, angle], ...]}

``(x, y)`` is a marking point in pixels (u right, v down); ``(x2, y2)`` a
second point along the marking line, so the point's direction is
``atan2(y2 - y, x2 - x)`` in image coordinates; ``shape`` is 0 for a T and
1 for an L junction. A slot joins marks ``i`` and ``j`` (1-based) at its
entrance; ``type`` is 1 perpendicular, 2 parallel, 3 slanted; ``angle`` is
the slot angle in degrees (90 for perpendicular slots). A file with one
mark (or one slot) stores it as a flat list, which is read and written the
same way.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.errors import FormatError
from semslam.geometry import FloatArray
from semslam.io._fields import Field, int_text
from semslam.io._json import find_non_finite, non_finite_message, parse_json
from semslam.io._text import read_text
from semslam.io.atomic import atomic_write_text
from semslam.types import JunctionShape, SlotKind

IntArray = NDArray[np.int64]

SHAPES = (JunctionShape.T, JunctionShape.L)
"""Junction shape by the label's shape code (0 = T, 1 = L)."""

SLOT_TYPES = {1: SlotKind.PERPENDICULAR, 2: SlotKind.PARALLEL, 3: SlotKind.SLANTED}
"""Slot kind by the label's type code."""


@dataclass(frozen=True, eq=False)
class TopviewLabels:
    """Marking points and slots labelled on one top-view image.

    Attributes:
        points: (N, 2) marking points, pixels (u right, v down).
        directions: (N,) direction of each point's marking line, radians,
            ``atan2(dv, du)`` in image coordinates.
        shapes: (N,) junction shape codes: 0 = T, 1 = L (see :data:`SHAPES`).
        slots: (M, 4) integer rows ``(i, j, type, angle)``: 1-based indices of
            the entrance marks, type code (see :data:`SLOT_TYPES`), angle in degrees.
    """

    points: FloatArray
    directions: FloatArray
    shapes: IntArray
    slots: IntArray

    def junction_shapes(self) -> list[JunctionShape]:
        """``shapes`` as :class:`~semslam.types.JunctionShape` values."""
        return [SHAPES[int(s)] for s in self.shapes]

    def slot_kinds(self) -> list[SlotKind]:
        """The slot type codes as :class:`~semslam.types.SlotKind` values."""
        return [SLOT_TYPES[int(s)] for s in self.slots[:, 2]]

    def with_separator_directions(self, max_angle_deg: float = 45.0) -> TopviewLabels:
        """These labels with every slot's entrance points directed along its separators
        into the slot, as semslam's detector reports them.

        ps2.0 (DMPR-PS) directs an L junction along one of its two arms: the separator
        when the point is a slot's first entrance point, the entrance line towards the
        first point when it is the second (741 of the 741 such points in the ps2.0
        training labels; T junctions point along their separator). Each second point
        that is an L directed within ``max_angle_deg`` of its first point takes the first
        point's direction (a slot's separators are parallel), unless that one lies along
        the entrance too.
        """
        directions = self.directions.copy()
        limit = np.radians(max_angle_deg)
        for i, j in np.asarray(self.slots, dtype=np.int64).reshape(-1, 4)[:, :2] - 1:
            if self.shapes[j] != 1:
                continue
            dx, dy = self.points[i] - self.points[j]
            along = math.atan2(dy, dx)  # from the second point towards the first
            first_off_line = min(_angle_between(self.directions[i], along),
                                 _angle_between(self.directions[i], along + math.pi)) > limit
            if _angle_between(self.directions[j], along) <= limit and first_off_line:
                directions[j] = self.directions[i]
        return replace(self, directions=directions)


def _angle_between(a: float, b: float) -> float:
    """Unsigned angle between two directions, radians in [0, pi]."""
    return abs((a - b + math.pi) % (2.0 * math.pi) - math.pi)


def dmpr_labels_to_dict(labels: TopviewLabels, arm_length_px: float = 50.0) -> dict[str, Any]:
    """The JSON document of ``labels``; the second point of each mark lies
    ``arm_length_px`` pixels along its direction."""
    points = np.asarray(labels.points, dtype=float).reshape(-1, 2)
    directions = np.asarray(labels.directions, dtype=float).reshape(-1)
    ends = points + arm_length_px * np.stack([np.cos(directions), np.sin(directions)], axis=1)
    marks: list[Any] = [
        [float(p[0]), float(p[1]), float(e[0]), float(e[1]), int(s)]
        for p, e, s in zip(points, ends, np.asarray(labels.shapes).reshape(-1), strict=True)
    ]
    slots: list[Any] = [[int(v) for v in row] for row in np.asarray(labels.slots).reshape(-1, 4)]
    return {
        "marks": marks[0] if len(marks) == 1 else marks,
        "slots": slots[0] if len(slots) == 1 else slots,
    }


def dmpr_labels_from_dict(document: Any, source: str = "<dict>") -> TopviewLabels:
    """Labels from their JSON document.

    Raises:
        FormatError: a mark without 5 numbers, a shape other than 0/1, a slot
            without 4 integers, an index out of range, an unknown type,
            NaN; the message names ``source`` and the field (``marks/2``).
    """
    bad = find_non_finite(document)
    if bad is not None:
        raise FormatError(f"{source}: {non_finite_message(*bad)}")
    root = Field(document, source, FormatError)
    marks = [_mark(f) for f in _rows(root["marks"])]
    n = len(marks)
    slot_field = root.get("slots")
    slots = [_slot(f, n) for f in ([] if slot_field is None else _rows(slot_field))]
    points = np.array([m[:2] for m in marks], dtype=float).reshape(n, 2)
    second = np.array([m[2:4] for m in marks], dtype=float).reshape(n, 2)
    d = second - points
    return TopviewLabels(
        points=points,
        directions=np.arctan2(d[:, 1], d[:, 0]),
        shapes=np.array([int(m[4]) for m in marks], dtype=np.int64),
        slots=np.array(slots, dtype=np.int64).reshape(len(slots), 4),
    )


def read_dmpr_labels(path: str | os.PathLike[str]) -> TopviewLabels:
    """Read one ps2.0 / DMPR-PS label file.

    Raises:
        FormatError: missing file, broken JSON or anything
            :func:`dmpr_labels_from_dict` refuses.
    """
    source = os.fspath(path)
    return dmpr_labels_from_dict(
        parse_json(read_text(path, FormatError), source, FormatError), source
    )


def write_dmpr_labels(
    path: str | os.PathLike[str], labels: TopviewLabels, arm_length_px: float = 50.0
) -> None:
    """Write labels in the ps2.0 form, atomically (see :func:`dmpr_labels_to_dict`).

    Raises:
        FormatError: the labels would not read back; nothing is written.
    """
    document = dmpr_labels_to_dict(labels, arm_length_px)
    dmpr_labels_from_dict(document, os.fspath(path))
    atomic_write_text(path, json.dumps(document, allow_nan=False) + "\n")


_MAX_PIXEL = 1e6
"""Largest magnitude of a label coordinate, px: ps2.0's views are 600 px; far beyond, the
file is broken (1e300 overflowed the detection metrics' squared distances)."""


def _rows(f: Field) -> list[Field]:
    """The rows of ``marks``/``slots``: a flat list is one row."""
    items = f.items()
    if items and not isinstance(items[0].value, list):
        return [f]
    return items


def _mark(f: Field) -> tuple[float, float, float, float, int]:
    items = f.items()
    if len(items) != 5:
        f.fail(f"expected 5 numbers [x, y, x2, y2, shape], got {len(items)}")
    x, y, x2, y2 = (e.number(-_MAX_PIXEL, _MAX_PIXEL) for e in items[:4])
    shape = items[4].number()
    if shape not in (0.0, 1.0):
        items[4].fail(f"shape must be 0 (T) or 1 (L), got {shape!r}")
    if x == x2 and y == y2:
        f.fail("the direction point equals the marking point")
    return x, y, x2, y2, int(shape)


def _slot(f: Field, n_marks: int) -> list[int]:
    items = f.items()
    if len(items) != 4:
        f.fail(f"expected 4 numbers [i, j, type, angle], got {len(items)}")
    values = []
    for e in items:
        v = e.number()
        if v != int(v):
            e.fail(f"expected an integer, got {v!r}")
        values.append(int(v))
    i, j, kind, angle = values
    if not 0 <= angle <= 180:
        items[3].fail(f"angle must be 0 to 180 degrees, got {int_text(angle)}")
    for k, idx in enumerate((i, j)):
        if not 1 <= idx <= n_marks:
            items[k].fail(f"mark index {int_text(idx)} out of range 1..{n_marks}")
    if i == j:
        items[1].fail(f"the slot joins mark {i} to itself")
    if kind not in SLOT_TYPES:
        items[2].fail(f"type must be 1, 2 or 3, got {kind}")
    return values
