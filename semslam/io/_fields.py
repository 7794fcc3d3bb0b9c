"""Typed access to a parsed JSON value that names the field in every error.

``Field(doc, "rig.json")["cameras"].items()[2]["K"].array((3, 3))`` either
returns a checked value or raises the chosen semslam error with a one-line
message such as ``rig.json: cameras/2/K: expected 3 rows, got 2``.
Field paths are JSON pointers without the leading slash.
"""

from __future__ import annotations

import math
import sys
from enum import Enum
from typing import Any, NoReturn, TypeVar

import numpy as np

from semslam.errors import FormatError, SemslamError
from semslam.geometry import FloatArray

E = TypeVar("E", bound=Enum)

_JSON_TYPE = {
    dict: "an object",
    list: "an array",
    str: "a string",
    bool: "true/false",
    int: "a number",
    float: "a number",
    type(None): "null",
}


def describe(value: Any) -> str:
    """How a JSON value looks, for messages: ``a string``, ``null``..."""
    return _JSON_TYPE.get(type(value), type(value).__name__)


class Field:
    """A value at ``pointer`` inside the document read from ``origin``.

    Attributes:
        value: the parsed JSON value.
        origin: where the document came from (``"map.json"``, ``"obs.jsonl line 4"``).
        pointer: path of the value inside the document (``"slots/3/corners"``).
        error: the semslam error class raised on any problem.
    """

    __slots__ = ("value", "origin", "error", "_parent", "_key")

    def __init__(
        self,
        value: Any,
        origin: str,
        error: type[SemslamError] = FormatError,
        pointer: str = "",
    ) -> None:
        self.value = value
        self.origin = origin
        self.error = error
        # the pointer is built only when a message needs it: readers make many fields
        self._parent: Field | None = None
        self._key: str | int = pointer

    @property
    def pointer(self) -> str:
        if self._parent is None:
            return str(self._key)
        parent = self._parent.pointer
        return f"{parent}/{self._key}" if parent else str(self._key)

    def fail(self, what: str) -> NoReturn:
        """Raise ``error("<origin>: <pointer>: <what>")``."""
        pointer = self.pointer
        where = f"{self.origin}: {pointer}" if pointer else self.origin
        raise self.error(f"{where}: {what}")

    def _child(self, key: str | int) -> Field:
        child = Field(self.value[key], self.origin, self.error)
        child._parent, child._key = self, key
        return child

    # ------------------------------------------------------------------ containers

    def obj(self) -> dict[str, Any]:
        """The value as a JSON object."""
        if not isinstance(self.value, dict):
            self.fail(f"expected an object, got {describe(self.value)}")
        return self.value

    def __getitem__(self, key: str) -> Field:
        """A required member of an object."""
        if key not in self.obj():
            self.fail(f"missing field '{key}'")
        return self._child(key)

    def get(self, key: str) -> Field | None:
        """An optional member of an object: None when absent or null."""
        if self.obj().get(key) is None:
            return None
        return self._child(key)

    def only(self, *keys: str) -> None:
        """Refuse members other than ``keys`` (catches misspelt field names)."""
        extra = sorted(set(self.obj()) - set(keys))
        if extra:
            self.fail(f"unknown field '{extra[0]}' (expected one of: {', '.join(keys)})")

    def items(self) -> list[Field]:
        """The elements of a JSON array."""
        if not isinstance(self.value, list):
            self.fail(f"expected an array, got {describe(self.value)}")
        return [self._child(i) for i in range(len(self.value))]

    # ------------------------------------------------------------------ scalars

    def number(
        self,
        minimum: float | None = None,
        maximum: float | None = None,
        positive: bool = False,
    ) -> float:
        """A finite number, optionally within ``[minimum, maximum]`` or > 0."""
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int | float):
            self.fail(f"expected a number, got {describe(v)}")
        try:
            v = float(v)
        except OverflowError:
            self.fail("number too large")
        if not math.isfinite(v):
            self.fail(f"{'NaN' if math.isnan(v) else 'infinity'} is not allowed")
        if positive and v <= 0:
            self.fail(f"must be > 0, got {v!r}")
        if minimum is not None and v < minimum:
            self.fail(f"must be >= {minimum!r}, got {v!r}")
        if maximum is not None and v > maximum:
            self.fail(f"must be <= {maximum!r}, got {v!r}")
        return v

    def integer(self, minimum: int | None = None, maximum: int | None = None) -> int:
        """An integer (``3.0`` is refused as a sign of a wrong field), optionally within
        ``[minimum, maximum]``."""
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(f"expected an integer, got {describe(v)}")
        if minimum is not None and v < minimum:
            self.fail(f"must be >= {minimum}, got {int_text(v)}")
        if maximum is not None and v > maximum:
            self.fail(f"must be <= {maximum}, got {int_text(v)}")
        return v

    def string(self, nonempty: bool = False) -> str:
        """A string, optionally non-empty."""
        if not isinstance(self.value, str):
            self.fail(f"expected a string, got {describe(self.value)}")
        if nonempty and not self.value:
            self.fail("must not be empty")
        return self.value

    def optional_string(self) -> str | None:
        """A string or null."""
        return None if self.value is None else self.string()

    def choice(self, enum: type[E]) -> E:
        """A member of a string enum, by value."""
        try:
            return enum(self.value)
        except (ValueError, TypeError):
            allowed = ", ".join(str(m.value) for m in enum)
            self.fail(f"{self.value!r} is not one of: {allowed}")

    # ------------------------------------------------------------------ arrays

    def array(self, shape: tuple[int | None, ...], within: float = math.inf) -> FloatArray:
        """A nested array of finite numbers of ``shape``, each at most ``within`` in
        magnitude; only the first axis may be None (any length), so an empty array gets
        the right trailing shape."""
        a = _plain_array(self.value, shape, within)
        if a is None:  # something is wrong: the element-wise walk names it
            a = np.array(self._nested(shape), dtype=float)
            check_within(self, a, within)
        if a.size == 0:
            a = a.reshape(tuple(0 if n is None else n for n in shape))
        return a

    def _nested(self, shape: tuple[int | None, ...]) -> Any:
        if not shape:
            return self.number()
        n = shape[0]
        elements = self.items()
        if n is not None and len(elements) != n:
            self.fail(f"expected {n} {_element_name(shape)}, got {len(elements)}")
        return [e._nested(shape[1:]) for e in elements]


