"""The HTTP edge: what every request meets before any route, and how the service is served
(docs/security.md).

:class:`EdgeMiddleware`, a pure ASGI middleware in front of the application
(:func:`install_edge`), answers in the one JSON error shape, in this order:

1. 429 ``too_many_failures`` (with ``Retry-After``) to an address that failed to
   authenticate ``auth_failure_limit`` times within ``auth_failure_window_s``
   (:class:`AuthGuard`; every failure goes to the ``hikoboshi.audit`` log, never the token);
2. 400 ``invalid_text`` to a path or query string holding NUL, another C0 control character
   or DEL, raw or percent-encoded: text the databases refuse (PostgreSQL) or store (SQLite)
   is refused here, the same on both;
3. 401 ``unauthorized`` to a request for an ``/api`` route (except ``/api/health``) without a
   known ``Authorization: Bearer`` token, before a byte of its body is read (roles are the
   routes' dependencies' business: 403 there). The websockets authenticate themselves;
4. 413 ``request_too_large`` to a body over ``max_request_bytes``: at once for a declared
   ``Content-Length``, else as soon as the streamed body grows past it.
   ``POST /api/passes/import`` streams through with its own limit (``max_import_bytes``);
5. for the authenticated routes, a JSON body (or one without a content type, which FastAPI
   reads as JSON) is read (bounded), parsed once and refused with 400 ``invalid_json``,
   ``json_too_deep`` (over ``max_json_depth``) or ``invalid_text`` (a string or key holding a
   control character other than tab, newline and carriage return, or a lone surrogate)
   before the application sees the original bytes.

Every response gets ``X-Content-Type-Options: nosniff``, ``Referrer-Policy: no-referrer``
and ``X-Frame-Options: DENY``; the console's page (``/``, ``/index.html``) a
``Content-Security-Policy`` that allows its own bundles and websocket only.

:func:`uvicorn_config` is how ``hikoboshi serve`` runs it: keep-alive and graceful
shutdown timeouts, a bounded request head, a request-head timeout
(:func:`head_timeout_protocol`) and an access log with secrets in query strings redacted.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import re
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote_to_bytes

from starlette.routing import Match, Router
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.deps import authenticate
from server.api.errors import HttpError, error_body
from server.services.clock import Clock, SystemClock
from server.services.events import AuthBlocked, record
from server.settings import Settings

if TYPE_CHECKING:
    import uvicorn
    from fastapi import FastAPI

__all__ = [
    "AuthGuard",
    "EdgeMiddleware",
    "RedactSecretsFilter",
    "check_json",
    "console_csp",
    "head_timeout_protocol",
    "install_edge",
    "uvicorn_config",
]

audit = logging.getLogger("hikoboshi.audit")
log = logging.getLogger("hikoboshi.ground.edge")

#: ``/api`` routes that need no token (the websockets authenticate themselves).
PUBLIC_PATHS = frozenset({"/api/health"})
#: Streams its body through with its own, larger limit (server/api/recordings.py).
IMPORT_PATH = "/api/passes/import"
#: The console's HTML pages: they get the Content-Security-Policy.
CONSOLE_PAGES = frozenset({"/", "/index.html"})

_CONTROL_BYTES = re.compile(rb"[\x00-\x1f\x7f]")
_CONTROL_TEXT = re.compile(r"[\x00-\x1f\x7f]")
#: In JSON strings: control characters except tab, newline, carriage return; and lone
#: surrogates (``"\ud800"`` parses, but no database stores it).
_BAD_JSON_TEXT = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ud800-\udfff]")
#: A Host header that may be written into the policy as is.
_SAFE_HOST = re.compile(r"(?:[A-Za-z0-9.-]+|\[[0-9A-Fa-f:.]+\])(?::[0-9]{1,5})?")

_SECURITY_HEADERS = (
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
)


def console_csp(host: str | None) -> str:
    """The console page's policy: scripts, styles, images and requests from this origin
    only; the websocket to this host (``'self'`` covers ws:/wss: in CSP 3 browsers, the
    host's own ws:/wss: origins the older ones); inline style attributes (the console sets
    some); ``data:`` and ``blob:`` images (the icon, report figures); no framing."""
    connect = "'self'"
    if host and _SAFE_HOST.fullmatch(host):
        connect += f" ws://{host} wss://{host}"
    return (
        "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
        f"img-src 'self' data: blob:; connect-src {connect}; object-src 'none'; "
        "base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
    )


@dataclass
class _Window:
    start: float
    failures: int = 0


class AuthGuard:
    """Failed authentications per client address in fixed windows: after ``limit`` failures
    within ``window_s`` of the first, the address is refused until the window ends. At most
    ``max_addresses`` are tracked (the oldest window goes first); ``clock`` is injectable
    (tests move it instead of sleeping)."""

    def __init__(
        self,
        *,
        limit: int,
        window_s: float,
        max_addresses: int,
        clock: Callable[[], float] = time.monotonic,
        on_blocked: Callable[[str, int, float], None] | None = None,
    ) -> None:
        self.limit = limit
        #: called once per window an address is blocked: (address, failures, seconds left)
        self.on_blocked = on_blocked
        self.window_s = window_s
        self.max_addresses = max_addresses
        self.clock = clock
        #: address -> its window, in the order the windows started
        self._windows: OrderedDict[str, _Window] = OrderedDict()

    def __len__(self) -> int:
        return len(self._windows)

    def retry_after(self, address: str) -> int | None:
        """Seconds until ``address`` may try again, or None when it is not blocked."""
        now = self.clock()
        self._expire(now)
        window = self._windows.get(address)
        if window is None or window.failures < self.limit:
            return None
        return max(1, math.ceil(window.start + self.window_s - now))

    def failed(self, address: str, path: str, reason: str) -> None:
        """Audit one failed authentication and count it against ``address``."""
        now = self.clock()
        self._expire(now)
        window = self._windows.get(address)
        if window is None:
            window = self._windows[address] = _Window(start=now)
            while len(self._windows) > self.max_addresses:
                self._windows.popitem(last=False)
        window.failures += 1
        audit.warning(
            "authentication failed: address=%s path=%r reason=%r (%d in this window)",
            address,
            path,
            reason,
            window.failures,
        )
        if window.failures == self.limit:
            left = window.start + self.window_s - now
            audit.warning(
                "address %s refused for %.0f s: %d failed authentications",
                address,
                left,
                window.failures,
            )
            if self.on_blocked is not None:
                try:
                    self.on_blocked(address, window.failures, left)
                except Exception:
                    log.exception("recording the block of %s failed", address)

    def _expire(self, now: float) -> None:
        # Windows are appended as they start, so the expired ones are at the front.
        while self._windows:
            first = next(iter(self._windows.values()))
            if now - first.start < self.window_s:
                break
            self._windows.popitem(last=False)


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


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", ()):
        if key.lower() == name:
            return bytes(value).decode("latin-1")
    return None


def _is_json(content_type: str | None) -> bool:
    """Whether FastAPI would read the body as JSON (it does without a content type)."""
    if content_type is None:
        return True
    media = content_type.split(";", 1)[0].strip().lower()
    return media == "application/json" or (
        media.startswith("application/") and media.endswith("+json")
    )


async def _respond(
    send: Send,
    status: int,
    code: str,
    message: str,
    detail: Any = None,
    headers: Iterable[tuple[bytes, bytes]] = (),
) -> None:
    body = json.dumps(error_body(code, message, detail)).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                *headers,
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class EdgeMiddleware:
    """See the module's docstring. ``router``: the application's, to tell an ``/api`` route
    (authenticated) from a path no route serves (404 from the application, unread)."""

    def __init__(
        self, app: ASGIApp, *, settings: Settings, guard: AuthGuard, router: Router
    ) -> None:
        self.app = app
        self.settings = settings
        self.guard = guard
        self.router = router

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            await self._http(scope, receive, _with_security_headers(scope, send))
        elif scope["type"] == "websocket":
            await self._websocket(scope, receive, send)
        else:
            await self.app(scope, receive, send)

    async def _websocket(self, scope: Scope, receive: Receive, send: Send) -> None:
        # Refused before the handshake (the client sees 403); the routes authenticate.
        if self.guard.retry_after(_address(scope)) is not None or _bad_target(scope):
            await send({"type": "websocket.close", "code": 1008})
            return
        await self.app(scope, receive, send)

    def _protected(self, scope: Scope) -> bool:
        path: str = scope["path"]
        if not (path == "/api" or path.startswith("/api/")) or path in PUBLIC_PATHS:
            return False
        return any(route.matches(scope)[0] is not Match.NONE for route in self.router.routes)

    async def _http(self, scope: Scope, receive: Receive, send: Send) -> None:
        address = _address(scope)
        declared = _content_length(scope)
        has_body = bool(declared) or _header(scope, b"transfer-encoding") is not None
        # A refusal that leaves a body unread closes the connection (nothing more is read).
        close = ((b"connection", b"close"),) if has_body else ()

        retry = self.guard.retry_after(address)
        if retry is not None:
            message = f"too many failed authentications from {address}: retry in {retry} s"
            headers = ((b"retry-after", str(retry).encode()), *close)
            await _respond(send, 429, "too_many_failures", message, headers=headers)
            return
        where = _bad_target(scope)
        if where is not None:
            message = f"the {where} holds a control character"
            await _respond(send, 400, "invalid_text", message, headers=close)
            return
        protected = self._protected(scope)
        if protected:
            try:
                authenticate(self.settings, _header(scope, b"authorization"))
            except HttpError as exc:
                self.guard.failed(address, scope["path"], exc.message)
                headers = ((b"www-authenticate", b"Bearer"), *close)
                await _respond(send, exc.status, exc.code, exc.message, headers=headers)
                return
        if scope["path"] == IMPORT_PATH:
            await self.app(scope, receive, send)  # streamed; the route enforces its limit
            return
        limit = self.settings.max_request_bytes
        if declared is not None and declared > limit:
            await _respond(send, 413, "request_too_large", _too_large(declared, limit), None, close)
            return
        if not protected:
            # No route here reads a body (public, or 404): a bounded stream all the same.
            await self.app(scope, _limited(receive, limit), send)
            return
        body = await _read_body(receive, limit)
        if body is None:
            return  # the client went away
        if len(body) > limit:
            await _respond(
                send, 413, "request_too_large", _too_large(len(body), limit), None, close
            )
            return
        if body and _is_json(_header(scope, b"content-type")):
            refused = check_json(body, self.settings.max_json_depth)
            if refused is not None:
                await _respond(send, 400, *refused)
                return
        await self.app(scope, _replay(body, receive), send)


def _address(scope: Scope) -> str:
    client = scope.get("client")
    return str(client[0]) if client else "unknown"


def _content_length(scope: Scope) -> int | None:
    value = _header(scope, b"content-length")
    return int(value) if value is not None and value.strip().isdigit() else None


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


def _with_security_headers(scope: Scope, send: Send) -> Send:
    extra = list(_SECURITY_HEADERS)
    if scope["path"] in CONSOLE_PAGES:
        policy = console_csp(_header(scope, b"host"))
        extra.append((b"content-security-policy", policy.encode("latin-1")))

    async def send_with_headers(message: Message) -> None:
        if message["type"] == "http.response.start":
            headers = list(message.get("headers", ()))
            present = {bytes(name).lower() for name, _ in headers}
            headers += [(name, value) for name, value in extra if name not in present]
            message = {**message, "headers": headers}
        await send(message)

    return send_with_headers


def install_edge(app: FastAPI, settings: Settings) -> AuthGuard:
    """Put :class:`EdgeMiddleware` in front of ``app``; its :class:`AuthGuard` is also
    ``app.state.auth_guard`` (the websockets count their failures there; tests move its
    clock)."""
    guard = AuthGuard(
        limit=settings.auth_failure_limit,
        window_s=settings.auth_failure_window_s,
        max_addresses=settings.auth_tracked_addresses,
        on_blocked=lambda address, failures, left: _record_block(app, address, failures, left),
    )
    app.state.auth_guard = guard
    app.add_middleware(EdgeMiddleware, settings=settings, guard=guard, router=app.router)
    return guard


def _record_block(app: FastAPI, address: str, failures: int, left_s: float) -> None:
    """Write an ``auth_blocked`` event to the audit log (the events table) and show it to
    the consoles: once per blocked window and address, so an attacker cannot make the
    service write more than that. On the readers' connections, in a thread: never on the
    command path's."""
    sessions = getattr(app.state, "sessions", None)
    publisher = getattr(app.state, "publisher", None)
    clock: Clock = getattr(app.state, "clock", None) or SystemClock()
    if sessions is None:
        return
    loop = asyncio.get_running_loop()
    blocked = AuthBlocked(
        actor="edge", address=address, failures=failures, blocked_s=round(left_s, 1)
    )

    def write() -> dict[str, Any]:
        with sessions() as session:
            event = record(session, blocked, clock.time_ns())
            session.commit()
            return event

    def done(future: asyncio.Future[dict[str, Any]]) -> None:
        if future.cancelled() or future.exception() is not None:
            log.error("auth_blocked event not written: %r", future.exception())
        elif publisher is not None:
            publisher.publish([future.result()])

    loop.run_in_executor(None, write).add_done_callback(done)


