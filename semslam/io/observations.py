"""Per-frame observations as JSON Lines: one :class:`FrameObservations` per line.

Everything is in the vehicle frame (x forward, y left), metres and radians::

    {"t": 12.3,
     "slots": [{"corners": [[x, y] x4], "kind", "label", "label_confidence",
                "confidence", "corner_sigma",
                "corner_sigma_own" [4], "corner_sigma_shared" [4] (both optional)}],
     "tags": [{"family", "id", "size", "x", "y", "yaw", "height", "covariance" [3][3]}],
     "markings": [{"a": [x, y], "b": [x, y], "width", "confidence", "sigma" (optional)}]}

Missing ``slots``/``tags``/``markings`` lists mean none were seen. Times
strictly increase from line to line. Points, sigmas and widths are within
:data:`MAX_RANGE` of the vehicle, tag covariances symmetric positive
semi-definite.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable
from typing import Any

import numpy as np

from semslam.errors import FormatError
from semslam.geometry import FloatArray
from semslam.io._fields import Field, check_covariance
from semslam.io._json import (
    find_non_finite,
    first_line,
    loads,
    may_hold_non_finite,
    non_finite_message,
)
from semslam.io._rows import check_time_order
from semslam.io._tag import tag_fields, tag_to_dict
from semslam.io._text import read_text, text_lines
from semslam.io.atomic import atomic_write_text
from semslam.types import (
    FrameObservations,
    MarkingObservation,
    SlotKind,
    SlotObservation,
    TagObservation,
)

MAX_RANGE = 1000.0
"""Largest ``|x|``, ``|y|``, sigma or width of an observation, metres. The sensors see tens of
metres; beyond a kilometre the file is broken, and the filters' squares would overflow."""


def frame_observations_to_dict(frame: FrameObservations) -> dict[str, Any]:
    """The JSON object of one frame (plain Python values)."""
    return {
        "t": float(frame.t),
        "slots": [_slot_to_dict(s) for s in frame.slots],
        "tags": [_tag_to_dict(s) for s in frame.tags],
        "markings": [_marking_to_dict(m) for m in frame.markings],
    }


def frame_observations_from_dict(
    document: Any, source: str = "<dict>", scan_non_finite: bool = True
) -> FrameObservations:
    """One frame from its JSON object.

    Args:
        document: the parsed JSON object.
        source: where it came from, for messages (``"obs.jsonl line 4"``).
        scan_non_finite: look for NaN/infinity anywhere in ``document`` first (so the
            message names it whatever else is wrong); False when its text was seen to
            hold none (:func:`~semslam.io._json.may_hold_non_finite`).

    Raises:
        FormatError: a missing or mistyped field, NaN/infinity, a value out of
            range; the message names ``source`` and the field (``slots/0/corners``).
    """
    bad = find_non_finite(document) if scan_non_finite else None
    if bad is not None:
        raise FormatError(f"{source}: {non_finite_message(*bad)}")
    root = Field(document, source, FormatError)
    root.obj()
    return FrameObservations(
        t=root["t"].number(),
        slots=tuple(_slot_from_field(f) for f in _list(root, "slots")),
        tags=tuple(_tag_from_field(f) for f in _list(root, "tags")),
        markings=tuple(_marking_from_field(f) for f in _list(root, "markings")),
    )


def write_observations(path: str | os.PathLike[str], frames: Iterable[FrameObservations]) -> None:
    """Write frames as JSON Lines, atomically.

    Raises:
        FormatError: a frame would not read back (NaN, a wrong shape, a value
            out of range) or times do not strictly increase; nothing is written.
    """
    name = os.fspath(path)
    lines: list[str] = []
    previous: float | None = None
    for i, frame in enumerate(frames):
        document = frame_observations_to_dict(frame)
        frame_observations_from_dict(document, f"{name}: frame {i}")  # would it read back?
        check_time_order(previous, document["t"], f"{name}: frame {i}", FormatError,
                         microseconds=True)
        previous = document["t"]
        lines.append(json.dumps(document, separators=(",", ":"), allow_nan=False))
    atomic_write_text(path, "".join(line + "\n" for line in lines))


