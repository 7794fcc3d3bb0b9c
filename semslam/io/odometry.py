"""odometry.csv: wheel speed and gyro yaw rate, ``t,speed,yaw_rate`` (s, m/s, rad/s)."""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from semslam.errors import DriveError
from semslam.geometry import FloatArray
from semslam.io._csv import check_columns, check_header, read_table
from semslam.io._rows import (
    check_finite_columns,
    check_time_order,
    check_times,
    format_time,
    parse_number,
)
from semslam.io.atomic import atomic_write_text
from semslam.io.errors import DriveFormatError
from semslam.io.tum import MAX_TIME

ODOMETRY_HEADER = ["t", "speed", "yaw_rate"]

MAX_SPEED = 100.0
"""Largest believable ``|speed|``, m/s (360 km/h: no car in a garage, nor anywhere)."""

MAX_YAW_RATE = 20.0
"""Largest believable ``|yaw_rate|``, rad/s (over 3 turns a second: a broken gyro)."""

_LIMITS = {"speed": (MAX_SPEED, "m/s"), "yaw_rate": (MAX_YAW_RATE, "rad/s")}


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
        DriveFormatError: arrays of different lengths, NaN/infinity, an impossible
            speed or yaw rate or a time beyond ``MAX_TIME`` (see :func:`read_odometry`),
            time not strictly increasing, a gap in the samples or samples faster than
            :data:`MAX_RATE`; nothing is written.
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
    check_times(columns["t"], path, DriveFormatError, "sample", within=MAX_TIME)
    check_gaps(columns["t"], lambda k: f"{os.fspath(path)}: sample {k}")
    check_rate(columns["t"], os.fspath(path))
    for column, (limit, _unit) in _LIMITS.items():
        over = np.flatnonzero(np.abs(columns[column]) > limit)
        if over.size:
            i = int(over[0])
            _refuse(f"{os.fspath(path)}: sample {i}", column, float(columns[column][i]))
    lines = [",".join(ODOMETRY_HEADER)]
    lines += [
        f"{float(t)!r},{float(v)!r},{float(w)!r}"
        for t, v, w in zip(columns["t"], columns["speed"], columns["yaw_rate"], strict=True)
    ]
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_odometry(path: str | os.PathLike[str]) -> Odometry:
    """Read odometry.csv.

    Physically impossible values are refused: ``|speed|`` above :data:`MAX_SPEED`
    (100 m/s) or ``|yaw_rate|`` above :data:`MAX_YAW_RATE` (20 rad/s); so is a time beyond
    :data:`semslam.io.tum.MAX_TIME` (1e11 s), which no trajectory written from it could hold.

    Raises:
        DriveFormatError: missing or empty file, wrong header, wrong column
            count, a non-number, NaN/infinity, an impossible speed or yaw rate,
            time not strictly increasing, a gap in the samples (more than
            :data:`MAX_GAP_PERIODS` median intervals and more than :data:`MIN_GAP_S`) or
            samples faster than :data:`MAX_RATE` (2000 Hz, their median interval);
            e.g. ``odometry.csv line 17: speed is NaN``.
    """
    name = os.fspath(path)
    header, rows = read_table(path, DriveFormatError)
    check_header(header, ODOMETRY_HEADER, path, DriveFormatError)
    data = np.empty((len(rows), 3))
    bounds = [(MAX_TIME, "s"), (math.inf, ""), (math.inf, "")]  # parse_number's within, unit
    previous: float | None = None
    for i, (lineno, fields) in enumerate(rows):
        where = f"{name} line {lineno}"
        check_columns(fields, ODOMETRY_HEADER, where, DriveFormatError)
        for j, (column, (within, unit)) in enumerate(zip(ODOMETRY_HEADER, bounds, strict=True)):
            data[i, j] = parse_number(fields[j], where, column, DriveFormatError, within, unit)
            if column in _LIMITS and abs(data[i, j]) > _LIMITS[column][0]:
                _refuse(where, column, float(data[i, j]))
        check_time_order(previous, data[i, 0], where, DriveFormatError)
        previous = data[i, 0]
    check_gaps(data[:, 0], lambda k: f"{name} line {rows[k][0]}")
    check_rate(data[:, 0], name)
    return Odometry(t=data[:, 0].copy(), speed=data[:, 1].copy(), yaw_rate=data[:, 2].copy())


