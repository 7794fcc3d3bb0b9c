"""JSON Schemas shipped in ``semslam/schemas`` and one-line validation errors.

A document is checked first by a validator compiled from the schema (fastjsonschema: Python
code generated for this schema, 0.03 s for a `garage` map against 0.85 s in jsonschema);
only a document it refuses goes through jsonschema, whose errors name the most relevant
violation (:func:`validate`). The schemas use only keywords both read alike (type, $ref,
properties, required, additionalProperties, items, min/maxItems, minimum, maximum,
exclusiveMinimum, enum, const; ``format`` is an annotation to both, as jsonschema reads it
without a format checker); tests/io hold that the two agree.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources
from typing import Any

import fastjsonschema
import jsonschema
from jsonschema.exceptions import ValidationError, best_match

from semslam.errors import SemslamError
from semslam.io._fields import describe


@cache
def load_schema(name: str) -> dict[str, Any]:
    """The schema ``semslam/schemas/<name>.schema.json`` as a dict."""
    text = resources.files("semslam").joinpath(f"schemas/{name}.schema.json").read_text("utf-8")
    return json.loads(text)


@cache
def _validator(name: str) -> jsonschema.protocols.Validator:
    schema = load_schema(name)
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


@cache
def _compiled(name: str):
    """Schema ``name`` compiled to a function that raises on an invalid document."""
    return fastjsonschema.compile(load_schema(name), use_formats=False)


def is_valid(document: Any, name: str) -> bool:
    """Whether ``document`` satisfies schema ``name`` (the compiled validator)."""
    try:
        _compiled(name)(document)
    except fastjsonschema.JsonSchemaException:
        return False
    return True


def validate(document: Any, name: str, source: str, error: type[SemslamError]) -> None:
    """Check ``document`` against schema ``name``.

    Raises:
        error: ``"<source>: <pointer>: <what is wrong>"`` for the most relevant
            violation, e.g. ``map.json: slots/3/corners: expected 4 items, got 3``.
    """
    if is_valid(document, name):
        return
    found = best_match(_validator(name).iter_errors(document))
    if found is None:  # pragma: no cover - the two validators disagree (tests/io hold they don't)
        raise error(f"{source}: does not satisfy the {name} schema")
    pointer = "/".join(str(p) for p in found.absolute_path) or "(top level)"
    raise error(f"{source}: {pointer}: {_describe(found)}")


_TYPE_NAMES = {
    "number": "a number",
    "integer": "an integer",
    "string": "a string",
    "array": "an array",
    "object": "an object",
    "boolean": "true/false",
    "null": "null",
}


def _describe(err: ValidationError) -> str:
    """A short, one-line account of a violation (jsonschema's own messages
    quote the whole offending value, which can be huge)."""
    v, kw, inst = err.validator_value, err.validator, err.instance
    if kw == "type":
        wanted = [v] if isinstance(v, str) else v
        return (
            f"expected {' or '.join(_TYPE_NAMES.get(t, t) for t in wanted)}, got {describe(inst)}"
        )
    if kw in ("minItems", "maxItems") and isinstance(inst, list):
        low, high = err.schema.get("minItems"), err.schema.get("maxItems")
        if low == high:
            return f"expected {low} items, got {len(inst)}"
        bound = "at least" if kw == "minItems" else "at most"
        return f"expected {bound} {v} items, got {len(inst)}"
    if kw == "required":
        return err.message
    if kw == "enum":
        return f"{_short(inst)} is not one of: {', '.join(map(str, v))}"
    if kw == "const":
        return f"expected {v!r}, got {_short(inst)}"
    if kw in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        op = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">", "exclusiveMaximum": "<"}
        return f"must be {op[kw]} {v}, got {_short(inst)}"
    return _one_line(err.message, 200)


def _short(value: Any) -> str:
    """``repr`` of a value cut to one short line."""
    return _one_line(repr(value), 60)


def _one_line(text: str, limit: int) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
