"""Gzip for HTTP responses of at least ``MINIMUM_BYTES`` when the client accepts it
(Starlette's ``GZipMiddleware``): JSON lists, the OpenAPI document, CSV exports and the
console's bundle. Never for websockets (the middleware sees HTTP only), nor for what is
already compressed (images, Parquet, MCAP, ``application/octet-stream``), nor for a stored
artifact served by :func:`server.api.served.serve_artifact`: that one streams with its
``Content-Length`` and a strong ``ETag`` of its bytes, and a client that resumes or checks it
needs them as they are; the route marks its request with :func:`send_as_stored`."""

from __future__ import annotations

from typing import Final

from starlette.datastructures import Headers
from starlette.middleware.gzip import DEFAULT_EXCLUDED_CONTENT_TYPES, GZipMiddleware, GZipResponder
from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["MINIMUM_BYTES", "Compression", "send_as_stored"]

#: Responses shorter than this go as they are (our choice: below about 1 KB gzip's header
#: and the CPU cost outweigh the bytes saved).
MINIMUM_BYTES: Final = 1024

#: zlib's own default, not Starlette's 9 (our choice): on 5,000 telemetry rows as JSON
#: (4.2 MB), level 9 took 2.8x the CPU of level 6 (468 against 170 ms) for 1.9 % fewer bytes,
#: on two cores shared with the live path.
COMPRESS_LEVEL: Final = 6

#: Content types sent as they are: Starlette's list, and the binary formats we serve that
#: are compressed already.
EXCLUDED_TYPES: Final = (
    *DEFAULT_EXCLUDED_CONTENT_TYPES,
    "application/octet-stream",
    "application/vnd.apache.parquet",
)

_AS_STORED: Final = "hikoboshi.send_as_stored"


def send_as_stored(connection: HTTPConnection) -> None:
    """Mark the request so that its response goes uncompressed, with its own length."""
    connection.scope[_AS_STORED] = True


class _Responder(GZipResponder):
    """Starlette's responder, passing a marked request's response through untouched."""

    def __init__(
        self,
        app: ASGIApp,
        scope: Scope,
        *,
        minimum_size: int,
        compresslevel: int,
        thread_minimum_size: int,
        exclude_content_types: tuple[str, ...],
    ) -> None:
        super().__init__(
            app,
            minimum_size,
            compresslevel,
            thread_minimum_size=thread_minimum_size,
            exclude_content_types=exclude_content_types,
        )
        self._scope = scope

    async def send_with_compression(self, message: Message) -> None:
        if self._scope.get(_AS_STORED):
            await self.send(message)
            return
        await super().send_with_compression(message)


class Compression(GZipMiddleware):
    """``GZipMiddleware`` at ``MINIMUM_BYTES`` with ``EXCLUDED_TYPES``, honouring
    :func:`send_as_stored`."""

    def __init__(self, app: ASGIApp, minimum_size: int = MINIMUM_BYTES) -> None:
        super().__init__(
            app,
            minimum_size=minimum_size,
            compresslevel=COMPRESS_LEVEL,
            exclude_content_types=EXCLUDED_TYPES,
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or "gzip" not in Headers(scope=scope).get("Accept-Encoding", ""):
            await self.app(scope, receive, send)
            return
        responder = _Responder(
            self.app,
            scope,
            minimum_size=self.minimum_size,
            compresslevel=self.compresslevel,
            thread_minimum_size=self.thread_minimum_size,
            exclude_content_types=self.exclude_content_types,
        )
        await responder(scope, receive, send)
