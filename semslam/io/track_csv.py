"""The per-frame output of the online localizer, a CSV written beside its TUM trajectory.

``NAME.tum`` holds the poses for evo; ``NAME.csv`` repeats them at full
precision with what the TUM format has no room for: the pose covariance,
the localizer's status and how many map elements it associated or rejected.
Header::

    t,x,y,yaw,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw,status,associated,rejected

Times in seconds, ``x, y, yaw`` the pose of the vehicle in the map frame
(m, m, rad), the covariance as its upper triangle (m^2, m^2, m*rad, m^2,
m*rad, rad^2), ``status`` one of :data:`TRACK_STATUSES`, the two counts as
non-negative integers. Floats are written with ``repr`` (they read back
bit for bit).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.errors import FormatError
from semslam.geometry import FloatArray
from semslam.io._csv import check_columns, check_header, read_table
from semslam.io._rows import check_finite_columns, check_time_order, check_times, parse_number
from semslam.io.atomic import atomic_write_text

TRACK_HEADER = [
    "t",
    "x",
    "y",
    "yaw",
    "cov_xx",
    "cov_xy",
    "cov_xyaw",
    "cov_yy",
    "cov_yyaw",
    "cov_yawyaw",
    "status",
    "associated",
    "rejected",
]
TRACK_STATUSES = ("tracking", "coasting", "lost", "relocalized", "initializing")
"""What the localizer was doing at a frame: ``tracking`` (updated from the map),
``coasting`` (odometry only, still trusted), ``lost`` (no usable estimate),
``relocalized`` (a fresh global fix this frame), ``initializing`` (no first fix yet)."""

_FLOAT_COLUMNS = TRACK_HEADER[:10]
_UPPER = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))  # row-major upper triangle
_VARIANCES = {"cov_xx", "cov_yy", "cov_yawyaw"}

MIN_VARIANCE = 1e-30
"""Smallest non-zero variance of a track (m^2, rad^2): a sigma of 1e-15 m or rad. No estimate is
that sure; below it (1e-315, a denormal) the NEES of an evaluation overflows to infinity and
NaN. 0 is kept: it stands for a frame without a covariance."""


@dataclass(frozen=True, eq=False)
class Track:
    """The localizer's estimate at each frame.

    Attributes:
        t: (N,) strictly increasing frame times, seconds.
        poses: (N, 3) ``(x, y, yaw)`` of the vehicle in the map frame
            (``mTv``), metres and radians.
        covariances: (N, 3, 3) symmetric covariance of each pose, order
            ``(x, y, yaw)``: m^2, m*rad, rad^2.
        status: N entries, each one of :data:`TRACK_STATUSES`.
        associated: (N,) map elements used in the frame's update.
        rejected: (N,) observations the frame's gate refused.
    """

    t: FloatArray
    poses: FloatArray
    covariances: FloatArray
    status: tuple[str, ...]
    associated: NDArray[np.int64]
    rejected: NDArray[np.int64]

    def __len__(self) -> int:
        return int(np.asarray(self.t).shape[0])


def write_track_csv(path: str | os.PathLike[str], track: Track) -> None:
    """Write a track CSV atomically, every float at full precision (``repr``).

    Only the upper triangle of each covariance is written; it reads back
    symmetric.

    Raises:
        FormatError: no frames, arrays of disagreeing shapes, NaN/infinity, a
            negative variance or count, a count that is not an integer, an
            unknown status, or time not strictly increasing; nothing is written.
    """
    name = os.fspath(path)
    t = np.asarray(track.t, dtype=float)
    poses = np.asarray(track.poses, dtype=float)
    covs = np.asarray(track.covariances, dtype=float)
    associated = np.asarray(track.associated)
    rejected = np.asarray(track.rejected)
    n = t.shape[0] if t.ndim == 1 else -1
    shapes = (t.shape, poses.shape, covs.shape, (len(track.status),), associated.shape)
    if (
        n < 0
        or poses.shape != (n, 3)
        or covs.shape != (n, 3, 3)
        or len(track.status) != n
        or associated.shape != (n,)
        or rejected.shape != (n,)
    ):
        raise FormatError(
            f"{name}: expected t (N,), poses (N, 3), covariances (N, 3, 3), status, "
            f"associated and rejected (N,), got {[*shapes, rejected.shape]}"
        )
    if n == 0:
        raise FormatError(f"{name}: no frames to write (empty track)")
    upper = covs[:, _UPPER[0], _UPPER[1]]
    columns = {c: v for c, v in zip(_FLOAT_COLUMNS, [t, *poses.T, *upper.T], strict=True)}
    check_finite_columns(columns, path, FormatError, "frame")
    check_times(t, path, FormatError, "frame")
    for column in _VARIANCES:
        bad = np.flatnonzero(columns[column] < 0)
        if bad.size:
            raise FormatError(f"{name}: frame {bad[0]}: {column} is negative")
        tiny = np.flatnonzero((columns[column] > 0) & (columns[column] < MIN_VARIANCE))
        if tiny.size:
            raise FormatError(f"{name}: frame {tiny[0]}: {_tiny(column, columns[column][tiny[0]])}")
    counts = {"associated": associated, "rejected": rejected}
    for column, values in counts.items():
        listed = values.tolist()
        ok = np.array([_is_count(v) for v in listed], dtype=bool)
        if not ok.all():
            i = int(np.flatnonzero(~ok)[0])
            raise FormatError(
                f"{name}: frame {i}: {column} is {listed[i]!r}, expected an integer >= 0"
            )
    for i, s in enumerate(track.status):
        if s not in TRACK_STATUSES:
            raise FormatError(
                f"{name}: frame {i}: status {s!r} is not one of {', '.join(TRACK_STATUSES)}"
            )
    rows = np.column_stack([columns[c] for c in _FLOAT_COLUMNS]).tolist()
    lines = [",".join(TRACK_HEADER)]
    lines += [
        ",".join([*(repr(float(v)) for v in row), str(s), str(int(a)), str(int(r))])
        for row, s, a, r in zip(rows, track.status, associated, rejected, strict=True)
    ]
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_track_csv(path: str | os.PathLike[str]) -> Track:
    """Read a track CSV.

    Raises:
        FormatError: missing or empty file, wrong header, wrong column count,
            a non-number, NaN/infinity, a negative variance, a count that is
            not an integer >= 0, an unknown status, time not strictly
            increasing; one line naming the file and line, e.g.
            ``run.csv line 7: status 'found' is not one of tracking, ...``.
    """
    name = os.fspath(path)
    header, rows = read_table(path, FormatError)
    check_header(header, TRACK_HEADER, path, FormatError)
    floats = np.empty((len(rows), len(_FLOAT_COLUMNS)))
    counts = np.empty((len(rows), 2), dtype=np.int64)
    status: list[str] = []
    previous: float | None = None
    for i, (lineno, fields) in enumerate(rows):
        where = f"{name} line {lineno}"
        check_columns(fields, TRACK_HEADER, where, FormatError)
        for j, column in enumerate(_FLOAT_COLUMNS):
            floats[i, j] = parse_number(fields[j], where, column, FormatError)
            if column in _VARIANCES and floats[i, j] < 0:
                raise FormatError(f"{where}: {column} is negative ({fields[j].strip()})")
            if column in _VARIANCES and 0 < floats[i, j] < MIN_VARIANCE:
                raise FormatError(f"{where}: {_tiny(column, floats[i, j])}")
        check_time_order(previous, floats[i, 0], where, FormatError)
        previous = floats[i, 0]
        s = fields[10].strip()
        if s not in TRACK_STATUSES:
            raise FormatError(f"{where}: status {s!r} is not one of {', '.join(TRACK_STATUSES)}")
        status.append(s)
        for k, column in enumerate(("associated", "rejected")):
            counts[i, k] = _parse_count(fields[11 + k], where, column)
    covs = np.zeros((len(rows), 3, 3))
    covs[:, _UPPER[0], _UPPER[1]] = floats[:, 4:]
    covs[:, _UPPER[1], _UPPER[0]] = floats[:, 4:]
    return Track(
        t=floats[:, 0].copy(),
        poses=floats[:, 1:4].copy(),
        covariances=covs,
        status=tuple(status),
        associated=counts[:, 0].copy(),
        rejected=counts[:, 1].copy(),
    )


def _tiny(column: str, value: float) -> str:
    return (f"{column} {value:g} is below {MIN_VARIANCE:g} (no estimate is that sure; "
            "0 stands for no covariance)")


def _is_count(value: object) -> bool:
    """An integer >= 0 (a float is accepted when it is a whole number)."""
    if isinstance(value, bool):
        return False
    if isinstance(value, int):
        return value >= 0
    return isinstance(value, float) and value.is_integer() and value >= 0


def _parse_count(token: str, where: str, column: str) -> int:
    text = token.strip()
    if not (text.isascii() and text.isdigit()):  # no sign, no decimal point
        shown = text or "empty"
        raise FormatError(f"{where}: {column} is {shown!r}, expected an integer >= 0")
    if len(text) > 18:  # held in int64
        raise FormatError(f"{where}: {column} {text} is out of range")
    return int(text)
