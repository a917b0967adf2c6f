"""What a JSON document the service takes may hold: its nesting at most so deep, and no
string or key with text the databases refuse (PostgreSQL) or store (SQLite) differently.

One walk for the HTTP edge's bodies (:mod:`server.api.edge_checks`) and the documents a
route reads itself (a plan document, :mod:`server.operations.plan_documents`)."""

from __future__ import annotations

import re
from typing import Any

__all__ = ["json_problem"]

#: In JSON strings: control characters except tab, newline, carriage return; and lone
#: surrogates (``"\ud800"`` parses, but no database stores it).
_BAD_JSON_TEXT = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ud800-\udfff]")


def json_problem(document: Any, max_depth: int, what: str = "body") -> tuple[str, str, Any] | None:
    """``(code, message, detail)`` when the parsed ``document`` nests deeper than
    ``max_depth`` (``json_too_deep``) or holds a bad string (``invalid_text``), else None.
    Iterative: a deep document does not exhaust the stack."""
    stack: list[tuple[Any, int, tuple[str | int, ...]]] = [(document, 1, ())]
    while stack:
        value, depth, loc = stack.pop()
        if isinstance(value, str):
            bad = _BAD_JSON_TEXT.search(value)
            if bad:
                return _bad_text(bad.group(), loc, what)
        elif isinstance(value, list | dict):
            if depth > max_depth:
                message = f"the JSON {what} is nested deeper than {max_depth}"
                return "json_too_deep", message, {"loc": list(loc)}
            if isinstance(value, list):
                stack.extend((item, depth + 1, (*loc, i)) for i, item in enumerate(value))
            else:
                for key, item in value.items():
                    bad = _BAD_JSON_TEXT.search(key)
                    if bad:
                        where = (*loc, key.encode("unicode_escape").decode())
                        return _bad_text(bad.group(), where, what)
                    stack.append((item, depth + 1, (*loc, key)))
    return None


def _bad_text(char: str, loc: tuple[str | int, ...], what: str) -> tuple[str, str, Any]:
    where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc) or f"the {what}"
    message = f"a JSON string holds a control character (U+{ord(char):04X}) at {where}"
    return "invalid_text", message, {"loc": list(loc), "char": f"U+{ord(char):04X}"}
