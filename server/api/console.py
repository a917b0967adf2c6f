"""``/api/console``: the consoles' websocket (docs/console.md), for viewers and operators.

The token comes in the ``Authorization`` header or (without one) a first message
``{"v": 1, "type": "auth", "token": ...}`` within the auth timeout: browsers cannot set
headers on a websocket, and a token in the URL would end up in access logs, so there is no
``?token=``. A missing or bad token or a role other than viewer or operator is accepted and
then closed with 1008 and the reason (a close before the handshake would lose the reason);
a bad token counts towards the address's failed-authentication limit (docs/security.md).
Every later frame goes to :class:`server.services.console.ConsoleHub`, which answers a bad
one with ``error`` and keeps the connection.

An authenticated console takes a seat first (:mod:`server.services.console_seats`: at
most ``consoles_per_token`` per token holder, ``consoles_per_address`` viewers per
address); over a cap it is closed with 1013 (try again later) and the reason, and the
refusal is written to the audit log (``hikoboshi.audit``).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated

from fastapi import APIRouter, Depends, WebSocket, WebSocketDisconnect
from starlette.requests import HTTPConnection

from server.api.deps import (
    ConsoleDep,
    Principal,
    SettingsDep,
    authenticate,
    record_auth_failure,
    websocket_principal,
)
from server.api.errors import HttpError
from server.services.console import AuthMsg, ConsoleHub, ProtocolError, decode_client
from server.services.console_seats import ConsoleRefused, ConsoleSeats
from server.settings import Role, Settings

__all__ = ["router"]

router = APIRouter(tags=["console"])
audit = logging.getLogger("hikoboshi.audit")

#: The close code of a console over a cap: "try again later" (RFC 6455 registry).
CLOSE_OVER_CAP = 1013

#: Roles that may watch (what ``require(Role.VIEWER)`` admits on REST).
_WATCHERS = (Role.VIEWER, Role.OPERATOR)


async def _principal(websocket: WebSocket, hub: ConsoleHub, settings: Settings) -> Principal:
    if websocket.headers.get("authorization"):
        return websocket_principal(websocket, Role.VIEWER)
    try:
        first = await asyncio.wait_for(websocket.receive(), hub.limits.auth_timeout_s)
    except TimeoutError:
        raise HttpError(401, "unauthorized", "no auth message in time") from None
    if first["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(first.get("code", 1000))
    raw = first.get("text")
    if raw is None:
        raw = first.get("bytes") or b""
    try:
        message = decode_client(raw, hub.limits.max_message_bytes)
    except ProtocolError as exc:
        raise HttpError(401, "unauthorized", f"auth expected first: {exc}") from None
    if not isinstance(message, AuthMsg):
        raise HttpError(401, "unauthorized", f"auth expected first, not {message.type}")
    try:
        principal = authenticate(settings, f"Bearer {message.token}")
    except HttpError as exc:
        record_auth_failure(websocket, exc.message, message.token)
        raise
    if principal.role not in _WATCHERS:
        raise HttpError(403, "forbidden", f"role {principal.role.value!r} may not connect here")
    return principal


def _fit(text: str, limit_bytes: int) -> str:
    """``text`` cut to at most ``limit_bytes`` of UTF-8 (a close reason's limit)."""
    return text.encode("utf-8")[:limit_bytes].decode("utf-8", "ignore")


async def _seats(connection: HTTPConnection) -> ConsoleSeats:
    """The consoles' seats (built by the lifespan, :mod:`server.app`)."""
    seats: ConsoleSeats = connection.app.state.console_seats
    return seats


SeatsDep = Annotated[ConsoleSeats, Depends(_seats)]


@router.websocket("/api/console")
async def console(
    websocket: WebSocket, hub: ConsoleDep, settings: SettingsDep, seats: SeatsDep
) -> None:
    await websocket.accept()
    try:
        principal = await _principal(websocket, hub, settings)
    except HttpError as exc:
        await websocket.close(code=1008, reason=exc.message[:120])
        return
    except WebSocketDisconnect:
        return
    address = websocket.client.host if websocket.client else "unknown"
    try:
        seat = seats.take(
            holder=principal.name, address=address, operator=principal.role is Role.OPERATOR
        )
    except ConsoleRefused as exc:
        audit.warning(
            "console refused: holder=%r role=%s address=%s cap=%s: %s",
            principal.name,
            principal.role.value,
            address,
            exc.cap,
            exc.message,
            extra={
                "fields": {
                    "event": "console_refused",
                    "holder": principal.name,
                    "role": principal.role.value,
                    "address": address,
                    "cap": exc.cap,
                    "reason": exc.message,
                }
            },
        )
        reason = f"too many consoles: {exc.message}"
        await websocket.close(code=CLOSE_OVER_CAP, reason=_fit(reason, 123))
        return
    with seat:
        await _serve(websocket, hub, principal)


async def _serve(websocket: WebSocket, hub: ConsoleHub, principal: Principal) -> None:
    async def close(code: int, reason: str) -> None:
        await websocket.close(code=code, reason=reason)

    client = hub.connect(
        actor=principal.name,
        role=principal.role.value,
        send_text=websocket.send_text,
        close=close,
    )
    try:
        while not client.closing:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
            raw = message.get("text")
            if raw is None:
                raw = message.get("bytes") or b""
            await hub.handle(client, raw)
    except (WebSocketDisconnect, RuntimeError):  # gone, or closed under us (kill)
        pass
    finally:
        await hub.disconnect(client)
