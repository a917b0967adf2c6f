"""The Foxglove live view's door: the viewer token asked, both Foxglove subprotocols spoken.

foxglove-sdk's websocket server (:mod:`server.services.foxglove_live`) asks no token and
speaks only ``foxglove.sdk.v1``; the official ``@foxglove/ws-protocol`` client, Lichtblick and
older Foxglove apps offer ``foxglove.websocket.v1``, the same protocol under its first name
(foxglove/ws-protocol#916, foxglove-sdk's handshake). So the SDK's server listens on the
loopback at a free port, and this gate, on the configured ``foxglove_host:foxglove_port``:

- asks a token of at least the viewer's role, as ``Authorization: Bearer TOKEN`` or, for
  clients that cannot set a header on a websocket (the Foxglove app: a URL is all it takes),
  as ``?token=TOKEN`` in the URL; a missing or unknown token is refused 401, a role that may
  not view 403; each failure goes to the audit log (the token's fingerprint, never the
  token) and counts against failed-authentication limits as the API's do (the same
  settings, :class:`~server.api.auth_guard.AuthGuard`; the gate's own, on its thread: over
  a limit, 429 until the window ends);
- accepts either subprotocol, the SDK's first, and refuses a client that offers neither
  with 400 naming both;
- relays every frame both ways, unchanged, between the client and the SDK's server, which it
  joins with ``foxglove.sdk.v1``.

It runs its own event loop on a thread of its own, as the SDK's server does: a Foxglove
client never takes time from the link's loop. The SDK's per-client backlog still bounds what
a slow client can hold (:data:`server.services.foxglove_live.CLIENT_BACKLOG`): the relay
reads from the SDK no faster than the client takes (websockets' write buffer pushes back).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Mapping
from typing import Any
from urllib.parse import parse_qs, urlsplit

from sqlalchemy.orm import Session, sessionmaker
from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response
from websockets.typing import Subprotocol

from server.api.auth_guard import AuthGuard
from server.api.deps import find_token, presented_credential
from server.services.dbworker import Publisher
from server.services.foxglove_live import FoxgloveLive
from server.settings import ApiToken, Role, Settings

__all__ = [
    "SUBPROTOCOLS",
    "UPSTREAM_SUBPROTOCOL",
    "FoxgloveGate",
    "close_foxglove",
    "open_foxglove",
]

log = logging.getLogger("hikoboshi.ground.foxglove")
audit = logging.getLogger("hikoboshi.audit")

#: What the SDK's server speaks, and what the gate joins it with.
UPSTREAM_SUBPROTOCOL = Subprotocol("foxglove.sdk.v1")
#: What the gate accepts, in its order of preference.
SUBPROTOCOLS = (UPSTREAM_SUBPROTOCOL, Subprotocol("foxglove.websocket.v1"))
#: The roles that may watch the live view.
_VIEWERS = frozenset({Role.VIEWER, Role.OPERATOR})

#: The path failed authentications are audited under.
_PATH = "foxglove"


def _credential(request: Request) -> tuple[str | None, str]:
    """The token a request presents (the header first, then the URL's ``token``) and where
    it came from."""
    header = presented_credential(request.headers.get("Authorization"))
    if header is not None:
        return header, "header"
    values = parse_qs(urlsplit(request.path).query).get("token")
    return (values[0] if values else None), "url"


class FoxgloveGate:
    """The gate on ``host:port`` (0: a free port, :attr:`port`) before the SDK's server on
    ``127.0.0.1:upstream_port``. ``tokens`` as the server's setting; ``guard`` counts the
    refused authentications (confined to the gate's thread: give it one of its own)."""

    def __init__(
        self,
        *,
        host: str,
        port: int,
        upstream_port: int,
        tokens: Mapping[str, ApiToken],
        guard: AuthGuard | None = None,
    ) -> None:
        self._host, self._port = host, port
        self._upstream = f"ws://127.0.0.1:{upstream_port}"
        self._tokens = tokens
        self._guard = guard
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Server | None = None
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._error: BaseException | None = None
        #: clients relayed now, and since the start
        self.clients = 0
        self.connections = 0

    @property
    def port(self) -> int:
        if self._server is None:
            return self._port
        return int(next(iter(self._server.sockets)).getsockname()[1])

    # -- lifecycle -------------------------------------------------------------------------

    def start(self) -> None:
        """Listen (an ``OSError`` when the address cannot be bound)."""
        self._thread = threading.Thread(target=self._run, name="foxglove-gate", daemon=True)
        self._thread.start()
        self._started.wait()
        if self._error is not None:
            raise self._error

    def close(self) -> None:
        loop, thread = self._loop, self._thread
        if loop is not None and thread is not None and thread.is_alive():
            loop.call_soon_threadsafe(self._shutdown)
            thread.join(timeout=10.0)  # a guard: closing takes milliseconds

    def _run(self) -> None:
        loop = self._loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._serve())
        finally:
            loop.close()

    async def _serve(self) -> None:
        try:
            self._server = await serve(
                self._relay,
                self._host,
                self._port,
                subprotocols=list(SUBPROTOCOLS),
                process_request=self._admit,
                max_size=None,  # the SDK's messages: a URDF can be large
                compression=None,
            )
        except BaseException as exc:
            self._error = exc
            self._started.set()
            return
        self._started.set()
        log.info("foxglove live view on ws://%s:%d (token asked)", self._host, self.port)
        await self._server.wait_closed()

    def _shutdown(self) -> None:
        if self._server is not None:
            self._server.close()

    # -- the handshake -----------------------------------------------------------------------

    def _admit(self, connection: ServerConnection, request: Request) -> Response | None:
        """None to go on with the handshake; else the refusal (401, 403, 429)."""
        presented, where = _credential(request)
        token = None if presented is None else find_token(self._tokens, presented)
        if token is not None and token.role in _VIEWERS:
            return None
        if token is not None:
            reason = f"role {token.role.value!r} may not watch the live view"
            audit.warning("foxglove live view refused %s: %s", token.name, reason)
            return connection.respond(403, f"forbidden: {reason}\n")
        reason = (
            "a viewer's token is required (Authorization: Bearer TOKEN, or ?token=TOKEN)"
            if presented is None
            else f"unknown token (given in the {where})"
        )
        address = str(connection.remote_address[0]) if connection.remote_address else "unknown"
        if self._guard is None:
            audit.warning("foxglove live view refused %s: %s", address, reason)
        else:
            retry = self._guard.retry_after(address, presented)
            if retry is not None:
                return connection.respond(
                    429, f"too many failed authentications: retry in {retry} s\n"
                )
            self._guard.failed(address, _PATH, reason, presented)
        return connection.respond(401, f"unauthorized: {reason}\n")

    # -- the relay ---------------------------------------------------------------------------

    async def _relay(self, client: ServerConnection) -> None:
        self.clients += 1
        self.connections += 1
        try:
            async with connect(
                self._upstream,
                subprotocols=[UPSTREAM_SUBPROTOCOL],
                max_size=None,
                compression=None,
            ) as sdk:
                await _pump_both(client, sdk)
        except (OSError, ConnectionClosed) as exc:
            log.warning("foxglove live view: the SDK's server did not answer: %s", exc)
            await client.close(1011, "the live view is not available")
        finally:
            self.clients -= 1


async def _pump_both(client: ServerConnection, sdk: ClientConnection) -> None:
    """Relay frames both ways until either side closes; then close the other."""

    async def pump(source: Any, sink: Any) -> None:
        try:
            async for message in source:
                await sink.send(message)
        except ConnectionClosed:
            pass

    tasks = [
        asyncio.create_task(pump(client, sdk)),
        asyncio.create_task(pump(sdk, client)),
    ]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await asyncio.gather(client.close(), sdk.close(), return_exceptions=True)


def open_foxglove(
    settings: Settings, publisher: Publisher, sessions: sessionmaker[Session]
) -> tuple[FoxgloveLive | None, FoxgloveGate | None]:
    """The Foxglove live view and its gate when ``foxglove_port`` is set, both listening
    (docs/mcap.md); ``(None, None)`` otherwise."""
    if settings.foxglove_port is None:
        return None, None
    view = FoxgloveLive(
        host="127.0.0.1",  # the gate's alone: nothing else may reach the SDK's server
        port=0,
        publisher=publisher,
        sessions=sessions,
        robot_files=tuple(str(p) for p in settings.robot_files),
    )
    view.start()
    gate = FoxgloveGate(
        host=settings.foxglove_host,
        port=settings.foxglove_port,
        upstream_port=view.port,
        tokens=settings.tokens,
        guard=AuthGuard.of(settings),
    )
    try:
        gate.start()
    except BaseException:
        view.close()
        raise
    return view, gate


def close_foxglove(view: FoxgloveLive | None, gate: FoxgloveGate | None) -> None:
    """Close the gate (its clients go), then the view."""
    if gate is not None:
        gate.close()
    if view is not None:
        view.close()
