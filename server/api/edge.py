"""The HTTP edge: what every request meets before any route (docs/security.md).

:class:`EdgeMiddleware`, a pure ASGI middleware in front of the application
(:func:`install_edge`), answers in the one JSON error shape, in this order:

1. 400 ``invalid_text`` to a path or query string holding NUL, another C0 control character
   or DEL, raw or percent-encoded: text the databases refuse (PostgreSQL) or store (SQLite)
   is refused here, the same on both;
2. 401 ``unauthorized`` to a request for an ``/api`` route (except ``/api/health``) without a
   known ``Authorization: Bearer`` token, before a byte of its body is read (roles are the
   routes' dependencies' business: 403 there); or 429 ``too_many_failures`` (with
   ``Retry-After``) instead when its address or the credential it presents failed
   ``auth_failure_limit`` times within ``auth_failure_window_s``
   (:class:`~server.api.auth_guard.AuthGuard`; every counted failure goes to the
   ``hikoboshi.audit`` log, never the token). Only a failing attempt is throttled: a valid
   token, and a request to a public path, never are. The websockets authenticate
   themselves, with the same guard (server/api/deps.py);
3. ``OPTIONS`` on a path a route serves: 204 with ``Allow`` listing the methods of the
   route's path as the OpenAPI document groups them, and ``OPTIONS`` (:class:`AllowTable`);
   a method the path does not serve: 405 ``method_not_allowed`` with the same ``Allow``
   (the router's own would name only the first route's methods). No route runs, no
   capacity is taken. There is no CORS here (the console is served from the same origin),
   so no preflight either;
4. its lane (:mod:`server.api.lanes`, by route and role) and its share of capacity: 429
   ``too_many_requests`` past ``heavy_reads_per_token`` heavy reads in flight for the
   token, 503 ``busy`` past ``viewer_requests_max`` viewer requests in flight, both with
   ``Retry-After`` and before a byte of the body is read;
5. 413 ``request_too_large`` to a body over ``max_request_bytes``: at once for a declared
   ``Content-Length``, else as soon as the streamed body grows past it.
   ``POST /api/passes/import`` and ``POST /api/plans/documents`` stream through, each
   with its own limit (``max_import_bytes``, ``max_plan_document_bytes``) and checks;
6. for the authenticated routes, a JSON body (or one without a content type, which FastAPI
   reads as JSON) is read (bounded), parsed once and refused with 400 ``invalid_json``,
   ``json_too_deep`` (over ``max_json_depth``) or ``invalid_text`` (a string or key holding a
   control character other than tab, newline and carriage return, or a lone surrogate)
   before the application sees the original bytes.

Every response gets ``X-Content-Type-Options: nosniff``, ``Referrer-Policy: no-referrer``
and ``X-Frame-Options: DENY``; the console's page (``/``, ``/index.html``) a
``Content-Security-Policy`` that allows its own bundles and websocket only.

The checks of a request's target and body are :mod:`server.api.edge_checks`'s; how the
service is served (uvicorn's timeouts and limits) is :mod:`server.api.http_server`'s.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from fastapi.routing import iter_route_contexts
from starlette.routing import Match, Router, compile_path
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.auth_guard import AuthGuard
from server.api.deps import authenticate, presented_credential
from server.api.edge_checks import (
    _bad_target,
    _limited,
    _read_body,
    _replay,
    _too_large,
    check_json,
)
from server.api.errors import PROBLEM_JSON, HttpError, problem
from server.api.lanes import Admission, Refusal, is_heavy, lane_of, set_lane
from server.services.clock import Clock, SystemClock
from server.services.events import AuthBlocked, record
from server.settings import Settings

if TYPE_CHECKING:
    from fastapi import FastAPI

__all__ = ["AllowTable", "EdgeMiddleware", "console_csp", "install_edge"]

log = logging.getLogger("hikoboshi.ground.edge")

#: ``/api`` routes that need no token (the websockets authenticate themselves).
PUBLIC_PATHS = frozenset({"/api/health", "/api/ready", "/api/command"})
#: Outside /api, yet authenticated here like it (a viewer's token: docs/security.md).
PROTECTED_PATHS = frozenset({"/metrics"})
#: Stream their bodies through with their own, larger limits (server/api/recordings.py,
#: server/api/plans.py), and check them themselves.
STREAMED_PATHS = frozenset({"/api/passes/import", "/api/plans/documents"})
#: The console's HTML pages: they get the Content-Security-Policy.
CONSOLE_PAGES = frozenset({"/", "/index.html"})

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


class AllowTable:
    """What ``Allow`` lists for a path: the methods of the first route whose path matches
    it, in the application's order, and of the other routes with that route's path template
    (``/api/passes/import`` is not ``/api/passes/{pass_id}``, though the second matches it
    too), plus ``OPTIONS``; the OpenAPI document groups operations the same way. Read from
    the router on first use (the routes are added after the edge is installed)."""

    def __init__(self, router: Router) -> None:
        self.router = router
        self._routes: list[tuple[re.Pattern[str], str, frozenset[str]]] | None = None

    def _table(self) -> list[tuple[re.Pattern[str], str, frozenset[str]]]:
        if self._routes is None:
            routes = []
            for route in iter_route_contexts(self.router.routes):
                path, methods = route.path, route.methods
                if path is None or not methods:
                    continue  # websockets: no HTTP methods to list
                regex, path_format, _ = compile_path(path)
                routes.append((regex, path_format, frozenset(methods)))
            self._routes = routes
        return self._routes

    def allowed(self, path: str) -> list[str] | None:
        """The methods for ``path``, sorted, or None when no route serves it."""
        table = self._table()
        template = next((fmt for regex, fmt, _ in table if regex.match(path)), None)
        if template is None:
            return None
        methods = {m for _, fmt, route_methods in table if fmt == template for m in route_methods}
        return sorted(methods | {"OPTIONS"})


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
    body = json.dumps(problem(status, code, message, detail)).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", PROBLEM_JSON.encode()),
                (b"content-length", str(len(body)).encode()),
                *headers,
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


async def _options(send: Send, allowed: list[str], close: tuple[tuple[bytes, bytes], ...]) -> None:
    await send(
        {
            "type": "http.response.start",
            "status": 204,
            "headers": [(b"allow", ", ".join(allowed).encode()), *close],
        }
    )
    await send({"type": "http.response.body", "body": b""})


class EdgeMiddleware:
    """See the module's docstring. ``router``: the application's, to tell an ``/api`` route
    (authenticated) from a path no route serves (404 from the application, unread)."""

    def __init__(
        self,
        app: ASGIApp,
        *,
        settings: Settings,
        guard: AuthGuard,
        router: Router,
        admission: Admission,
    ) -> None:
        self.app = app
        self.settings = settings
        self.guard = guard
        self.router = router
        self.admission = admission
        self.allow = AllowTable(router)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            await self._http(scope, receive, _with_security_headers(scope, send))
        elif scope["type"] == "websocket":
            await self._websocket(scope, receive, send)
        else:
            await self.app(scope, receive, send)

    async def _websocket(self, scope: Scope, receive: Receive, send: Send) -> None:
        # Refused before the handshake (the client sees 403). The routes authenticate, and
        # ask the guard only about a failed attempt (server/api/deps.py): the vehicle's
        # link with its token connects whoever else failed from its address.
        if _bad_target(scope):
            await send({"type": "websocket.close", "code": 1008})
            return
        await self.app(scope, receive, send)

    def _protected(self, scope: Scope) -> bool:
        path: str = scope["path"]
        if path in PROTECTED_PATHS:
            return True
        if not (path == "/api" or path.startswith("/api/")) or path in PUBLIC_PATHS:
            return False
        return any(route.matches(scope)[0] is not Match.NONE for route in self.router.routes)

    async def _http(self, scope: Scope, receive: Receive, send: Send) -> None:
        address = _address(scope)
        declared = _content_length(scope)
        has_body = bool(declared) or _header(scope, b"transfer-encoding") is not None
        # A refusal that leaves a body unread closes the connection (nothing more is read).
        close: tuple[tuple[bytes, bytes], ...] = ((b"connection", b"close"),) if has_body else ()

        where = _bad_target(scope)
        if where is not None:
            message = f"the {where} holds a control character"
            await _respond(send, 400, "invalid_text", message, headers=close)
            return
        protected = self._protected(scope)
        principal = None
        if protected:
            authorization = _header(scope, b"authorization")
            try:
                principal = authenticate(self.settings, authorization)
            except HttpError as exc:
                # Only a failed attempt meets the guard: a valid token is never throttled.
                credential = presented_credential(authorization)
                retry = self.guard.retry_after(address, credential)
                if retry is not None:
                    message = f"too many failed authentications: retry in {retry} s"
                    headers = ((b"retry-after", str(retry).encode()), *close)
                    await _respond(send, 429, "too_many_failures", message, headers=headers)
                    return
                self.guard.failed(address, scope["path"], exc.message, credential)
                headers = ((b"www-authenticate", b"Bearer"), *close)
                await _respond(send, exc.status, exc.code, exc.message, headers=headers)
                return
        allowed = self.allow.allowed(scope["path"])
        if allowed is not None and scope["method"] not in allowed:
            message = f"{scope['method']} is not allowed here: {', '.join(allowed)}"
            headers = ((b"allow", ", ".join(allowed).encode()), *close)
            await _respond(send, 405, "method_not_allowed", message, headers=headers)
            return
        if allowed is not None and scope["method"] == "OPTIONS":
            await _options(send, allowed, close)
            return
        # Its lane and share of capacity (server/api/lanes.py), refused unread past it.
        lane = lane_of(scope["path"], None if principal is None else principal.role)
        set_lane(scope, lane)
        ticket = await self.admission.admit(
            lane,
            heavy=is_heavy(scope["method"], scope["path"]),
            holder=None if principal is None else principal.name,
        )
        if isinstance(ticket, Refusal):
            after = ((b"retry-after", str(ticket.retry_after_s).encode()),)
            detail = {"retry_after_s": ticket.retry_after_s}
            await _respond(
                send, ticket.status, ticket.code, ticket.message, detail, (*after, *close)
            )
            return
        try:
            await self._admitted(scope, receive, send, protected, declared, close)
        finally:
            ticket.release()

    async def _admitted(
        self,
        scope: Scope,
        receive: Receive,
        send: Send,
        protected: bool,
        declared: int | None,
        close: tuple[tuple[bytes, bytes], ...],
    ) -> None:
        if scope["path"] in STREAMED_PATHS:
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
    clock), its :class:`~server.api.lanes.Admission` ``app.state.admission``."""
    guard = AuthGuard.of(
        settings, lambda address, failures, left: _record_block(app, address, failures, left)
    )
    app.state.auth_guard = guard
    admission = Admission.of(settings)
    app.state.admission = admission
    app.add_middleware(
        EdgeMiddleware, settings=settings, guard=guard, router=app.router, admission=admission
    )
    return guard


def _record_block(app: FastAPI, address: str, failures: int, left_s: float) -> None:
    """Write an ``auth_blocked`` event to the audit log (the events table), shown to the
    consoles once it commits (the sessions' hook): once per blocked window and address, so
    an attacker cannot make the service write more than that. On the readers' connections,
    in a thread: never on the command path's."""
    sessions = getattr(app.state, "sessions", None)
    clock: Clock = getattr(app.state, "clock", None) or SystemClock()
    if sessions is None:
        return
    loop = asyncio.get_running_loop()
    blocked = AuthBlocked(
        actor="edge", address=address, failures=failures, blocked_s=round(left_s, 1)
    )

    def write() -> None:
        with sessions() as session:
            record(session, blocked, clock.time_ns())
            session.commit()

    def done(future: asyncio.Future[None]) -> None:
        if future.cancelled() or future.exception() is not None:
            log.error("auth_blocked event not written: %r", future.exception())

    loop.run_in_executor(None, write).add_done_callback(done)
