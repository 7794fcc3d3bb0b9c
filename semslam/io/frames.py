"""frames.csv: the frame times and, per camera or image kind, the image file of each frame.

Header ``t,<column>,<column>...`` (e.g. ``t,topview,front``); values after
``t`` are paths relative to the drive folder, written with '/', or empty
when that frame has no such image.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import PurePosixPath

import numpy as np

from semslam.geometry import FloatArray
from semslam.io._csv import check_columns, read_table
from semslam.io._rows import check_time_order, check_times, parse_number
from semslam.io.atomic import atomic_write_text
from semslam.io.errors import DriveFormatError
from semslam.io.tum import MAX_TIME

_COLUMN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


@dataclass(frozen=True, eq=False)
class FrameIndex:
    """The frames of a drive.

    Attributes:
        t: (N,) strictly increasing frame times, seconds.
        images: per column (``"topview"``, ``"front"``...) a list of N paths
            relative to the drive folder; ``""`` where a frame has no image.
    """

    t: FloatArray
    images: dict[str, list[str]] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(np.asarray(self.t).shape[0])


def write_frames(path: str | os.PathLike[str], frames: FrameIndex) -> None:
    """Write frames.csv atomically.

    Raises:
        DriveFormatError: a column of the wrong length or with a bad name, an
            absolute path or one with ',' or a line break, NaN times, times beyond
            ``MAX_TIME`` or not strictly increasing; nothing is written.
    """
    name = os.fspath(path)
    t = np.asarray(frames.t, dtype=float)
    if t.ndim != 1:
        raise DriveFormatError(f"{name}: t must be an (N,) array, got shape {t.shape}")
    check_times(t, path, DriveFormatError, "frame", within=MAX_TIME, microseconds=True)
    columns = list(frames.images)
    for column in columns:
        if column == "t" or not _COLUMN_NAME.match(column):
            raise DriveFormatError(f"{name}: bad column name {column!r}")
        paths = frames.images[column]
        if len(paths) != t.shape[0]:
            raise DriveFormatError(
                f"{name}: column {column} has {len(paths)} paths for {t.shape[0]} frames"
            )
        for i, p in enumerate(paths):
            problem = _path_problem(p)
            if problem:
                raise DriveFormatError(f"{name}: frame {i}: {column}: {problem}")
    lines = [",".join(["t", *columns])]
    for i, ti in enumerate(t):
        lines.append(",".join([repr(float(ti)), *(frames.images[c][i] for c in columns)]))
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_frames(path: str | os.PathLike[str]) -> FrameIndex:
    """Read frames.csv.

    Raises:
        DriveFormatError: missing or empty file, a header not starting with
            ``t`` or with bad or repeated column names, wrong column count,
            a bad time (or one beyond :data:`semslam.io.tum.MAX_TIME`, 1e11 s: the
            trajectories written per frame could not hold it), time not strictly increasing,
            an absolute path or one leaving the drive folder; the message names the file and
            line.
    """
    name = os.fspath(path)
    header, rows = read_table(path, DriveFormatError)
    if header[0] != "t":
        raise DriveFormatError(f"{name} line 1: first column is '{header[0]}', expected 't'")
    for column in header[1:]:
        if not _COLUMN_NAME.match(column):
            raise DriveFormatError(f"{name} line 1: bad column name {column!r}")
    if len(set(header)) != len(header):
        raise DriveFormatError(f"{name} line 1: repeated column name in '{','.join(header)}'")
    t = np.empty(len(rows))
    images: dict[str, list[str]] = {c: [] for c in header[1:]}
    previous: float | None = None
    for i, (lineno, fields) in enumerate(rows):
        where = f"{name} line {lineno}"
        check_columns(fields, header, where, DriveFormatError)
        t[i] = parse_number(fields[0], where, "t", DriveFormatError, MAX_TIME, "s")
        check_time_order(previous, t[i], where, DriveFormatError, microseconds=True)
        previous = t[i]
        for column, value in zip(header[1:], fields[1:], strict=True):
            value = value.strip()
            problem = _path_problem(value)
            if problem:
                raise DriveFormatError(f"{where}: {column}: {problem}")
            images[column].append(value)
    return FrameIndex(t=t, images=images)


def _path_problem(p: str) -> str | None:
    """Why ``p`` is not a usable relative image path, or None ('' is fine: no image)."""
    if not isinstance(p, str):
        return f"expected a path string, got {type(p).__name__}"
    if not p:
        return None
    if "," in p or "\n" in p or "\r" in p:
        return f"path {p!r} contains ',' or a line break"
    if p != p.strip():  # the reader strips each column
        return f"path {p!r} starts or ends with white space"
    if "\\" in p or re.match(r"[A-Za-z]:", p):
        return f"path {p!r} must use '/' and be relative"
    pure = PurePosixPath(p)
    if pure.is_absolute():
        return f"path {p!r} is absolute, expected relative to the drive folder"
    if ".." in pure.parts:
        return f"path {p!r} leaves the drive folder"
    return None
