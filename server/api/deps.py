"""Dependencies as ``Annotated`` aliases: settings, a database session, the caller, and the
services the composition root (:mod:`server.app`) built: the link, the downlink, the
runner, the command path's database worker and the consoles' hub. Routes take these; none
reads ``app.state`` itself."""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Awaitable, Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Annotated, TypeVar

from fastapi import Depends, Path, Request, Security, WebSocket
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session, sessionmaker
from starlette.requests import HTTPConnection

from server.api.errors import HttpError
from server.api.lanes import Lane, request_lane
from server.schemas import SafeLine
from server.services.alarms import AlarmService
from server.services.authority import CommandAuthority
from server.services.clock import Clock
from server.services.console import ConsoleHub
from server.services.dbworker import Database, Publisher
from server.services.downlink import GroundDownlink
from server.services.link import GroundLink
from server.services.runner import PassRunner
from server.services.workers import WorkerPool
from server.settings import ApiToken, Role, Settings

T = TypeVar("T")

__all__ = [
    "BEARER",
    "AlarmsDep",
    "AuthorityDep",
    "ClockDep",
    "ConsoleDep",
    "DatabaseDep",
    "DownlinkDep",
    "IdPath",
    "LinkDep",
    "OperatorDep",
    "Principal",
    "PublisherDep",
    "ReadSessionsDep",
    "RunnerDep",
    "SessionDep",
    "SettingsDep",
    "ViewerDep",
    "WorkersDep",
    "authenticate",
    "find_token",
    "presented_credential",
    "record_auth_failure",
    "require",
    "websocket_principal",
]


def _state(name: str, kind: type[T]) -> Callable[[HTTPConnection], Awaitable[T]]:
    """A dependency on ``app.state.<name>`` (set by the lifespan, :mod:`server.app`), on the
    event loop, for routes and websockets alike."""

    async def get(connection: HTTPConnection) -> T:
        value: T = getattr(connection.app.state, name)
        return value

    get.__name__ = f"get_{name}"
    return get


get_settings = _state("settings", Settings)


def _session_factory(request: Request, *, read_only: bool) -> sessionmaker[Session]:
    state = request.app.state
    factory: sessionmaker[Session]
    if request_lane(request) is Lane.OPERATOR:
        factory = state.operator_read_sessions if read_only else state.operator_sessions
    else:
        factory = state.read_sessions if read_only else state.sessions
    return factory


def get_session(request: Request) -> Iterator[Session]:
    """A session for the request: a read-only one for GET and HEAD (they never write, and on
    SQLite a reader then never waits for the ground's writer); from the operators' own pool
    for an operator's request, else from the readers' (its lane: server/api/lanes.py)."""
    read_only = request.method in ("GET", "HEAD")
    with _session_factory(request, read_only=read_only)() as session:
        yield session


async def get_read_sessions(request: Request) -> sessionmaker[Session]:
    """The read-only session factory of the request's lane, for a route that reads in
    several short sessions (a streamed export) rather than one for the whole request."""
    return _session_factory(request, read_only=True)


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_session)]
#: The read-only sessions of the request's lane (as SessionDep picks them), as a factory.
ReadSessionsDep = Annotated[sessionmaker[Session], Depends(get_read_sessions)]
#: The injected clock every event and arrival is timed on.
ClockDep = Annotated[Clock, Depends(_state("clock", Clock))]
#: The consoles' publish hook.
PublisherDep = Annotated[Publisher, Depends(_state("publisher", Publisher))]
LinkDep = Annotated[GroundLink, Depends(_state("link", GroundLink))]
DownlinkDep = Annotated[GroundDownlink, Depends(_state("downlink", GroundDownlink))]
RunnerDep = Annotated[PassRunner, Depends(_state("runner", PassRunner))]
#: The command path's database worker (its own connections: readers cannot hold it up).
DatabaseDep = Annotated[Database, Depends(_state("db", Database))]
ConsoleDep = Annotated[ConsoleHub, Depends(_state("console", ConsoleHub))]
AlarmsDep = Annotated[AlarmService, Depends(_state("alarms", AlarmService))]
#: The command lease's keeper: whether this ground commands the vehicle or is a standby.
AuthorityDep = Annotated[CommandAuthority, Depends(_state("authority", CommandAuthority))]


@dataclass(frozen=True)
class Principal:
    name: str
    role: Role


def _digest(secret: str) -> bytes:
    return hashlib.sha256(secret.encode("utf-8", "surrogateescape")).digest()


def find_token(tokens: Mapping[str, ApiToken], presented: str) -> ApiToken | None:
    """The token ``presented`` is, compared in constant time: against every configured
    token (no early exit, no lookup by the secret), as SHA-256 digests so that neither a
    token's content nor its length shows in the time taken."""
    wanted = _digest(presented)
    found: ApiToken | None = None
    for secret, token in tokens.items():
        if hmac.compare_digest(_digest(secret), wanted):
            found = token
    return found


