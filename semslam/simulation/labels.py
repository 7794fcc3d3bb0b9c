"""Training labels of a rendered top view, in the DMPR-PS label form used by ps2.0.

``{"marks": [[x, y, x2, y2, shape], ...], "slots": [[i, j, type, angle], ...],
"ids": [{"slot": k, "label": "B17", "box": [[u, v] x 4]}, ...]}``: (x, y) a
marking point in pixels, direction atan2(y2 - y, x2 - x) along the separating
line into the slot, shape 0 = T, 1 = L; slots index marks from 1, type 1
perpendicular, 2 parallel, 3 slanted, angle in degrees. ``ids`` (our
addition; DMPR-PS readers ignore it) boxes each painted slot ID for the
ID recogniser.
"""

from __future__ import annotations

import json
import math
from typing import Any

_DIRECTION_LENGTH_PX = 50.0


def annotation_to_dict(annotation: Any) -> dict[str, Any]:
    """The DMPR-PS dict of a ``TopviewAnnotation`` (points, directions, shapes, slots, ids)."""
    marks = [
        [
            round(float(x), 3),
            round(float(y), 3),
            round(float(x + _DIRECTION_LENGTH_PX * math.cos(d)), 3),
            round(float(y + _DIRECTION_LENGTH_PX * math.sin(d)), 3),
            int(shape),
        ]
        for (x, y), d, shape in zip(
            annotation.points, annotation.directions, annotation.shapes, strict=True
        )
    ]
    slots = [
        [int(i), int(j), int(kind), round(float(angle), 3)]
        for i, j, kind, angle in annotation.slots
    ]
    ids = [
        {
            "slot": int(slot_id),
            "label": label,
            "box": [[round(float(u), 2), round(float(v), 2)] for u, v in box],
        }
        for slot_id, label, box in annotation.ids
    ]
    return {"marks": marks, "slots": slots, "ids": ids}


def annotation_to_json(annotation: Any) -> str:
    """One-line JSON of :func:`annotation_to_dict`."""
    return json.dumps(annotation_to_dict(annotation), separators=(",", ":")) + "\n"
