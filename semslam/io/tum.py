"""TUM trajectories, as evo reads them: one pose per line, ``t x y z qx qy qz qw``.

Poses here are planar: ``(x, y, yaw)`` in metres and radians; the file has
z = 0 and the quaternion of a rotation by yaw about +z. Time in seconds
with 6 decimals, positions with 6 (a micrometre), quaternions with 9.
"""

from __future__ import annotations

import math
import os

import numpy as np
from numpy.typing import ArrayLike

from semslam.errors import FormatError
from semslam.geometry import FloatArray, quaternion_to_yaw, yaw_to_quaternion
from semslam.io._rows import check_finite_columns, check_time_order, check_times, parse_number
from semslam.io._text import read_text, text_lines
from semslam.io.atomic import atomic_write_text

TUM_HEADER = "# t x y z qx qy qz qw"
_COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")

MAX_POSITION = 1e6
"""Largest ``|x|``, ``|y|``, ``|z|`` read, metres (1000 km: beyond it a file is broken)."""

MAX_TIME = 1e11
"""Largest ``|t|`` read, seconds (3000 years: nanosecond stamps are refused, not misread)."""

MAX_TILT_DEG = 45.0
"""Largest roll/pitch tilt read, degrees: garage ramps are under 15; a pose tilted more is a
trajectory of another axis convention (a camera frame, z forward), whose yaw is nonsense."""

_BOUNDS = {col: (MAX_POSITION, "m") for col in ("x", "y", "z")}  # parse_number's within, unit


def write_tum(path: str | os.PathLike[str], t: ArrayLike, poses: ArrayLike) -> None:
    """Write a planar trajectory as a TUM file, atomically.

    Args:
        path: target file.
        t: (N,) strictly increasing times, seconds.
        poses: (N, 3) poses ``(x, y, yaw)`` in the map frame, metres and radians.

    Raises:
        FormatError: shapes disagree, no poses, a value is NaN/infinite or beyond what
            :func:`read_tum` reads (:data:`MAX_TIME`, :data:`MAX_POSITION`), or time does
            not increase at the file's microseconds: what would not read back.
    """
    times = np.asarray(t, dtype=float)
    p = np.asarray(poses, dtype=float)
    if times.ndim != 1 or p.shape != (times.shape[0], 3):
        raise FormatError(
            f"{os.fspath(path)}: expected t (N,) and poses (N, 3), got {times.shape} and {p.shape}"
        )
    if times.shape[0] == 0:
        raise FormatError(f"{os.fspath(path)}: no poses to write (empty trajectory)")
    check_finite_columns({"x": p[:, 0], "y": p[:, 1], "yaw": p[:, 2]}, path, FormatError, "pose")
    check_times(times, path, FormatError, "pose")
    for name, values, limit in (("t", times, MAX_TIME), ("x", p[:, 0], MAX_POSITION),
                                ("y", p[:, 1], MAX_POSITION)):
        beyond = np.flatnonzero(np.abs(values) > limit)
        if len(beyond):
            k = int(beyond[0])
            raise FormatError(f"{os.fspath(path)}: pose {k}: {name} {values[k]:g} is out of "
                              f"range (|{name}| <= {limit:g})")
    stamps = [f"{ti:.6f}" for ti in times]
    for k in range(1, len(stamps)):
        if float(stamps[k]) <= float(stamps[k - 1]):
            raise FormatError(f"{os.fspath(path)}: pose {k}: time {stamps[k]} s repeats at the "
                              "file's microseconds")
    lines = [TUM_HEADER]
    for stamp, (x, y, yaw) in zip(stamps, p, strict=True):
        qx, qy, qz, qw = yaw_to_quaternion(float(yaw))
        lines.append(f"{stamp} {x:.6f} {y:.6f} 0.000000 {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}")
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_tum_rows(path: str | os.PathLike[str]) -> tuple[FloatArray, list[int]]:
    """The rows ``t x y z qx qy qz qw`` (N, 8) of a TUM file, checked, with the line number
    of each (for readers that add their own checks); '#' comments and blank lines skipped.

    Raises:
        FormatError: missing file, no poses, wrong column count, a non-number,
            NaN/infinity, a time beyond :data:`MAX_TIME` or a position beyond
            :data:`MAX_POSITION`, a zero quaternion or time not strictly increasing;
            the message names the file and line.
    """
    name = os.fspath(path)
    rows: list[list[float]] = []
    lines: list[int] = []
    previous: float | None = None
    for lineno, line in enumerate(text_lines(read_text(path, FormatError)), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        where = f"{name} line {lineno}"
        tokens = text.split()
        if len(tokens) != len(_COLUMNS):
            kind = " (a JSON file? a TUM trajectory is text rows)" if text[0] in "{[" else ""
            raise FormatError(
                f"{where}: expected 8 columns (t x y z qx qy qz qw), got {len(tokens)}{kind}"
            )
        row = [
            parse_number(tok, where, col, FormatError, *_BOUNDS.get(col, ()))
            for tok, col in zip(tokens, _COLUMNS, strict=True)
        ]
        if abs(row[0]) > MAX_TIME:
            raise FormatError(
                f"{where}: t {row[0]:g} s is out of range (|t| <= {MAX_TIME:g} s; "
                "TUM times are seconds)"
            )
        if math.hypot(*row[4:]) < 1e-9:
            raise FormatError(f"{where}: quaternion has zero length")
        check_time_order(previous, row[0], where, FormatError)
        previous = row[0]
        rows.append(row)
        lines.append(lineno)
    if not rows:
        raise FormatError(f"{name}: no poses (empty trajectory)")
    return np.array(rows, dtype=float), lines


def read_tum(path: str | os.PathLike[str]) -> tuple[FloatArray, FloatArray]:
    """Read a TUM trajectory; '#' comments and blank lines are skipped; z, roll and pitch
    are dropped (a tilt up to :data:`MAX_TILT_DEG`: a ramp, a body on its springs).

    Returns:
        ``(t, poses)``: (N,) times in seconds and (N, 3) poses ``(x, y, yaw)``,
        yaw wrapped to (-pi, pi].

    Raises:
        FormatError: as :func:`read_tum_rows`, or a pose tilted more than
            :data:`MAX_TILT_DEG` from level (its yaw would mean nothing).
    """
    rows, lines = read_tum_rows(path)
    q = rows[:, 4:8] / np.linalg.norm(rows[:, 4:8], axis=1, keepdims=True)
    up = 1.0 - 2.0 * (q[:, 0] ** 2 + q[:, 1] ** 2)  # body z . world z = cos(tilt)
    tilted = np.nonzero(up < math.cos(math.radians(MAX_TILT_DEG)))[0]
    if len(tilted):
        k = int(tilted[0])
        tilt = math.degrees(math.acos(float(np.clip(up[k], -1.0, 1.0))))
        raise FormatError(
            f"{os.fspath(path)} line {lines[k]}: the pose is tilted {tilt:.0f} deg from level "
            f"(more than {MAX_TILT_DEG:g}); poses here are planar, body z up (a camera-frame "
            "trajectory, z forward?)"
        )
    yaw = [quaternion_to_yaw(*q) for q in rows[:, 4:8]]
    return rows[:, 0].copy(), np.column_stack([rows[:, 1], rows[:, 2], yaw])
