"""A strict validator for the small subset of JSON Schema that our channel schemas use.

The reader must refuse a message that breaks its channel's schema, and ``jsonschema-rs`` is a
development dependency only; so the schemas in :mod:`telemetry.mcap._schemas` are compiled
here into plain functions. Only these keywords are understood (an unknown keyword in a schema
is a programming error, caught when it is compiled): ``type``, ``properties``, ``required``,
``additionalProperties`` (a boolean or a schema), ``items``, ``minItems``, ``maxItems``, ``enum``,
``minimum``, ``maximum``; ``title``, ``description`` and ``$comment`` are notes.

It is stricter than JSON Schema in one place: an ``integer`` must be a JSON integer (``3``),
not a float with a zero fraction (``3.0``); our writer never writes the latter, and a float
would not round-trip an int64 exactly.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["SchemaViolation", "Validator", "compile_schema"]


class SchemaViolation(ValueError):
    """A document that breaks its schema; the text says where and how."""


Validator = Callable[[Any], None]
_Check = Callable[[Any, str], None]

_NOTES = {"title", "description", "$comment", "$schema"}
_KNOWN = _NOTES | {
    "type",
    "properties",
    "required",
    "additionalProperties",
    "items",
    "minItems",
    "maxItems",
    "enum",
    "minimum",
    "maximum",
}


# JSON's types as the exact Python types json.loads produces (bool is not an integer here).
_PY_TYPES: dict[str, tuple[type, ...]] = {
    "object": (dict,),
    "array": (list,),
    "string": (str,),
    "boolean": (bool,),
    "null": (type(None),),
    "integer": (int,),
    "number": (int, float),
}


def _py_types(names: list[str]) -> frozenset[type]:
    unknown = [n for n in names if n not in _PY_TYPES]
    if unknown:
        raise ValueError(f"unsupported JSON Schema types {unknown}")
    return frozenset(t for n in names for t in _PY_TYPES[n])


def _only_type(schema: Mapping[str, Any]) -> frozenset[type] | None:
    """The allowed Python types when ``schema`` checks nothing but its type (a fast path)."""
    if set(schema) - _NOTES != {"type"}:
        return None
    names = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    return _py_types(names)


def _compile(schema: Mapping[str, Any]) -> _Check:
    unknown = set(schema) - _KNOWN
    if unknown:
        raise ValueError(f"unsupported JSON Schema keywords {sorted(unknown)}")
    checks: list[_Check] = []

    if "type" in schema:
        names = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        allowed = _py_types(names)

        def check_type(value: Any, where: str) -> None:
            if type(value) not in allowed:
                got = type(value).__name__
                raise SchemaViolation(f"{where}: expected {' or '.join(names)}, got {got}")

        checks.append(check_type)

    if "enum" in schema:
        choices = list(schema["enum"])

        def check_enum(value: Any, where: str) -> None:
            if not any(value == c and type(value) is type(c) for c in choices):
                raise SchemaViolation(f"{where}: {value!r} is not one of {choices}")

        checks.append(check_enum)

    for key, holds, text in (
        ("minimum", lambda v, lim: v >= lim, "below the minimum"),
        ("maximum", lambda v, lim: v <= lim, "above the maximum"),
    ):
        if key in schema:
            limit = schema[key]

            def check_bound(
                value: Any, where: str, limit: Any = limit, holds: Any = holds, text: str = text
            ) -> None:
                if type(value) in (int, float) and not holds(value, limit):
                    raise SchemaViolation(f"{where}: {value!r} is {text} {limit!r}")

            checks.append(check_bound)

    if "properties" in schema or "required" in schema or "additionalProperties" in schema:
        props = {k: _compile(v) for k, v in schema.get("properties", {}).items()}
        required = list(schema.get("required", []))
        extra = schema.get("additionalProperties", True)
        closed = extra is False
        extra_check = _compile(extra) if isinstance(extra, Mapping) else None

        def check_object(value: Any, where: str) -> None:
            if not isinstance(value, dict):
                return
            for key in required:
                if key not in value:
                    raise SchemaViolation(f"{where}: missing required field {key!r}")
            for key, item in value.items():
                sub = props.get(key)
                if sub is not None:
                    sub(item, f"{where}.{key}")
                elif extra_check is not None:
                    extra_check(item, f"{where}.{str(key)[:64]}")
                elif closed:
                    raise SchemaViolation(f"{where}: unexpected field {str(key)[:64]!r}")

        checks.append(check_object)

    if "items" in schema or "minItems" in schema or "maxItems" in schema:
        item_check = _compile(schema["items"]) if "items" in schema else None
        item_types = _only_type(schema["items"]) if "items" in schema else None
        lo = schema.get("minItems", 0)
        hi = schema.get("maxItems")

        def check_array(value: Any, where: str) -> None:
            if not isinstance(value, list):
                return
            if len(value) < lo or (hi is not None and len(value) > hi):
                want = f"{lo}" if hi == lo else f"{lo} to {hi if hi is not None else 'any'}"
                raise SchemaViolation(f"{where}: {len(value)} items, expected {want}")
            if item_types is not None:
                for item in value:
                    if type(item) not in item_types:
                        break
                else:
                    return
            if item_check is not None:
                for i, item in enumerate(value):
                    item_check(item, f"{where}[{i}]")

        checks.append(check_array)

    if len(checks) == 1:
        return checks[0]

    def check(value: Any, where: str) -> None:
        for c in checks:
            c(value, where)

    return check


def compile_schema(schema: Mapping[str, Any], *, name: str = "message") -> Validator:
    """A function that returns ``None`` for a document valid under ``schema`` and raises
    :class:`SchemaViolation` (naming the path, e.g. ``message.joints_rad[3]``) otherwise."""
    check = _compile(schema)

    def validate(document: Any) -> None:
        check(document, name)

    return validate