# --- serving: uvicorn's settings ---------------------------------------------------------


class RedactSecretsFilter(logging.Filter):
    """Rewrites ``token=...`` (and the like) in query strings of log records: for the access
    log, so that a token someone put in a URL is not kept."""

    _SECRET = re.compile(r"(?i)([?&](?:token|access_token|api_key|apikey|key|secret)=)[^&\s\"]*")

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(
                self._SECRET.sub(r"\1[redacted]", arg) if isinstance(arg, str) else arg
                for arg in record.args
            )
        if isinstance(record.msg, str):
            record.msg = self._SECRET.sub(r"\1[redacted]", record.msg)
        return True


def head_timeout_protocol(seconds: float) -> type[asyncio.Protocol]:
    """uvicorn's h11 protocol, closing a connection whose request head has not fully arrived
    ``seconds`` after the connection opened or the head's first byte arrived (uvicorn has
    no such timeout: a client sending half a request line would hold its connection for
    good). Idle keep-alive connections are uvicorn's ``timeout_keep_alive``'s."""
    import h11
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class HeadTimeoutH11Protocol(H11Protocol):
        head_timeout_s = seconds
        _head_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm_head_timer()

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            self._watch_head()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            # A pipelined request may have left part of its head behind.
            if self.conn.trailing_data[0]:
                self._watch_head()

        def connection_lost(self, exc: Exception | None) -> None:
            self._cancel_head_timer()
            super().connection_lost(exc)

        def _watch_head(self) -> None:
            if not self.transport.is_closing() and self.conn.their_state is h11.IDLE:
                self._arm_head_timer()  # part of a head, waiting for the rest
            else:
                self._cancel_head_timer()

        def _arm_head_timer(self) -> None:
            if self._head_timer is None:
                self._head_timer = self.loop.call_later(self.head_timeout_s, self._head_timeout)

        def _cancel_head_timer(self) -> None:
            if self._head_timer is not None:
                self._head_timer.cancel()
                self._head_timer = None

        def _head_timeout(self) -> None:
            self._head_timer = None
            if not self.transport.is_closing() and self.conn.their_state is h11.IDLE:
                client = f"{self.client[0]}:{self.client[1]}" if self.client else "a client"
                log.info("closing %s: no request head within %.1f s", client, self.head_timeout_s)
                self.transport.close()

    return HeadTimeoutH11Protocol


def uvicorn_config(app: ASGIApp, settings: Settings, *, host: str, port: int) -> uvicorn.Config:
    """How ``hikoboshi serve`` runs ``app``: the edge's timeouts and limits, the access log
    redacted. Run it with ``uvicorn.Server(config).run()``."""
    import uvicorn

    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level="info",
        http=head_timeout_protocol(settings.header_timeout_s),
        timeout_keep_alive=math.ceil(settings.keep_alive_timeout_s),
        timeout_graceful_shutdown=3,
        h11_max_incomplete_event_size=settings.max_header_bytes,
        server_header=False,
    )
    # uvicorn.Config has configured logging by now: the filter stays.
    access = logging.getLogger("uvicorn.access")
    if not any(isinstance(f, RedactSecretsFilter) for f in access.filters):
        access.addFilter(RedactSecretsFilter())
    return config