def int_text(v: int) -> str:
    """An integer for a one-line message: its digits when short, else to six figures."""
    if abs(v) < 10**12:
        return str(v)
    try:
        return f"{float(v):.6g}"
    except OverflowError:  # beyond any float
        return f"an integer of {len(str(abs(v)))} digits"


def check_within(f: Field, values: Any, within: float) -> None:
    """Refuse (naming ``f``) the first of ``values`` beyond ``within`` in magnitude."""
    flat = np.asarray(values, dtype=float).reshape(-1)
    big = np.flatnonzero(np.abs(flat) > within)
    if big.size:
        f.fail(f"{float(flat[big[0]]):g} is out of range (|value| <= {within:g})")


def check_covariance(f: Field, covariance: FloatArray, bound: float) -> None:
    """Refuse (naming ``f``) a covariance that is not symmetric positive semi-definite to
    rounding, or has an entry beyond ``bound`` (a broken file; the filters would overflow)."""
    c = np.asarray(covariance, dtype=float)
    scale = max(float(np.max(np.abs(c))), 1e-300)
    if scale > bound:
        f.fail(f"covariance entry {scale:g} is out of range (|entry| <= {bound:g})")
    if np.max(np.abs(c - c.T)) > 1e-9 * scale:
        f.fail("not symmetric")
    if float(np.linalg.eigvalsh(0.5 * (c + c.T))[0]) < -1e-9 * scale:
        f.fail("not positive semi-definite")


def check_covariances(f: Field, covariances: FloatArray, bound: float) -> None:
    """:func:`check_covariance` of each of ``covariances`` (K, n, n), the elements of the
    list ``f``, all at once; on a failure the first failing one is named as alone."""
    c = np.asarray(covariances, dtype=float)
    if not len(c):
        return
    scale = np.maximum(np.abs(c).max(axis=(1, 2)), 1e-300)
    if (scale <= bound).all():  # no NaN, nothing huge: the sums below cannot overflow
        cT = np.swapaxes(c, 1, 2)
        lowest = np.linalg.eigvalsh(0.5 * (c + cT))[:, 0]
        if ((np.abs(c - cT).max(axis=(1, 2)) <= 1e-9 * scale) & (lowest >= -1e-9 * scale)).all():
            return
    for field, covariance in zip(f.items(), c, strict=True):
        check_covariance(field, covariance, bound)


_FLOAT_MAX = sys.float_info.max


def _plain_array(
    value: Any, shape: tuple[int | None, ...], within: float = math.inf
) -> FloatArray | None:
    """The array when ``value`` is nested lists of ``shape`` holding finite ints and
    floats only (not bools), none beyond ``within`` in magnitude, else None; builds no
    pointer, so it is the fast path."""
    if shape == (2,) and type(value) is list and len(value) == 2:  # a point, checked in floats
        bound = min(within, _FLOAT_MAX)  # NaN, infinity and huge ints fail the comparison
        x, y = value
        plain = _plain_numbers(x, ()) and _plain_numbers(y, ())
        within_bound = plain and abs(x) <= bound and abs(y) <= bound
        return np.array(value, dtype=float) if within_bound else None
    if not _plain_numbers(value, shape):
        return None
    try:
        a = np.array(value, dtype=float)
    except OverflowError:  # an integer beyond float
        return None
    if within == math.inf:
        return a if np.isfinite(a).all() else None
    return a if (np.abs(a) <= within).all() else None  # NaN and infinity fail too


def _plain_numbers(value: Any, shape: tuple[int | None, ...]) -> bool:
    """Whether ``value`` is nested lists of ``shape`` holding only ints and floats (a bool
    is neither here, as in :meth:`Field.number`)."""
    if not shape:
        return type(value) is float or type(value) is int
    n = shape[0]
    if type(value) is not list or (n is not None and len(value) != n):
        return False
    return all(_plain_numbers(v, shape[1:]) for v in value)


def _element_name(shape: tuple[int | None, ...]) -> str:
    if len(shape) == 1:
        return "numbers"
    if len(shape) == 2 and shape[1] == 2:
        return "points"
    return "rows"


def check_header(root: Field, expected_format: str, supported_version: int) -> int:
    """Check the ``format`` string and ``version`` of a versioned document.

    Returns:
        The document's version.

    Raises:
        root.error: ``"rig.json: format is 'x', expected 'semslam-rig'"`` or
            ``"rig.json: version 2 is newer than this semslam reads (1)"``.
    """
    fmt = root.obj().get("format")
    if fmt != expected_format:
        got = "missing" if fmt is None else repr(fmt)
        raise root.error(f"{root.origin}: format is {got}, expected '{expected_format}'")
    version = root["version"].integer(1)
    if version > supported_version:
        raise root.error(
            f"{root.origin}: version {version} is newer than this semslam reads "
            f"({supported_version})"
        )
    return version
