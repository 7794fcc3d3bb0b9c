"""The JSON form of a tag, shared by the map (map frame) and observations (vehicle frame)."""

from __future__ import annotations

from typing import Any

import numpy as np

from semslam.io._fields import Field
from semslam.types import TagFamily

MAX_YAW = 1000.0
"""A tag's yaw (radians) is refused beyond this: any angle is one within a turn, and a
writer's unwrapped angle stays far below it; 1e300 is a broken file, not an angle."""


MAX_TAG_ID = 10**6
"""Largest tag ID read: the AprilTag families hold at most tens of thousands of codes (587 in
tag36h11), and the mapper keys a tag's graph variable by its ID, which gtsam's symbols hold
only below 2^56 (a larger ID was a ValueError or TypeError, a traceback)."""


def tag_to_dict(family: TagFamily, tag_id: int, size: float, pose: Any, height: float,
                covariance: Any) -> dict[str, Any]:
    """``{"family", "id", "size", "x", "y", "yaw", "height", "covariance"}``."""
    x, y, yaw = (float(v) for v in np.asarray(pose, dtype=float).reshape(3))
    return {
        "family": TagFamily(family).value,
        "id": int(tag_id),
        "size": float(size),
        "x": x,
        "y": y,
        "yaw": yaw,
        "height": float(height),
        "covariance": np.asarray(covariance, dtype=float).tolist(),
    }


def tag_fields(f: Field, reach: float | None = None) -> dict[str, Any]:
    """The checked parts of a tag dict: family, tag_id, size, pose (3,), height, covariance;
    ``x`` and ``y`` within ``reach`` (metres) of the frame's origin when given, ``yaw``
    within :data:`MAX_YAW`, ``id`` at most :data:`MAX_TAG_ID`."""
    low, high = (None, None) if reach is None else (-reach, reach)
    return {
        "family": f["family"].choice(TagFamily),
        "tag_id": f["id"].integer(0, MAX_TAG_ID),
        "size": f["size"].number(positive=True),
        "pose": np.array([f["x"].number(low, high), f["y"].number(low, high),
                          f["yaw"].number(-MAX_YAW, MAX_YAW)]),
        "height": f["height"].number(),
        "covariance": f["covariance"].array((3, 3)),
    }
