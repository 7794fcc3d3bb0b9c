"""JSON helpers shared by the readers and writers.

Python's ``json`` accepts ``NaN`` and ``Infinity``, which are not JSON;
:func:`parse_json` keeps them long enough for :func:`find_non_finite` to name
the field, and every reader then refuses them. It also keeps the last of two
equal keys in one object without a word; :func:`loads` refuses them (a key
written twice is an edit gone wrong, and which one counts is a guess).
"""

from __future__ import annotations

import datetime
import json
import math
import os
import re
import sys
from collections.abc import Iterator
from enum import Enum
from typing import Any

import numpy as np

from semslam.errors import SemslamError


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj = dict(pairs)
    if len(obj) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise ValueError(f"duplicate key {key!r} in one object")
            seen.add(key)
    return obj


_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")


def loads(text: str) -> Any:
    """``json.loads`` that refuses an object with a key twice, or a string holding a lone
    UTF-16 surrogate (``"\\ud800"``: no Unicode text; no UTF-8 writer takes it), with a
    ValueError naming the key or the string's pointer."""
    value = json.loads(text, object_pairs_hook=_unique_keys)
    if _SURROGATE_ESCAPE.search(text) is not None:  # only escapes make one
        pointer = _lone_surrogate(value)
        if pointer is not None:
            raise ValueError(f"{pointer or '(top level)'}: a string holds a lone surrogate "
                             "(a \\ud800-\\udfff escape outside a pair), not Unicode text")
    return value


def _lone_surrogate(value: Any) -> str | None:
    """The pointer of the first string or key in ``value`` that is not valid Unicode."""
    stack: list[tuple[str, Any]] = [("", value)]
    while stack:
        path, item = stack.pop()
        if isinstance(item, str):
            if not item.isascii() and not _encodable(item):
                return path
        elif isinstance(item, dict):
            for key in item:
                if not key.isascii() and not _encodable(key):
                    return _join(path, key.encode("utf-8", "replace").decode())
            stack.extend((_join(path, k), v) for k, v in reversed(list(item.items())))
        elif isinstance(item, list):
            stack.extend((_join(path, i), v) for i, v in reversed(list(enumerate(item))))
    return None


