"""The map file: versioned JSON validated against ``semslam/schemas/map.schema.json``.

Layout (map frame, metres and radians)::

    {"format": "semslam-map", "version": 1,
     "metadata": {"generator": ..., "version": ..., "created": ..., "source": ...,
                  "statistics": {...}},
     "slots": [{"id", "label", "label_confidence", "corners" [4][2],
                "corner_covariances" [4][2][2], "kind", "observations",
                optional "heading_variance" (rad^2)}],
     "tags": [{"family", "id", "size", "x", "y", "yaw", "height", "covariance" [3][3]}],
     "markings": [{"a" [2], "b" [2], "width", optional "sigma" (m), optional
                   "across_covariance" [2][2] (m^2, the offsets at a and b)}]}

Every load checks, in order: JSON syntax, finite numbers, the format
string, the version, the schema, unique slot IDs, then the values: every
coordinate within :data:`MAX_COORDINATE` of the origin, covariances symmetric
positive semi-definite with no entry beyond :data:`MAX_VARIANCE`, markings of
non-zero length, each tag (family, id) once. Each failure is a
:class:`~semslam.errors.MapError` naming the file and the field
(``map.json: slots/0/corner_covariances/0: not positive semi-definite``).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from semslam.errors import MapError
from semslam.io._fields import Field, check_covariance, check_covariances, check_within
from semslam.io._json import (
    dumps_pretty,
    find_non_finite,
    may_hold_non_finite,
    non_finite_message,
    parse_json,
    to_jsonable,
)
from semslam.io._schema import validate
from semslam.io._tag import tag_fields, tag_to_dict
from semslam.io._text import read_text
from semslam.io.atomic import atomic_write_text
from semslam.io.observations import MIN_SLOT_SIDE, shortest_side
from semslam.types import Marking, SemanticMap, Slot, SlotKind, Tag

MAP_FORMAT = "semslam-map"
MAP_VERSION = 1

MAX_COORDINATE = 1e6
"""Largest ``|x|`` or ``|y|`` of a map coordinate, metres (1000 km: beyond it, a broken file)."""

MAX_VARIANCE = MAX_COORDINATE**2
"""Largest ``|entry|`` of a covariance (m^2, rad^2 or m rad): a sigma of 1000 km. Beyond it a
file is broken, and the filter's arithmetic would overflow."""


def map_to_dict(semantic_map: SemanticMap) -> dict[str, Any]:
    """The JSON document of a map (plain Python values; numpy converted).

    Raises:
        TypeError: the metadata holds a value JSON cannot store (a bug in the caller).
    """
    return {
        "format": MAP_FORMAT,
        "version": MAP_VERSION,
        "metadata": to_jsonable(dict(semantic_map.metadata), "metadata"),
        "slots": [_slot_to_dict(s) for s in semantic_map.slots],
        "tags": [_tag_to_dict(t) for t in semantic_map.tags],
        "markings": [_marking_to_dict(m) for m in semantic_map.markings],
    }


def map_from_dict(
    document: Any, source: str = "<dict>", scan_non_finite: bool = True
) -> SemanticMap:
    """A map from its JSON document, fully checked.

    Args:
        document: the parsed JSON.
        source: name used in error messages (the file path).
        scan_non_finite: look for NaN/infinity anywhere in ``document`` first (so the
            message names it whatever else is wrong); False when its text was seen to
            hold none (:func:`~semslam.io._json.may_hold_non_finite`).

    Raises:
        MapError: wrong format or version, a schema violation, NaN/infinity,
            duplicate slot IDs or tags, a coordinate beyond :data:`MAX_COORDINATE`, a
            covariance that is not symmetric positive semi-definite, or a zero-length
            marking; the message names ``source`` and the field.
    """
    check_map_document(document, source, scan_non_finite)
    root = Field(document, source, MapError)
    slots = tuple(_slot_from_field(f) for f in root["slots"].items())
    seen: dict[int, int] = {}
    for i, slot in enumerate(slots):
        if slot.id in seen:
            raise MapError(
                f"{source}: slots/{i}/id: duplicate id {slot.id} (also slots/{seen[slot.id]})"
            )
        seen[slot.id] = i
    tags = tuple(_tag_from_field(f) for f in root["tags"].items())
    first_tag: dict[tuple[str, int], int] = {}
    for i, tag in enumerate(tags):
        key = (str(tag.family), int(tag.tag_id))
        if key in first_tag:
            raise MapError(
                f"{source}: tags/{i}: duplicate tag {key[0]} id {key[1]} "
                f"(also tags/{first_tag[key]})"
            )
        first_tag[key] = i
    return SemanticMap(
        slots=slots,
        tags=tags,
        markings=tuple(_marking_from_field(f) for f in root["markings"].items()),
        metadata=dict(document["metadata"]),
    )


