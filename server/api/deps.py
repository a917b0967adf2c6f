"""Dependencies as ``Annotated`` aliases: settings, a database session, the caller."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Header, Request, WebSocket
from sqlalchemy.orm import Session, sessionmaker

from server.errors import ServiceError
from server.settings import Role, Settings

__all__ = [
    "OperatorDep",
    "Principal",
    "SessionDep",
    "SettingsDep",
    "ViewerDep",
    "authenticate",
    "require",
    "websocket_principal",
]


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def get_session(request: Request) -> Iterator[Session]:
    """A session for the request: a read-only one for GET and HEAD (they never write, and on
    SQLite a reader then never waits for the ground's writer)."""
    state = request.app.state
    read_only = request.method in ("GET", "HEAD")
    factory: sessionmaker[Session] = state.read_sessions if read_only else state.sessions
    with factory() as session:
        yield session


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_session)]


@dataclass(frozen=True)
class Principal:
    name: str
    role: Role


def authenticate(settings: Settings, authorization: str | None) -> Principal:
    """The caller behind ``Authorization: Bearer TOKEN``; 401 without a known token."""
    if not authorization or not authorization.startswith("Bearer "):
        raise ServiceError(401, "unauthorized", "an API token is required (Authorization: Bearer)")
    token = settings.tokens.get(authorization.removeprefix("Bearer ").strip())
    if token is None:
        raise ServiceError(401, "unauthorized", "unknown API token")
    return Principal(token.name, token.role)


#: Which roles may act as which: an operator may do what a viewer does.
_GRANTS = {
    Role.VIEWER: {Role.VIEWER, Role.OPERATOR},
    Role.OPERATOR: {Role.OPERATOR},
    Role.SPACECRAFT: {Role.SPACECRAFT},
}


def require(role: Role) -> Callable[..., Principal]:
    """A dependency that admits callers whose role grants ``role`` (else 403)."""

    def dependency(
        settings: SettingsDep, authorization: Annotated[str | None, Header()] = None
    ) -> Principal:
        principal = authenticate(settings, authorization)
        if principal.role not in _GRANTS[role]:
            raise ServiceError(
                403,
                "forbidden",
                f"role {principal.role.value!r} may not do this ({role.value} only)",
            )
        return principal

    return dependency


ViewerDep = Annotated[Principal, Depends(require(Role.VIEWER))]
OperatorDep = Annotated[Principal, Depends(require(Role.OPERATOR))]


def websocket_principal(websocket: WebSocket, role: Role) -> Principal:
    """Authenticate a websocket by its Authorization header or ``?token=`` (browsers cannot
    set headers on a websocket)."""
    settings: Settings = websocket.app.state.settings
    header = websocket.headers.get("authorization")
    token = websocket.query_params.get("token")
    principal = authenticate(settings, header or (f"Bearer {token}" if token else None))
    if principal.role not in _GRANTS[role]:
        raise ServiceError(403, "forbidden", f"role {principal.role.value!r} may not connect here")
    return principal