def _encodable(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def parse_json(text: str, source: str, error: type[SemslamError]) -> Any:
    """Parse ``text``; a syntax error becomes ``error`` naming ``source``, line and column
    (a key twice in one object, ``error`` naming the key)."""
    try:
        return loads(text)
    except json.JSONDecodeError as exc:
        if not text.strip():
            raise error(f"{source}: empty file, expected JSON") from None
        stripped = text.rstrip()
        first = text.lstrip()[:1]
        if first not in ("{", "["):  # another kind of file given where JSON belongs
            hint = f" (it starts with {first!r}: not a JSON document)"
        elif exc.pos >= len(stripped) or stripped[-1] not in "}]":
            hint = " (the file looks truncated)"
        else:
            hint = ""
        raise error(
            f"{source}: not valid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}"
            + hint
        ) from None
    except RecursionError:
        raise error(f"{source}: not valid JSON: arrays or objects nested too deeply") from None
    except ValueError as exc:  # e.g. an integer with 5000 digits
        if "int_max_str_digits" in str(exc) or "integer string conversion" in str(exc):
            raise error(f"{source}: not valid JSON: an integer of more than "
                        f"{sys.get_int_max_str_digits():,} digits") from None
        raise error(f"{source}: not valid JSON: {first_line(exc)}") from None


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message, for one-line error messages."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def find_non_finite(value: Any, pointer: str = "") -> tuple[str, float] | None:
    """The first NaN or infinite number in a parsed JSON value.

    Returns:
        ``(pointer, number)`` with a JSON-pointer-like path such as
        ``slots/3/corners/0/1`` (no leading slash; empty for the top level),
        or None when every number is finite.
    """
    for path, item in _walk(value, pointer):
        if isinstance(item, float) and not math.isfinite(item):
            return path, item
    return None


_BIG_EXPONENT = re.compile(r"[eE]\+?\d{3}")


def may_hold_non_finite(text: str) -> bool:
    """Whether ``json.loads(text)`` can give a NaN or an infinite number that
    :func:`find_non_finite` should name.

    Python's ``json`` gives them for the tokens ``NaN``, ``Infinity`` and
    ``-Infinity`` and for floats beyond the double range: an exponent of three
    digits, or a plain mantissa of over 308 digits. That last form is not looked
    for (the search costs more than the parse); the typed readers refuse any
    non-finite number they read (``Field.number``, ``Field.array``). False
    positives (such a word inside a string) only cost the walk.
    """
    return "NaN" in text or "Infinity" in text or _BIG_EXPONENT.search(text) is not None


def non_finite_message(pointer: str, number: float) -> str:
    """``"slots/3/corners/0/1: NaN is not allowed"``."""
    name = "NaN" if math.isnan(number) else ("Infinity" if number > 0 else "-Infinity")
    return f"{pointer or '(top level)'}: {name} is not allowed"


def _walk(value: Any, pointer: str) -> Iterator[tuple[str, Any]]:
    stack = [(pointer, value)]
    while stack:
        path, item = stack.pop()
        if isinstance(item, dict):
            stack.extend((_join(path, k), v) for k, v in reversed(list(item.items())))
        elif isinstance(item, list | tuple):
            stack.extend((_join(path, i), v) for i, v in reversed(list(enumerate(item))))
        else:
            yield path, item


def _join(pointer: str, key: object) -> str:
    return f"{pointer}/{key}" if pointer else str(key)


def to_jsonable(value: Any, pointer: str = "") -> Any:
    """Plain JSON values (dict, list, str, int, float, bool, None) from values that
    may hold numpy scalars and arrays, tuples, enums, paths, dates and times
    (ISO 8601); dict keys become strings.

    Raises:
        TypeError: a value of another type, naming its pointer (``statistics/when``).
    """
    if value is None or type(value) in (str, int, float, bool):
        return value
    if isinstance(value, Enum):
        return to_jsonable(value.value, pointer)
    if isinstance(value, np.generic):
        return to_jsonable(value.item(), pointer)
    for plain in (str, int, float):  # other subclasses of the plain types
        if isinstance(value, plain):
            return plain(value)
    if isinstance(value, dict):
        return {str(k): to_jsonable(v, _join(pointer, k)) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [to_jsonable(v, _join(pointer, i)) for i, v in enumerate(value)]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, datetime.date | datetime.time):
        return value.isoformat()
    raise TypeError(f"{pointer or '(top level)'}: {type(value).__name__} cannot be stored in JSON")


_LINE = 80  # arrays of arrays longer than this get one row per line


def dumps_pretty(value: Any) -> str:
    """Indented JSON, ending in a newline, with arrays of numbers kept on one line
    and matrices one row per line when they do not fit on one.

    Raises:
        ValueError: ``value`` holds NaN or infinity (callers check first).
    """
    return _dump(value, 0) + "\n"


def _dump(value: Any, level: int) -> str:
    pad, inner = "  " * level, "  " * (level + 1)
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = [f"{inner}{json.dumps(str(k))}: {_dump(v, level + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(value, list | tuple):
        if not value:
            return "[]"
        if _is_flat(value):
            one_line = json.dumps(value, allow_nan=False, ensure_ascii=False)
            nested = any(isinstance(v, list | tuple) for v in value)
            if not nested or len(pad) + len(one_line) <= _LINE:
                return one_line
        items = [inner + _dump(v, level + 1) for v in value]
        return "[\n" + ",\n".join(items) + "\n" + pad + "]"
    return json.dumps(value, allow_nan=False, ensure_ascii=False)


def _is_flat(value: list | tuple) -> bool:
    """True for arrays of scalars or of arrays of scalars (points, matrices)."""
    return all(
        not isinstance(v, dict) and (not isinstance(v, list | tuple) or _is_flat(v)) for v in value
    )