def presented_credential(authorization: str | None) -> str | None:
    """What an ``Authorization`` value presents: the token after ``Bearer``, else the whole
    value; None without one."""
    if not authorization:
        return None
    if authorization.startswith("Bearer "):
        return authorization.removeprefix("Bearer ").strip()
    return authorization


def authenticate(settings: Settings, authorization: str | None) -> Principal:
    """The caller behind ``Authorization: Bearer TOKEN``; 401 without a known token."""
    if not authorization or not authorization.startswith("Bearer "):
        raise HttpError(401, "unauthorized", "an API token is required (Authorization: Bearer)")
    token = find_token(settings.tokens, authorization.removeprefix("Bearer ").strip())
    if token is None:
        raise HttpError(401, "unauthorized", "unknown API token")
    return Principal(token.name, token.role)


#: The API's security scheme in the OpenAPI document (``bearerAuth``: Swagger UI's
#: Authorize button, generated clients' token). Declared only: ``auto_error=False``, so
#: :func:`authenticate` alone decides, with the same 401 reasons as before.
BEARER = HTTPBearer(
    scheme_name="bearerAuth",
    description="An API token (HIKOBOSHI_TOKENS) as Authorization: Bearer TOKEN; its role "
    "(viewer, operator, spacecraft) decides what it may do (docs/security.md).",
    auto_error=False,
)


#: Which roles may act as which: an operator may do what a viewer does.
_GRANTS = {
    Role.VIEWER: {Role.VIEWER, Role.OPERATOR},
    Role.OPERATOR: {Role.OPERATOR},
    Role.SPACECRAFT: {Role.SPACECRAFT},
}


def require(role: Role) -> Callable[..., Awaitable[Principal]]:
    """A dependency that admits callers whose role grants ``role`` (else 403). Async, so
    that FastAPI runs it on the event loop: the token check never waits for a worker
    thread (the edge, server/api/edge.py, has already refused unknown tokens)."""

    async def dependency(
        request: Request,
        _: Annotated[HTTPAuthorizationCredentials | None, Security(BEARER)],
    ) -> Principal:
        settings: Settings = request.app.state.settings
        principal = authenticate(settings, request.headers.get("authorization"))
        if principal.role not in _GRANTS[role]:
            raise HttpError(
                403,
                "forbidden",
                f"role {principal.role.value!r} may not do this ({role.value} only)",
            )
        return principal

    return dependency


ViewerDep = Annotated[Principal, Depends(require(Role.VIEWER))]
OperatorDep = Annotated[Principal, Depends(require(Role.OPERATOR))]


def websocket_principal(websocket: WebSocket, role: Role) -> Principal:
    """Authenticate a websocket by its Authorization header. Never by a query parameter: a
    token in a URL ends up in access logs (the console, whose browsers cannot set headers
    on a websocket, sends its token in a first message instead: server/api/console.py).
    A refused token counts towards the address's and the token's failed-authentication
    limits (:func:`record_auth_failure`); a valid one is never throttled."""
    settings: Settings = websocket.app.state.settings
    authorization = websocket.headers.get("authorization")
    try:
        principal = authenticate(settings, authorization)
    except HttpError as exc:
        record_auth_failure(websocket, exc.message, presented_credential(authorization))
        raise
    if principal.role not in _GRANTS[role]:
        raise HttpError(403, "forbidden", f"role {principal.role.value!r} may not connect here")
    return principal


def record_auth_failure(websocket: WebSocket, reason: str, credential: str | None) -> None:
    """Audit a websocket's failed authentication and count it against its address and the
    ``credential`` it presented (the edge's guard, server/api/auth_guard.py, when the
    application has one). Over either's limit: 429 ``too_many_failures`` instead (neither
    counted nor audited again: the block was, once). Called only for a failed attempt."""
    guard = getattr(websocket.app.state, "auth_guard", None)
    if guard is None:
        return
    client = websocket.client
    address = client.host if client else "unknown"
    retry = guard.retry_after(address, credential)
    if retry is not None:
        message = f"too many failed authentications: retry in {retry} s"
        raise HttpError(429, "too_many_failures", message)
    guard.failed(address, websocket.url.path, reason, credential)


get_workers = _state("workers", WorkerPool)

#: The pool of worker processes for CPU-heavy requests (server/services/workers.py).
WorkersDep = Annotated[WorkerPool, Depends(get_workers)]


#: A stored record's id in a path (a pass's, a plan's, an alarm's: a UUID; an unknown one is
#: 404): text without control characters, as the edge requires (server/schemas/__init__.py).
IdPath = Annotated[SafeLine, Path(min_length=1, max_length=64)]
