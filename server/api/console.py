"""``/api/console``: the consoles' websocket (docs/console.md), for viewers and operators.

The token comes in the ``Authorization`` header or (without one) a first message
``{"v": 1, "type": "auth", "token": ...}`` within the auth timeout: browsers cannot set
headers on a websocket, and a token in the URL would end up in access logs, so there is no
``?token=``. A missing or bad token or a role other than viewer or operator is accepted and
then closed with 1008 and the reason (a close before the handshake would lose the reason);
a bad token counts towards the address's failed-authentication limit (docs/security.md).
Every later frame goes to :class:`server.services.console.ConsoleHub`, which answers a bad
one with ``error`` and keeps the connection.
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

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
from server.settings import Role, Settings

__all__ = ["router"]

router = APIRouter(tags=["console"])

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
        record_auth_failure(websocket, exc.message)
        raise
    if principal.role not in _WATCHERS:
        raise HttpError(403, "forbidden", f"role {principal.role.value!r} may not connect here")
    return principal


@router.websocket("/api/console")
async def console(websocket: WebSocket, hub: ConsoleDep, settings: SettingsDep) -> None:
    await websocket.accept()
    try:
        principal = await _principal(websocket, hub, settings)
    except HttpError as exc:
        await websocket.close(code=1008, reason=exc.message[:120])
        return
    except WebSocketDisconnect:
        return

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