def read_observations(path: str | os.PathLike[str]) -> list[FrameObservations]:
    """Read a JSON Lines file of frames (blank lines are skipped; an empty file is no frames).

    Raises:
        FormatError: missing file, a line that is not JSON (e.g. a truncated
            last line), a bad field, or time not strictly increasing; the
            message names the file, the line and the field.
    """
    name = os.fspath(path)
    frames: list[FrameObservations] = []
    for lineno, line in enumerate(text_lines(read_text(path, FormatError)), start=1):
        if not line.strip():
            continue
        where = f"{name} line {lineno}"
        try:
            document = loads(line)
        except json.JSONDecodeError as exc:
            raise FormatError(f"{where}: not valid JSON at column {exc.colno}: {exc.msg}") from None
        except (ValueError, RecursionError) as exc:
            raise FormatError(f"{where}: not valid JSON: {first_line(exc)}") from None
        frame = frame_observations_from_dict(document, where, may_hold_non_finite(line))
        check_time_order(frames[-1].t if frames else None, frame.t, where, FormatError,
                         microseconds=True)
        frames.append(frame)
    return frames


# --------------------------------------------------------------------------- elements


def _list(root: Field, key: str) -> list[Field]:
    field = root.get(key)
    return [] if field is None else field.items()


def _slot_to_dict(slot: SlotObservation) -> dict[str, Any]:
    out = {
        "corners": np.asarray(slot.vCorners, dtype=float).tolist(),
        "kind": SlotKind(slot.kind).value,
        "label": slot.label,
        "label_confidence": float(slot.label_confidence),
        "confidence": float(slot.confidence),
        "corner_sigma": float(slot.corner_sigma),
    }
    for key in ("corner_sigma_own", "corner_sigma_shared"):
        sigmas = getattr(slot, key)
        if sigmas is not None:
            out[key] = [float(v) for v in sigmas]
    return out


MIN_SLOT_SIDE = 0.05
"""m: a slot whose side is shorter is no slot (its rectangle has no direction to fit)."""


def shortest_side(corners: FloatArray) -> float:
    """The shortest side of the quadrilateral of ``corners`` ((4, 2), in order), m (in
    floats: it runs for every slot a drive's observation file holds)."""
    points = corners.tolist()
    return min(math.hypot(x1 - x0, y1 - y0)
               for (x0, y0), (x1, y1) in zip(points, points[1:] + points[:1], strict=True))


def _slot_from_field(f: Field) -> SlotObservation:
    label, own, shared = f.get("label"), f.get("corner_sigma_own"), f.get("corner_sigma_shared")
    corners = f["corners"].array((4, 2), within=MAX_RANGE)
    side = shortest_side(corners)
    if side < MIN_SLOT_SIDE:
        f["corners"].fail(f"a side of {side:.3g} m: corners must be at least "
                          f"{MIN_SLOT_SIDE} m apart")
    return SlotObservation(
        vCorners=corners,
        kind=f["kind"].choice(SlotKind),
        label=None if label is None else label.string(),
        label_confidence=f["label_confidence"].number(0.0, 1.0),
        confidence=f["confidence"].number(0.0, 1.0),
        corner_sigma=f["corner_sigma"].number(0.0, MAX_RANGE),
        corner_sigma_own=_corner_sigmas(own),
        corner_sigma_shared=_corner_sigmas(shared),
    )


def _corner_sigmas(f: Field | None) -> tuple[float, float, float, float] | None:
    """An optional list of four per-corner sigmas (m)."""
    if f is None:
        return None
    sigmas = f.array((4,), within=MAX_RANGE)
    if np.any(sigmas < 0):
        f.fail("a sigma below 0")
    return tuple(float(v) for v in sigmas)


def _tag_to_dict(tag: TagObservation) -> dict[str, Any]:
    return tag_to_dict(tag.family, tag.tag_id, tag.size, tag.vTt, tag.height, tag.covariance)


def _tag_from_field(f: Field) -> TagObservation:
    parts = tag_fields(f, reach=MAX_RANGE)
    check_covariance(f["covariance"], parts["covariance"], MAX_RANGE**2)
    return TagObservation(vTt=parts.pop("pose"), **parts)


def _marking_to_dict(marking: MarkingObservation) -> dict[str, Any]:
    out = {
        "a": np.asarray(marking.vA, dtype=float).tolist(),
        "b": np.asarray(marking.vB, dtype=float).tolist(),
        "width": float(marking.width),
        "confidence": float(marking.confidence),
    }
    if marking.sigma is not None:
        out["sigma"] = float(marking.sigma)
    return out


def _marking_from_field(f: Field) -> MarkingObservation:
    sigma = f.get("sigma")
    return MarkingObservation(
        vA=f["a"].array((2,), within=MAX_RANGE),
        vB=f["b"].array((2,), within=MAX_RANGE),
        width=f["width"].number(maximum=MAX_RANGE, positive=True),
        confidence=f["confidence"].number(0.0, 1.0),
        sigma=None if sigma is None else sigma.number(maximum=MAX_RANGE, positive=True),
    )
