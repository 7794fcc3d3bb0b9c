"""odometry.csv: wheel speed and gyro yaw rate, ``t,speed,yaw_rate`` (s, m/s, rad/s)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from semslam.geometry import FloatArray
from semslam.io._csv import check_columns, check_header, read_table
from semslam.io._rows import check_finite_columns, check_time_order, check_times, parse_number
from semslam.io.atomic import atomic_write_text
from semslam.io.errors import DriveFormatError

ODOMETRY_HEADER = ["t", "speed", "yaw_rate"]


@dataclass(frozen=True, eq=False)
class Odometry:
    """Odometry samples.

    Attributes:
        t: (N,) strictly increasing times, seconds.
        speed: (N,) forward speed of the vehicle centre, m/s.
        yaw_rate: (N,) yaw rate, rad/s, counter-clockwise positive.
    """

    t: FloatArray
    speed: FloatArray
    yaw_rate: FloatArray

    def __len__(self) -> int:
        return int(np.asarray(self.t).shape[0])


def write_odometry(path: str | os.PathLike[str], odometry: Odometry) -> None:
    """Write odometry.csv atomically, every number at full precision.

    Raises:
        DriveFormatError: arrays of different lengths, NaN/infinity, or time not
            strictly increasing; nothing is written.
    """
    columns = {
        "t": np.asarray(odometry.t, dtype=float),
        "speed": np.asarray(odometry.speed, dtype=float),
        "yaw_rate": np.asarray(odometry.yaw_rate, dtype=float),
    }
    shapes = {a.shape for a in columns.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 1:
        raise DriveFormatError(
            f"{os.fspath(path)}: t, speed, yaw_rate must be (N,) arrays of one length, "
            f"got shapes {[a.shape for a in columns.values()]}"
        )
    check_finite_columns(columns, path, DriveFormatError, "sample")
    check_times(columns["t"], path, DriveFormatError, "sample")
    lines = [",".join(ODOMETRY_HEADER)]
    lines += [
        f"{float(t)!r},{float(v)!r},{float(w)!r}"
        for t, v, w in zip(columns["t"], columns["speed"], columns["yaw_rate"], strict=True)
    ]
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_odometry(path: str | os.PathLike[str]) -> Odometry:
    """Read odometry.csv.

    Raises:
        DriveFormatError: missing or empty file, wrong header, wrong column
            count, a non-number, NaN/infinity, time not strictly increasing;
            e.g. ``odometry.csv line 17: speed is NaN``.
    """
    name = os.fspath(path)
    header, rows = read_table(path, DriveFormatError)
    check_header(header, ODOMETRY_HEADER, path, DriveFormatError)
    data = np.empty((len(rows), 3))
    previous: float | None = None
    for i, (lineno, fields) in enumerate(rows):
        where = f"{name} line {lineno}"
        check_columns(fields, ODOMETRY_HEADER, where, DriveFormatError)
        for j, column in enumerate(ODOMETRY_HEADER):
            data[i, j] = parse_number(fields[j], where, column, DriveFormatError)
        check_time_order(previous, data[i, 0], where, DriveFormatError)
        previous = data[i, 0]
    return Odometry(t=data[:, 0].copy(), speed=data[:, 1].copy(), yaw_rate=data[:, 2].copy())