MAX_GAP_PERIODS = 10.0
MIN_GAP_S = 1.0
"""A gap in odometry.csv longer than both (median intervals, seconds) is refused: dead
reckoning across it would be a guess, and the frames inside it would be placed wrong."""


def check_gaps(t: FloatArray, where: Callable[[int], str]) -> None:
    """Refuse a gap in the times ``t`` (s): :data:`MAX_GAP_PERIODS` median intervals and
    :data:`MIN_GAP_S` both exceeded; ``where(k)`` names sample ``k`` (``odometry.csv line
    17``)."""
    if len(t) < 3:
        return
    dt = np.diff(t)
    period = float(np.median(dt))
    gaps = np.flatnonzero(dt > max(MAX_GAP_PERIODS * period, MIN_GAP_S))
    if len(gaps):
        k = int(gaps[0]) + 1
        raise DriveFormatError(
            f"{where(k)}: {dt[k - 1]:.3f} s since the sample before (the median "
            f"interval is {period:.3f} s): odometry is missing there"
        )


MAX_RATE = 2000.0
"""Highest odometry rate read, Hz (a median interval under 0.5 ms is refused: twice the
simulator's highest ``odometry_rate``, room for a recording's jitter): the localizer predicts
and updates its filter at every sample (80 us each), so a 94 s drive sampled at 50 kHz took
over 2 minutes to localize."""


def check_rate(t: FloatArray, name: str) -> None:
    """Refuse odometry times ``t`` (s) sampled faster than :data:`MAX_RATE` (their median
    interval); ``name`` is the file."""
    if len(t) < 2:
        return
    period = float(np.median(np.diff(t)))
    if period < 1.0 / MAX_RATE:
        raise DriveFormatError(
            f"{name}: samples {period * 1e3:.3g} ms apart (the median interval), over "
            f"{MAX_RATE:g} Hz: resample the odometry to {MAX_RATE:g} Hz or less"
        )


def _refuse(where: str, column: str, value: float) -> None:
    limit, unit = _LIMITS[column]
    raise DriveFormatError(
        f"{where}: {column} {value:g} {unit} is impossible (|{column}| must be <= {limit:g} {unit})"
    )


def odometry_span(odometry_t: FloatArray) -> tuple[float, float, float]:
    """``(first, last, period)`` of odometry sample times, the period being the median
    interval (0 for a single sample); for :func:`check_covered`. Without samples the
    span is unbounded (nothing to check against).
    """
    times = np.asarray(odometry_t, dtype=float).reshape(-1)
    if times.size == 0:
        return -math.inf, math.inf, 0.0
    period = float(np.median(np.diff(times))) if times.size > 1 else 0.0
    return float(times[0]), float(times[-1]), period


def check_covered(
    t: float, span: tuple[float, float, float], what: str = "observations", start: bool = False
) -> None:
    """Refuse a time the odometry (its :func:`odometry_span`) does not cover.

    A time more than one odometry period after the last sample is refused (odometry.csv
    cut short); with ``start``, so is a time before the first sample.

    Raises:
        DriveError: ``"observations reach 91.900 s, after the odometry (ends at 9.980 s)..."``.
    """
    first, last, period = span
    if t > last + period + 1e-6:
        raise DriveError(
            f"{what} reach {format_time(t)} s, after the odometry (ends at {format_time(last)} s): "
            "is odometry.csv cut short?"
        )
    if start and t < first - 1e-6:
        raise DriveError(
            f"{what} start at {format_time(t)} s, before the odometry ({format_time(first)} s)"
        )
