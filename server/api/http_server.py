"""How the ground service is served (docs/security.md): :func:`uvicorn_config` is how
``hikoboshi serve`` runs it, keep-alive and graceful shutdown timeouts, a bounded request
head, a request-head timeout (:func:`head_timeout_protocol`), forwarded headers believed
from ``trusted_proxies`` only (the client address the edge's guard counts is the peer's
otherwise), and every log record with its secrets redacted (:mod:`server.redaction`)."""

from __future__ import annotations

import asyncio
import logging
import math
from typing import TYPE_CHECKING

from starlette.types import ASGIApp

from server.redaction import RedactSecretsFilter, install_redaction
from server.settings import Settings

if TYPE_CHECKING:
    import uvicorn

__all__ = ["head_timeout_protocol", "uvicorn_config"]

log = logging.getLogger("hikoboshi.ground.edge")


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


def uvicorn_config(
    app: ASGIApp, settings: Settings, *, host: str, port: int, log_level: str = "info"
) -> uvicorn.Config:
    """How ``hikoboshi serve`` (and ``demo``'s ground) runs ``app``: the edge's timeouts and
    limits; ``X-Forwarded-For`` believed from ``settings.trusted_proxies`` only (uvicorn's
    own default believes loopback, so that anyone on the host could name any address);
    every log record redacted (:mod:`server.redaction`). Run it with
    ``server.app.GroundServer(config, app).run()`` (which stops the worker pool first on
    SIGTERM)."""
    import uvicorn

    install_redaction()
    proxies = list(settings.trusted_proxies)
    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level=log_level,
        # uvicorn's records go to the root logger, as configured by server.logs (one
        # format for every line), not through uvicorn's own handlers.
        log_config=None,
        lifespan="on",
        http=head_timeout_protocol(settings.header_timeout_s),
        timeout_keep_alive=math.ceil(settings.keep_alive_timeout_s),
        timeout_graceful_shutdown=3,
        h11_max_incomplete_event_size=settings.max_header_bytes,
        server_header=False,
        proxy_headers=bool(proxies),
        forwarded_allow_ips=proxies,
    )
    # The filter stays (the record factory redacts already; the filter keeps the access log
    # redacted if another one replaces it).
    access = logging.getLogger("uvicorn.access")
    if not any(isinstance(f, RedactSecretsFilter) for f in access.filters):
        access.addFilter(RedactSecretsFilter())
    return config
