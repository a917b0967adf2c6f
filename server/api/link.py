"""``/api/link``: the spacecraft's websocket (docs/protocol.md), for the ``spacecraft`` role.

A bad token or role is accepted and then closed with 1008 and the reason (closing before
the handshake would lose the reason to a bare HTTP 403). A ground that does not hold the
vehicle's command lease (a standby, server/services/authority.py) refuses the handshake
itself (503, ``standby`` and the holder's name; a holder that loses the lease closes the
socket with 1013): the spacecraft tries its next ground, having sent this one nothing. Every text
(or binary) frame goes to :class:`server.services.link.GroundLink`, which answers a
malformed one with ``error`` and keeps the connection. Only the socket's own end closes
the session: an exception while handling one message (a bug, a database failure) is
logged and the next message is read.
"""

from __future__ import annotations

import asyncio
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.api.deps import AuthorityDep, ClockDep, LinkDep, websocket_principal
from server.api.errors import HttpError, ProblemResponse, problem
from server.services.link import Connection
from server.settings import Role

__all__ = ["router"]

router = APIRouter(tags=["link"])
log = logging.getLogger("hikoboshi.ground.link")


@router.websocket("/api/link")
async def spacecraft_link(
    websocket: WebSocket, link: LinkDep, clock: ClockDep, authority: AuthorityDep
) -> None:
    refusal = authority.refusal()
    if refusal is not None:
        # a standby (or a lease lapsing): refused in the handshake, before the vehicle says
        # hello or sends what it kept for the ground; it goes on to its next ground's URL
        await websocket.send_denial_response(
            ProblemResponse(
                problem(503, refusal.code, refusal.message, refusal.detail),
                status_code=503,
                headers={"Retry-After": "1"},
            )
        )
        return
    await websocket.accept()
    try:
        principal = websocket_principal(websocket, Role.SPACECRAFT)
    except HttpError as exc:
        await websocket.close(code=1008, reason=exc.message[:120])
        return

    async def close(code: int, reason: str) -> None:
        await websocket.close(code=code, reason=reason)

    peer = websocket.client
    conn = Connection(
        actor=principal.name,
        send_text=websocket.send_text,
        close=close,
        peer=f"{peer.host}:{peer.port}" if peer else None,
        user_agent=websocket.headers.get("user-agent", "")[:256] or None,
        connected_ns=clock.time_ns(),
    )
    await link.attach(conn)
    reason = "closed"
    try:
        while True:
            try:
                message = await websocket.receive()
            except RuntimeError as exc:  # the socket was closed under us (superseded)
                reason = str(exc)[:200]
                break
            received_mono = clock.monotonic()  # the one timing of its arrival
            if message["type"] == "websocket.disconnect":
                reason = f"closed by the spacecraft ({message.get('code')})"
                break
            raw = message.get("text")
            if raw is None:
                raw = message.get("bytes") or b""
            try:
                await link.handle(conn, raw, received_mono)
            except Exception:
                # Not a closed socket (a RecursionError is a RuntimeError too): one message
                # went wrong; the link stays up for the next.
                log.exception("handling a message from the spacecraft failed")
    except WebSocketDisconnect as exc:
        reason = f"closed by the spacecraft ({exc.code})"
    except asyncio.CancelledError:
        # The server's shutdown cancels a handler still open past its graceful timeout: a
        # routine stop, not an error (the vehicle reconnects to the next ground).
        reason = "the ground service is stopping"
    await link.detach(conn, reason)
