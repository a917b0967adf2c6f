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
from server.schemas.json_text import json_problem

__all__ = ["check_json", "request_too_large"]

_CONTROL_BYTES = re.compile(rb"[\x00-\x1f\x7f]")
_CONTROL_TEXT = re.compile(r"[\x00-\x1f\x7f]")


def check_json(body: bytes, max_depth: int) -> tuple[str, str, Any] | None:
    """``(code, message, detail)`` when ``body`` is not JSON the service takes, else None.

    Parsed once with :func:`json.loads` (a RecursionError from the parser is too deep);
    depth and strings are then checked iteratively (:func:`server.schemas.json_text.
    json_problem`)."""
    try:
        document = json.loads(body)
    except RecursionError:
        return "json_too_deep", f"the JSON body is nested deeper than {max_depth}", None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        return "invalid_json", f"the body is not JSON: {exc}", None
    return json_problem(document, max_depth)


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


def request_too_large(size: int, limit: int) -> HttpError:
    """413 ``request_too_large``: a body of ``size`` bytes or more, over ``limit``."""
    return HttpError(413, "request_too_large", _too_large(size, limit))


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
                raise request_too_large(received, limit)
        return message

    return limited
