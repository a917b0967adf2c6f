"""What the edge (:mod:`server.api.edge`) checks of a request before the application reads
it: control characters in its target (path and query string, raw or percent-encoded), its
body read within the limit (or streamed through a bounded receive) and handed on as if
unread, and a JSON body parsed once and checked (:func:`check_json`: depth, control
characters, lone surrogates)."""

from __future__ import annotations

import json
import re
from typing import Any
from urllib.parse import unquote_to_bytes

from starlette.types import Message, Receive, Scope

from server.api.errors import HttpError

__all__ = ["check_json"]

_CONTROL_BYTES = re.compile(rb"[\x00-\x1f\x7f]")
_CONTROL_TEXT = re.compile(r"[\x00-\x1f\x7f]")
#: In JSON strings: control characters except tab, newline, carriage return; and lone
#: surrogates (``"\ud800"`` parses, but no database stores it).
_BAD_JSON_TEXT = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ud800-\udfff]")


def check_json(body: bytes, max_depth: int) -> tuple[str, str, Any] | None:
    """``(code, message, detail)`` when ``body`` is not JSON the service takes, else None.

    Parsed once with :func:`json.loads` (a RecursionError from the parser is too deep);
    depth and strings are then checked iteratively."""
    try:
        document = json.loads(body)
    except RecursionError:
        return "json_too_deep", f"the JSON body is nested deeper than {max_depth}", None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        return "invalid_json", f"the body is not JSON: {exc}", None
    stack: list[tuple[Any, int, tuple[str | int, ...]]] = [(document, 1, ())]
    while stack:
        value, depth, loc = stack.pop()
        if isinstance(value, str):
            bad = _BAD_JSON_TEXT.search(value)
            if bad:
                return _bad_text(bad.group(), loc)
        elif isinstance(value, list | dict):
            if depth > max_depth:
                message = f"the JSON body is nested deeper than {max_depth}"
                return "json_too_deep", message, {"loc": list(loc)}
            if isinstance(value, list):
                stack.extend((item, depth + 1, (*loc, i)) for i, item in enumerate(value))
            else:
                for key, item in value.items():
                    bad = _BAD_JSON_TEXT.search(key)
                    if bad:
                        return _bad_text(bad.group(), (*loc, key.encode("unicode_escape").decode()))
                    stack.append((item, depth + 1, (*loc, key)))
    return None


def _bad_text(char: str, loc: tuple[str | int, ...]) -> tuple[str, str, Any]:
    where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc) or "the body"
    message = f"a JSON string holds a control character (U+{ord(char):04X}) at {where}"
    return "invalid_text", message, {"loc": list(loc), "char": f"U+{ord(char):04X}"}


def _bad_target(scope: Scope) -> str | None:
    """``"path"`` or ``"query string"`` when it holds a control character (raw or
    percent-encoded), else None."""
    raw_path: bytes = scope.get("raw_path") or scope["path"].encode("utf-8", "surrogateescape")
    query: bytes = scope.get("query_string", b"")
    if _CONTROL_TEXT.search(scope["path"]):
        return "path"
    for what, raw in (("path", raw_path), ("query string", query)):
        if _CONTROL_BYTES.search(raw) or _CONTROL_BYTES.search(unquote_to_bytes(raw)):
            return what
    return None


def _too_large(size: int, limit: int) -> str:
    return f"a request body of {size} bytes or more exceeds the limit of {limit} bytes"


async def _read_body(receive: Receive, limit: int) -> bytes | None:
    """The body, or its first ``limit + 1`` bytes or more when it is larger; None when the
    client disconnected."""
    body = bytearray()
    while True:
        message = await receive()
        if message["type"] != "http.request":
            return None
        body += message.get("body", b"")
        if len(body) > limit or not message.get("more_body", False):
            return bytes(body)


def _replay(body: bytes, receive: Receive) -> Receive:
    """The body read ahead, as one message; then the client's (its disconnect)."""
    pending = True

    async def replay() -> Message:
        nonlocal pending
        if pending:
            pending = False
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay


def _limited(receive: Receive, limit: int) -> Receive:
    received = 0

    async def limited() -> Message:
        nonlocal received
        message = await receive()
        if message["type"] == "http.request":
            received += len(message.get("body", b""))
            if received > limit:
                raise HttpError(413, "request_too_large", _too_large(received, limit))
        return message

    return limited