def check_map_document(
    document: Any, source: str = "<dict>", scan_non_finite: bool = True
) -> None:
    """Check a map document without building the map (see :func:`map_from_dict`)."""
    if not isinstance(document, dict):
        raise MapError(f"{source}: expected a JSON object at the top level")
    # the metadata is scanned whatever the text held: a float literal of over 308 digits
    # reads as infinity without a token may_hold_non_finite looks for, and no typed field
    # checks the free-form metadata
    bad = find_non_finite(document if scan_non_finite else document.get("metadata"),
                          "" if scan_non_finite else "metadata")
    if bad is not None:
        raise MapError(f"{source}: {non_finite_message(*bad)}")
    fmt = document.get("format")
    if fmt != MAP_FORMAT:
        got = "missing" if fmt is None else repr(fmt)
        raise MapError(f"{source}: format is {got}, expected '{MAP_FORMAT}'")
    version = document.get("version")
    if isinstance(version, int) and not isinstance(version, bool) and version > MAP_VERSION:
        raise MapError(
            f"{source}: version {version} is newer than this semslam reads ({MAP_VERSION})"
        )
    validate(document, "map", source, MapError)


def save_map(path: str | os.PathLike[str], semantic_map: SemanticMap) -> None:
    """Write a map as pretty JSON, atomically, after checking it against the schema.

    Raises:
        MapError: the map would not load back (NaN, bad shapes...); nothing is written.
    """
    document = map_to_dict(semantic_map)
    map_from_dict(document, os.fspath(path))
    atomic_write_text(path, dumps_pretty(document))


def load_map(path: str | os.PathLike[str]) -> SemanticMap:
    """Read and check a map file.

    Raises:
        MapError: missing or unreadable file, broken JSON, or any problem
            listed in :func:`map_from_dict`.
    """
    source = os.fspath(path)
    text = read_text(path, MapError)
    return map_from_dict(parse_json(text, source, MapError), source, may_hold_non_finite(text))


# --------------------------------------------------------------------------- elements


def _slot_to_dict(slot: Slot) -> dict[str, Any]:
    return {
        "id": int(slot.id),
        "label": slot.label,
        "label_confidence": float(slot.label_confidence),
        "corners": np.asarray(slot.corners, dtype=float).tolist(),
        "corner_covariances": np.asarray(slot.corner_covariances, dtype=float).tolist(),
        "kind": SlotKind(slot.kind).value,
        "observations": int(slot.observations),
        **({} if slot.heading_variance is None else
           {"heading_variance": float(slot.heading_variance)}),
    }


def _slot_from_field(f: Field) -> Slot:
    corners = f["corners"].array((4, 2), within=MAX_COORDINATE)
    side = shortest_side(corners)
    if side < MIN_SLOT_SIDE:  # as a sighting's: a slot no wider than paint is no slot
        f["corners"].fail(f"a side of {side:.3g} m: corners must be at least "
                          f"{MIN_SLOT_SIDE} m apart")
    covariances = f["corner_covariances"].array((4, 2, 2))
    check_covariances(f["corner_covariances"], covariances, MAX_VARIANCE)
    return Slot(
        id=f["id"].integer(),
        label=f["label"].optional_string(),
        label_confidence=f["label_confidence"].number(0.0, 1.0),
        corners=corners,
        corner_covariances=covariances,
        kind=f["kind"].choice(SlotKind),
        observations=f["observations"].integer(0),
        heading_variance=(
            None if (h := f.get("heading_variance")) is None else h.number(0.0, MAX_VARIANCE)
        ),
    )


def _tag_to_dict(tag: Tag) -> dict[str, Any]:
    return tag_to_dict(tag.family, tag.tag_id, tag.size, tag.mTt, tag.height, tag.covariance)


def _tag_from_field(f: Field) -> Tag:
    parts = tag_fields(f)
    check_within(f, parts["pose"][:2], MAX_COORDINATE)
    check_covariance(f["covariance"], parts["covariance"], MAX_VARIANCE)
    return Tag(mTt=parts.pop("pose"), **parts)


def _marking_to_dict(marking: Marking) -> dict[str, Any]:
    return {
        "a": np.asarray(marking.a, dtype=float).tolist(),
        "b": np.asarray(marking.b, dtype=float).tolist(),
        "width": float(marking.width),
        **({} if marking.sigma is None else {"sigma": float(marking.sigma)}),
        **({} if marking.across_covariance is None else {
            "across_covariance": np.asarray(marking.across_covariance, dtype=float).tolist()}),
    }


def _marking_from_field(f: Field) -> Marking:
    a, b = f["a"].array((2,), within=MAX_COORDINATE), f["b"].array((2,), within=MAX_COORDINATE)
    if np.array_equal(a, b):
        f.fail("zero-length marking (a and b are the same point)")
    sigma = None if (v := f.get("sigma")) is None else v.number(0.0, MAX_COORDINATE)
    across = None
    if (v := f.get("across_covariance")) is not None:
        across = v.array((2, 2))
        check_covariance(v, across, MAX_VARIANCE)
    return Marking(a=a, b=b, width=f["width"].number(positive=True), sigma=sigma,
                   across_covariance=across)
