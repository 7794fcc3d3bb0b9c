"""Helpers for line-oriented numeric files (CSV tables, TUM trajectories)."""

from __future__ import annotations

import math
import os

import numpy as np

from semslam.errors import SemslamError
from semslam.geometry import FloatArray


def parse_number(
    token: str,
    where: str,
    name: str,
    error: type[SemslamError],
    within: float = math.inf,
    unit: str = "",
) -> float:
    """A finite float from ``token``, at most ``within`` in magnitude (``unit`` for messages).

    Raises:
        error: ``"<where>: <name> is not a number ('abc')"``, ``"<where>: <name> is NaN"`` or
            ``"<where>: x 1e+300 m is out of range (|x| <= 1e+06 m)"``.
    """
    try:
        value = float(token)
    except ValueError:
        shown = token.strip() or "empty"
        raise error(f"{where}: {name} is not a number ({shown!r})") from None
    if math.isnan(value):
        raise error(f"{where}: {name} is NaN")
    if math.isinf(value):
        raise error(f"{where}: {name} is infinite")
    if abs(value) > within:
        u = f" {unit}" if unit else ""
        raise error(f"{where}: {name} {value:g}{u} is out of range (|{name}| <= {within:g}{u})")
    return value


def check_time_order(
    previous: float | None, t: float, where: str, error: type[SemslamError],
    microseconds: bool = False,
) -> None:
    """Refuse a time stamp that does not come strictly after ``previous``; with
    ``microseconds``, also one that repeats ``previous`` to the microsecond (a frame's time:
    the trajectories written per frame hold times to the microsecond, as TUM files do).

    Raises:
        error: ``"<where>: time goes backwards (12.300 after 12.400)"``,
            ``"<where>: time repeats (12.400)"`` or ``"<where>: time 12.400000 repeats
            the previous frame's to the microsecond"``.
    """
    if previous is None:
        return
    if t > previous:
        if microseconds and f"{t:.6f}" == f"{previous:.6f}":
            raise error(f"{where}: time {t:.6f} repeats the previous frame's to the "
                        "microsecond (frame times are written to the microsecond)")
        return
    if t == previous:
        raise error(f"{where}: time repeats ({format_time(t)})")
    a, b = _distinct(t, previous)
    raise error(f"{where}: time goes backwards ({a} after {b})")


def format_time(t: float) -> str:
    """A time stamp in seconds with three decimals (in ``%g`` form from 1e12 s on)."""
    return f"{t:.3f}" if abs(t) < 1e12 else f"{t:g}"


def _distinct(a: float, b: float) -> tuple[str, str]:
    """``a`` and ``b`` printed with the fewest decimals (at least 3) that tell them apart."""
    if max(abs(a), abs(b)) >= 1e12:  # no decimals to count: %g, then every digit
        return (f"{a:g}", f"{b:g}") if f"{a:g}" != f"{b:g}" else (repr(a), repr(b))
    for decimals in range(3, 10):
        sa, sb = f"{a:.{decimals}f}", f"{b:.{decimals}f}"
        if sa != sb:
            return sa, sb
    return repr(a), repr(b)


def check_times(
    t: FloatArray, path: str | os.PathLike[str], error: type[SemslamError], what: str = "row",
    within: float = math.inf, microseconds: bool = False,
) -> None:
    """Refuse non-finite or not strictly increasing times before writing ``path``; also
    times beyond ``within`` seconds in magnitude, and with ``microseconds`` times repeating
    the previous one to the microsecond (what the readers refuse, see
    :func:`check_time_order`).

    Raises:
        error: ``"<path>: row 3: time goes backwards (...)"`` (rows counted from 0).
    """
    name = os.fspath(path)
    check_finite_columns({"time": t}, path, error, what)
    beyond = np.flatnonzero(np.abs(t) > within)
    if beyond.size:
        k = int(beyond[0])
        raise error(f"{name}: {what} {k}: t {t[k]:g} s is out of range (|t| <= {within:g} s)")
    stalls = np.diff(t) <= 0
    if microseconds and len(t) > 1:
        stamps = np.char.mod("%.6f", t)
        stalls |= stamps[1:] == stamps[:-1]
    if stalls.any():
        i = int(np.argmax(stalls)) + 1
        check_time_order(float(t[i - 1]), float(t[i]), f"{name}: {what} {i}", error,
                         microseconds)


def check_finite_columns(
    columns: dict[str, FloatArray],
    path: str | os.PathLike[str],
    error: type[SemslamError],
    what: str = "row",
) -> None:
    """Refuse NaN or infinity in any column before writing ``path``."""
    for name, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise error(f"{os.fspath(path)}: {what} {bad[0]}: {name} is {values[bad[0]]}")
