"""Read the tags a `semslam plan-tags` plan proposes (``tag_plan.json``).

Only ``proposed_tags`` is read: a list of ``{"x": m, "y": m, "yaw": rad}`` in the map frame,
the yaw the direction the tag faces.
"""

from __future__ import annotations

import math
import os

import numpy as np

from semslam.errors import FormatError
from semslam.geometry import FloatArray
from semslam.io._fields import Field
from semslam.io._json import parse_json
from semslam.io._text import read_text
from semslam.io.map_json import MAX_COORDINATE


def read_proposed_tags(path: str | os.PathLike[str]) -> FloatArray:
    """The proposed tag poses (K, 3) of a tag plan, in its order.

    Raises:
        FormatError: missing file, broken JSON, no ``proposed_tags`` list, or a tag whose
            x, y or yaw is missing, not a finite number or out of range (x, y within
            :data:`~semslam.io.map_json.MAX_COORDINATE` m as in a map, yaw within 2 pi);
            the message names the field.
    """
    name = os.fspath(path)
    doc = Field(parse_json(read_text(path, FormatError), name, FormatError), name, FormatError)
    poses = [
        [
            tag["x"].number(-MAX_COORDINATE, MAX_COORDINATE),
            tag["y"].number(-MAX_COORDINATE, MAX_COORDINATE),
            tag["yaw"].number(-2 * math.pi, 2 * math.pi),
        ]
        for tag in doc["proposed_tags"].items()
    ]
    return np.array(poses, dtype=float).reshape(-1, 3)


__all__ = ["read_proposed_tags"]
