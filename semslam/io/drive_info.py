"""drive.json: what a drive is, where it starts and which observation sets it holds.

Layout::

    {"format": "semslam-drive", "version": 1, "name": "garage-a-run-3",
     "start_pose": [x, y, yaw] or null, "frame_rate": 10.0,
     "source": {...free...}, "observations": ["exact", "noisy"]}

``start_pose`` is the vehicle's pose in the map frame at the first
odometry sample (metres, radians); null when unknown (then the drive
starts at the origin). ``observations`` names the files
``observations/<name>.jsonl``. Missing ``start_pose``, ``source`` or
``observations`` read as null, ``{}`` and ``[]``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from semslam.geometry import FloatArray
from semslam.io._fields import Field, check_header
from semslam.io._json import (
    dumps_pretty,
    find_non_finite,
    non_finite_message,
    parse_json,
    to_jsonable,
)
from semslam.io._text import read_text
from semslam.io.atomic import atomic_write_text
from semslam.io.errors import DriveFormatError
from semslam.io.odometry import MAX_RATE

DRIVE_FORMAT = "semslam-drive"
DRIVE_VERSION = 1
_OBSERVATION_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*\Z")
MAX_START = 1e5
"""Bound on each start-pose number (m, m, rad): a drive starting farther out would leave the
map's own range (1e6 m) or overflow the filter's arithmetic."""
MAX_FRAME_RATE = MAX_RATE
"""Bound on ``frame_rate``, Hz: the odometry's own (:data:`semslam.io.odometry.MAX_RATE`); no
camera of a drive semslam reads is faster."""


@dataclass(frozen=True, eq=False)
class DriveInfo:
    """The content of drive.json.

    Attributes:
        name: a name for the drive.
        start_pose: (3,) pose ``(x, y, yaw)`` of the vehicle in the map frame
            at the first odometry sample, or None when unknown.
        frame_rate: camera frame rate, Hz.
        source: free-form description of where the drive came from (simulator
            seed and settings, recording...).
        observations: names of the observation sets in ``observations/<name>.jsonl``.
    """

    name: str
    start_pose: FloatArray | None = None
    frame_rate: float = 10.0
    source: dict[str, Any] = field(default_factory=dict)
    observations: tuple[str, ...] = ()


def drive_info_to_dict(info: DriveInfo) -> dict[str, Any]:
    """The JSON document of drive.json."""
    start = None if info.start_pose is None else np.asarray(info.start_pose, dtype=float).tolist()
    return {
        "format": DRIVE_FORMAT,
        "version": DRIVE_VERSION,
        "name": info.name,
        "start_pose": start,
        "frame_rate": float(info.frame_rate),
        "source": to_jsonable(dict(info.source), "source"),
        "observations": list(info.observations),
    }


def drive_info_from_dict(document: Any, source: str = "<dict>") -> DriveInfo:
    """drive.json's content from its JSON document.

    Raises:
        DriveFormatError: wrong format or version, a missing, unknown or
            mistyped field, NaN; the message names ``source`` and the field.
    """
    bad = find_non_finite(document)
    if bad is not None:
        raise DriveFormatError(f"{source}: {non_finite_message(*bad)}")
    root = Field(document, source, DriveFormatError)
    check_header(root, DRIVE_FORMAT, DRIVE_VERSION)
    root.only("format", "version", "name", "start_pose", "frame_rate", "source", "observations")
    start = root.get("start_pose")
    listed = root.get("observations")
    names: list[str] = []
    for f in [] if listed is None else listed.items():
        n = f.string()
        if not _OBSERVATION_NAME.match(n):
            f.fail(f"{n!r} is not a usable file name")
        if n in names:
            f.fail(f"repeated name {n!r}")
        names.append(n)
    source_field = root.get("source")
    return DriveInfo(
        name=root["name"].string(nonempty=True),
        start_pose=None if start is None else start.array((3,), within=MAX_START),
        frame_rate=root["frame_rate"].number(positive=True, maximum=MAX_FRAME_RATE),
        source={} if source_field is None else dict(source_field.obj()),
        observations=tuple(names),
    )


def write_drive_info(path: str | os.PathLike[str], info: DriveInfo) -> None:
    """Write drive.json atomically after checking that it reads back.

    Raises:
        DriveFormatError: the content would not read back; nothing is written.
    """
    document = drive_info_to_dict(info)
    drive_info_from_dict(document, os.fspath(path))
    atomic_write_text(path, dumps_pretty(document))


def read_drive_info(path: str | os.PathLike[str]) -> DriveInfo:
    """Read drive.json.

    Raises:
        DriveFormatError: missing file, broken JSON or anything
            :func:`drive_info_from_dict` refuses.
    """
    name = os.fspath(path)
    text = read_text(path, DriveFormatError)
    return drive_info_from_dict(parse_json(text, name, DriveFormatError), name)
